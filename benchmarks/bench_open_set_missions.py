"""Open-set missions: ground the served model was never trained on.

For each class of :data:`terrainml.experiments.missions.OPEN_SET_CLASSES` (dry_sand, wet_mud,
tilled_loam) in turn, the served model is trained without it (the mission model's recipe,
:func:`benchmarks.bench_missions.ensure_model` with ``held_out``: the same simulator logs of seed
20 minus that class's runs, ``train --windows short --model svm --seed 0``) and drives the
missions whose ground has that class (:func:`~terrainml.experiments.missions.open_set_suite`: a
floor of it, a floor with its patches, a field route with its patches). Policies:

* ``none``: no traction control;
* ``terrain-aware-closed``: the served model without its novelty score, every window one of its
  classes (the closed set: no novelty score);
* ``terrain-aware``: the same model with its novelty score: ground flagged unknown is served the
  class-free safe cap (``unknown_terrain``);
* ``terrain-aware-refine-unknown``: as ``terrain-aware``, the safe cap on unknown ground refined
  online from the robot's thrust-slip data (:mod:`terrainml.control.cap_refiner`);
* ``oracle-cap``: the limiter at the true traction peak of the ground under each wheel.

Then the same served policies with the model trained on all eight classes on the whole suite
(known ground: what the novelty score costs where nothing is unknown).

Acceptance, per held-out class and over the three: unknown-ground handling completes
at least as many missions as the closed-set model; energy per metre no worse than 3% above the
oracle cap's on the missions where no control does not spin (its spin share <= 0.2, both
complete); no mission that no control completes and the policy fails.

Which handling is ``terrain-aware``'s default was chosen on the *tuning* seeds
(``python -m benchmarks.bench_open_set_missions --seeds tuning``), never on the evaluation seeds
this section reports. ``$TERRAINML_MISSION_SAVE`` (a folder) keeps each run's rows there and,
with ``$TERRAINML_MISSION_REUSE``, reads them back instead of rerunning.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.bench_missions import DEFAULT_MODEL_DIR, MODEL_DATA_SEED, _median, _rate, _ratio, ensure_model

POLICIES = ("none", "terrain-aware-closed", "terrain-aware", "terrain-aware-refine-unknown", "oracle-cap")
SERVED = ("terrain-aware-closed", "terrain-aware", "terrain-aware-refine-unknown")
HANDLING = ("terrain-aware", "terrain-aware-refine-unknown")
MODELS_DIR = Path("runs/open_set_models")
SPIN_SHARE = 0.2     # as bench_missions: a mission where none's spin share is above this spins


def _rows(specs, policy: str, model, tag: str, seeds: str) -> tuple[list[dict], float]:
    """Rows of ``policy`` on ``specs`` (read back from ``$TERRAINML_MISSION_SAVE`` when asked)."""
    from terrainml.experiments.missions import run_suite

    save = os.environ.get("TERRAINML_MISSION_SAVE")
    cached = Path(save or ".", f"open_set_{seeds}_{tag}_{policy}.json")
    if save and os.environ.get("TERRAINML_MISSION_REUSE") and cached.exists():
        return json.loads(cached.read_text()), 0.0
    t0 = time.perf_counter()
    rows, _ = run_suite(specs, policy, n_jobs=2, model=model if policy in SERVED else None)
    if save:
        cached.parent.mkdir(parents=True, exist_ok=True)
        cached.write_text(json.dumps(rows, default=float))
    return rows, time.perf_counter() - t0


def criteria(rows: dict[str, list[dict]], policy: str) -> list[tuple[str, str, str, bool]]:
    """The acceptance of one handling policy against its rows' ``none``,
    ``terrain-aware-closed`` and ``oracle-cap`` rows (paired by index)."""
    none, closed, cap, pol = rows["none"], rows["terrain-aware-closed"], rows["oracle-cap"], rows[policy]
    n_pol, n_closed = sum(r["success"] for r in pol), sum(r["success"] for r in closed)
    out = [("missions completed (closed-set model)", f"{n_pol} of {len(pol)} ({n_closed})", ">= closed-set",
            n_pol >= n_closed)]
    calm = [(c, p) for a, c, p in zip(none, cap, pol)
            if a["spin_share"] <= SPIN_SHARE and c["success"] and p["success"]]
    d_e = [_ratio(c, p, "energy_j_per_m") for c, p in calm]
    n_over = sum(v > 0.03 for v in d_e if np.isfinite(v))
    out.append((f"no control does not spin ({len(calm)}): energy/m vs oracle cap > +3%, median [worst]",
                f"{n_over} ({100 * _median(d_e):+.1f}% [{100 * max(d_e, default=np.nan):+.1f}%])", "0",
                n_over == 0))
    lost = [a for a, p in zip(none, pol) if a["success"] and not p["success"]]
    out.append(("missions none completes and the policy fails", str(len(lost)), "0", not lost))
    return out


def _class_table(by_class: dict[str, dict[str, list[dict]]]) -> list[str]:
    lines = ["| held out | missions | policy | success | median energy J/m | energy/m vs oracle cap, median "
             "| median spin share | fallback share |", "|---|---|---|---|---|---|---|---|"]
    for held, rows in by_class.items():
        for pol in POLICIES:
            rs = rows[pol]
            d = _median([_ratio(c, r, "energy_j_per_m") for c, r in zip(rows["oracle-cap"], rs)
                         if c["success"] and r["success"]])
            lines.append(f"| {held} | {len(rs)} | {pol} | {_rate(rs):.0f}% | "
                         f"{_median([r['energy_j_per_m'] for r in rs]):.0f} | {100 * d:+.1f}% | "
                         f"{_median([r['spin_share'] for r in rs]):.2f} | "
                         f"{np.mean([r['fallback_share'] for r in rs]):.2f} |")
    return lines


def _lost_table(by_class: dict[str, dict[str, list[dict]]], policy: str) -> list[str]:
    """Missions the policy fails that no control completes, or completes at > +3% over the cap."""
    out = []
    for held, rows in by_class.items():
        for a, c, k, p in zip(rows["none"], rows["oracle-cap"], rows["terrain-aware-closed"], rows[policy]):
            d = _ratio(c, p, "energy_j_per_m")
            if (a["success"] and not p["success"]) or (a["spin_share"] <= SPIN_SHARE and np.isfinite(d) and d > 0.03):
                out.append(f"| {held} | {p['family']} | {p['terrain']} | {p['seed']} | "
                           f"{p['parameters']['grade_deg']:.1f} | {'ok' if a['success'] else 'fails'} | "
                           f"{'ok' if k['success'] else 'fails'} | {'ok' if p['success'] else 'fails'}, "
                           f"stall {p['longest_stall_s']:.1f} s | {100 * d:+.1f}% |")
    head = ["| held out | family | terrain | seed | grade deg | none | closed-set | policy | energy/m vs cap |",
            "|---|---|---|---|---|---|---|---|---|"]
    return head + out if out else ["none."]


def run(quick: bool = False, seeds: str = "eval") -> str:
    from terrainml.experiments.missions import OPEN_SET_CLASSES, open_set_suite, suite

    took = 0.0
    by_class: dict[str, dict[str, list[dict]]] = {}
    for held in OPEN_SET_CLASSES:
        model = ensure_model(MODELS_DIR / f"no_{held}", held_out=held)
        specs = open_set_suite(held, seeds, limit=4 if quick else None)
        by_class[held] = {}
        for pol in POLICIES:
            by_class[held][pol], dt = _rows(specs, pol, model, f"no_{held}", seeds)
            took += dt
    pooled = {pol: [r for rows in by_class.values() for r in rows[pol]] for pol in POLICIES}
    full = ensure_model(Path(os.environ.get("TERRAINML_MISSION_MODEL", DEFAULT_MODEL_DIR)))
    known_specs = suite("all", seeds, limit=8 if quick else None)
    known: dict[str, list[dict]] = {}
    for pol in SERVED:
        known[pol], dt = _rows(known_specs, pol, full, "all_classes", seeds)
        took += dt
    n = sum(len(r["none"]) for r in by_class.values())
    lines = [
        "## Open-set missions: ground the served model never saw",
        "",
        f"{'Evaluation' if seeds == 'eval' else 'Tuning'} seeds; for each held-out class the missions of both "
        f"families whose ground has it ({n} missions in all, per policy), served by a model trained without it "
        f"(simulator logs of seed {MODEL_DATA_SEED} minus that class's runs, `train --windows short --model svm "
        f"--seed 0`); {took:.0f} s of missions, `--n-jobs 2`. Same rows as `terrainml mission run --suite all "
        "--held-out CLASS --policy P --model runs/open_set_models/no_CLASS`. Definitions: docs/missions.md; "
        "policies in the module docstring of `benchmarks/bench_open_set_missions.py`.",
        "",
        "### Acceptance, pooled over the three held-out classes",
        "",
        "| policy | criterion | measured | goal | pass |",
        "|---|---|---|---|---|",
    ]
    for pol in HANDLING:
        for name, meas, goal, ok in criteria(pooled, pol):
            lines.append(f"| {pol} | {name} | {meas} | {goal} | {'pass' if ok else '**fail**'} |")
    lines += ["", "### Per held-out class", "", *_class_table(by_class)]
    for pol in HANDLING:
        lines += ["", f"### Missions `{pol}` fails that none completes, or > +3% energy/m over the oracle cap "
                  "where none does not spin", "", *_lost_table(by_class, pol)]
    lines += ["", f"### Known ground: the model on all eight classes, whole suite ({len(known_specs)} missions)", "",
              "| policy | success | median energy J/m | energy/m vs closed-set, median [worst] | fallback share |",
              "|---|---|---|---|---|"]
    for pol in SERVED:
        d = [_ratio(a, b, "energy_j_per_m") for a, b in zip(known["terrain-aware-closed"], known[pol])
             if a["success"] and b["success"]]
        lines.append(f"| {pol} | {_rate(known[pol]):.0f}% | {_median([r['energy_j_per_m'] for r in known[pol]]):.0f} | "
                     f"{100 * _median(d):+.1f}% [{100 * max(d, default=np.nan):+.1f}%] | "
                     f"{np.mean([r['fallback_share'] for r in known[pol]]):.3f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":  # pragma: no cover
    print(run(quick="--quick" in sys.argv, seeds="tuning" if "tuning" in sys.argv else "eval"))
