"""Mission suite: every traction-control policy against no control.

Runs both suites (``greenhouse``, ``field``) on the evaluation seeds for every policy
(``none``, ``fixed``, ``accel-limit``, ``current-limit``, ``terrain-aware`` served by the online
predictor, ``oracle`` with the true class, ``oracle-cap`` at the true peak) and writes:

* the acceptance per policy (measured against goal, pass/fail);
* the distribution of success, route time, battery energy per metre, spin share and sinkage per
  family and terrain;
* the missions a policy regresses on against no control.

``terrain-aware`` needs a model trained on simulator data whose seeds are not mission seeds:
``$TERRAINML_MISSION_MODEL`` if set, else ``runs/mission_model``, trained here when missing
(:func:`ensure_model`: ``terrainml sim generate --runs-per-class 5 --duration-s 60 --seed 20``
then ``terrainml train`` with default options, seed 0). ``$TERRAINML_MISSION_SAVE`` (a folder)
also saves each policy's report JSON there (``terrainml mission plot`` reads them); with
``$TERRAINML_MISSION_REUSE`` set, saved reports are read back instead of rerun. ``quick``
runs the first 2 seeds only. Same rows as ``terrainml mission run --suite NAME --policy P
--n-jobs 2 --out P.json``.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

POLICIES = ("none", "fixed", "accel-limit", "current-limit", "terrain-aware", "oracle", "oracle-cap")
MODEL_DATA_SEED = 20          # simulator dataset seed of the served model (not a mission seed)
DEFAULT_MODEL_DIR = Path("runs/mission_model")


def ensure_model(model_dir: Path, held_out: str | None = None) -> Path:
    """The served model of ``terrain-aware``: trained with default options on simulator data
    (seed :data:`MODEL_DATA_SEED`, 5 runs of 60 s per class) when ``model_dir`` has none.

    ``held_out``: a class left out of the training runs (the open-set suite's models,
    ``bench_open_set_missions``): the same logs, linked into ``<model_dir>_data`` without that
    class's runs, so the models differ only by the class they never saw.
    """
    if (model_dir / "manifest.json").exists():
        return model_dir
    logs = DEFAULT_MODEL_DIR.parent / f"{DEFAULT_MODEL_DIR.name}_simdata"
    cli = [str(Path(sys.executable).with_name("terrainml"))]     # the venv's console script
    if not (logs / "index.csv").exists():
        subprocess.run(cli + ["sim", "generate", "--runs-per-class", "5", "--duration-s", "60", "--seed",
                              str(MODEL_DATA_SEED), "--out", str(logs), "--n-jobs", "2"], check=True)
    data = logs
    if held_out is not None:
        data = model_dir.parent / f"{model_dir.name}_data"
        data.mkdir(parents=True, exist_ok=True)
        with (logs / "index.csv").open() as f:
            for row in csv.DictReader(f):
                link = data / row["file"]
                if row["terrain"] != held_out and not link.exists():
                    link.symlink_to((logs / row["file"]).resolve())
    subprocess.run(cli + ["train", "--data", str(data), "--out", str(model_dir), "--seed", "0", "--windows", "short",
                          "--model", "svm", "--n-jobs", "2"], check=True)
    return model_dir


def _fmt(x, spec: str = ".2f") -> str:
    return "n/a" if x is None or not np.isfinite(x) else format(x, spec)


def _dist(rows: list[dict], key: str, spec: str = ".2f") -> str:
    """median [p10, p90] of a key over rows (finite values only)."""
    x = np.array([r[key] for r in rows if r.get(key) is not None and np.isfinite(r[key])], float)
    if x.size == 0:
        return "n/a"
    p10, med, p90 = np.percentile(x, [10, 50, 90])
    return f"{med:{spec}} [{p10:{spec}}, {p90:{spec}}]"


def _rate(rows: list[dict]) -> float:
    return 100.0 * float(np.mean([r["success"] for r in rows])) if rows else float("nan")


def _ratio(a: dict, b: dict, key: str) -> float:
    """b[key] / a[key] - 1 (NaN when either is missing or a's is not positive)."""
    x, y = a.get(key), b.get(key)
    if x is None or y is None or not (np.isfinite(x) and np.isfinite(y)) or x <= 0:
        return float("nan")
    return y / x - 1.0


def _median(x: list[float]) -> float:
    x = [v for v in x if np.isfinite(v)]
    return float(np.median(x)) if x else float("nan")


def criteria(none: list[dict], pol: list[dict], oracle: list[dict] | None = None) -> list[tuple]:
    """The acceptance criteria for one policy's rows (paired with ``none`` by index).

    Returns ``(criterion, measured, goal, ok)`` tuples. Definitions (docs/control_missions.md):
    energy and time changes are per mission, ``policy / none - 1``; time only where both completed
    the route (a failed mission's time is its 2x-nominal timeout).
    """
    pairs = list(zip(none, pol))
    out: list[tuple] = []
    band = [(a, b) for a, b in pairs if a["family"] == "field" and a["demand_ratio"] <= 0.9]
    r_none, r_pol = _rate([a for a, _ in band]), _rate([b for _, b in band])
    out.append((f"field, demand <= 0.9 ({len(band)} missions): success", f"{r_pol:.0f}% (none {r_none:.0f}%)",
                ">= 95%", r_pol >= 95.0))
    spin = [(a, b) for a, b in pairs if a["family"] == "field" and a["spin_share"] > 0.2]
    save = [-_ratio(a, b, "energy_j_per_m") for a, b in spin]
    med = _median(save)
    out.append((f"field, none spins > 20% ({len(spin)}): energy/m saved, median [min]",
                f"{100 * med:.0f}% [{100 * min(save, default=np.nan):.0f}%]", ">= 50%",
                bool(np.isfinite(med) and med >= 0.5)))
    lost = [(a, b) for a, b in pairs if a["success"] and not b["success"]]
    out.append(("missions none completes and the policy fails", f"{len(lost)}", "0", not lost))
    d_e = [_ratio(a, b, "energy_j_per_m") for a, b in pairs if a["success"] and b["success"]]
    d_t = [_ratio(a, b, "time_s") for a, b in pairs if a["success"] and b["success"]]
    n_e = sum(v > 0.03 for v in d_e if np.isfinite(v))
    n_t = sum(v > 0.05 for v in d_t if np.isfinite(v))
    out.append((f"both complete ({len(d_e)}): energy/m > +3% (worst)",
                f"{n_e} ({100 * max(d_e, default=np.nan):+.1f}%)", "0", n_e == 0))
    out.append((f"both complete ({len(d_t)}): time > +5% (worst)",
                f"{n_t} ({100 * max(d_t, default=np.nan):+.1f}%)", "0", n_t == 0))
    lvl = [(a, b) for a, b in pairs if a["family"] == "greenhouse" and a["parameters"]["grade_deg"] == 0.0]
    e_l = _median([_ratio(a, b, "energy_j_per_m") for a, b in lvl])
    t_l = _median([_ratio(a, b, "time_s") for a, b in lvl if a["route_done"] and b["route_done"]])
    out.append((f"greenhouse level ({len(lvl)}): energy/m, median change", f"{100 * e_l:+.1f}%", "<= +2%",
                bool(e_l <= 0.02)))
    out.append((f"greenhouse level ({len(lvl)}): time, median change", f"{100 * t_l:+.1f}%", "<= +3%",
                bool(t_l <= 0.03)))
    st = [(a, b) for a, b in pairs if a["family"] == "greenhouse" and a["parameters"]["start"] == "step"
          and a["terrain"] in ("dry_sand", "wet_mud")]
    s_st = _median([-_ratio(a, b, "energy_j_per_m") for a, b in st])
    out.append((f"greenhouse step starts, sand + mud ({len(st)}): energy/m saved, median",
                f"{100 * s_st:+.1f}%", ">= 3%", bool(s_st >= 0.03)))
    if oracle is not None:
        d_s = _rate(pol) - _rate(oracle)
        d_eo = _median([_ratio(o, b, "energy_j_per_m") for o, b in zip(oracle, pol)])
        out.append(("served vs oracle: success difference", f"{d_s:+.1f} points", "within 2", abs(d_s) <= 2.0))
        out.append(("served vs oracle: energy/m, median change", f"{100 * d_eo:+.1f}%", "within 5%",
                    bool(abs(d_eo) <= 0.05)))
    return out


def _save(save_dir: str | None, pol: str, rows: list[dict], seeds: list[int], model) -> None:
    if not save_dir:
        return
    from terrainml.commands.mission_cmds import _json_ready

    Path(save_dir).mkdir(parents=True, exist_ok=True)
    rep = {"suite": "all", "policy": pol, "seeds": seeds, "model": None if model is None else str(model),
           "missions": rows}
    (Path(save_dir) / f"{pol}.json").write_text(json.dumps(_json_ready(rep)))


def run(quick: bool = False) -> str:
    from terrainml.experiments.missions import EVAL_SEEDS, FAMILIES, run_suite, suite

    n_seeds = 2 if quick else len(EVAL_SEEDS)
    model = ensure_model(Path(os.environ.get("TERRAINML_MISSION_MODEL", DEFAULT_MODEL_DIR)))
    save_dir = os.environ.get("TERRAINML_MISSION_SAVE")
    specs = [s for f in FAMILIES for s in suite(f) if s.seed in EVAL_SEEDS[:n_seeds]]
    rows: dict[str, list[dict]] = {}
    took: dict[str, float] = {}
    for pol in POLICIES:
        t0 = time.perf_counter()
        cached = Path(save_dir or ".", f"{pol}.json")
        if save_dir and os.environ.get("TERRAINML_MISSION_REUSE") and cached.exists():
            rows[pol] = json.loads(cached.read_text())["missions"]     # re-render a saved run
            took[pol] = 0.0
            continue
        rows[pol], _ = run_suite(specs, pol, n_jobs=2, model=model if pol == "terrain-aware" else None)
        took[pol] = time.perf_counter() - t0
        _save(save_dir, pol, rows[pol], list(EVAL_SEEDS[:n_seeds]), model)
    n = len(rows["none"])
    energy_src = sorted({r.get("energy_source", "?") for r in rows["none"]})
    lines = [
        "## Mission suite: traction-control policies against no control (`terrainml mission run`)",
        "",
        f"Evaluation seeds {list(EVAL_SEEDS[:n_seeds])} (fixed in `terrainml/experiments/missions.py`, "
        f"never used for tuning; the limiter was tuned on the tuning seeds 5000-5011), {n} missions per "
        f"policy, reference robot, `--n-jobs 2`; {sum(took.values()):.0f} s for {len(POLICIES)} policies. "
        f"Energy source: {', '.join(energy_src)}. `terrain-aware` is served by the online predictor "
        f"from `{model}` (SVM, default `terrainml train` options, trained on simulator data of seed "
        f"{MODEL_DATA_SEED}, 5 runs of 60 s per class: no mission seed). Definitions: docs/missions.md, "
        "docs/control_missions.md.",
        "",
        "### Acceptance per policy (evaluation seeds)",
        "",
        "| policy | criterion | measured | goal | pass |",
        "|---|---|---|---|---|",
    ]
    for pol in POLICIES[1:]:
        orc = rows["oracle"] if pol == "terrain-aware" else None
        for name, meas, goal, ok in criteria(rows["none"], rows[pol], orc):
            lines.append(f"| {pol} | {name} | {meas} | {goal} | {'pass' if ok else '**fail**'} |")
    lines += ["", "### Per family", "",
              "| family | policy | success | level-ground success | success at demand <= 0.9 "
              "| median energy J/m | median spin share | fallback share |",
              "|---|---|---|---|---|---|---|---|"]
    for fam in FAMILIES:
        for pol in POLICIES:
            rs = [r for r in rows[pol] if r["family"] == fam]
            level = [r for r in rs if r["parameters"].get("grade_deg", 0.0) == 0.0]
            ctrl = [r for r in rs if r["demand_ratio"] <= 0.9]

            def rate(sub):
                return f"{_rate(sub):.0f}% ({len(sub)})" if sub else "n/a"
            lines.append(f"| {fam} | {pol} | {rate(rs)} | {rate(level)} | {rate(ctrl)} | "
                         f"{_fmt(np.median([r['energy_j_per_m'] for r in rs]), '.0f')} | "
                         f"{_fmt(np.median([r['spin_share'] for r in rs]))} | "
                         f"{_fmt(np.mean([r['fallback_share'] for r in rs]))} |")
    lines += ["", "### Per family and terrain", "",
              "Cells: median [p10, p90] over the missions.", "",
              "| family | terrain | policy | n | success | time s | energy J/m | spin share | max sinkage mm "
              "| demand ratio |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for fam, terrains in FAMILIES.items():
        for ter in terrains:
            for pol in POLICIES:
                rs = [r for r in rows[pol] if r["family"] == fam and r["terrain"] == ter]
                if not rs:
                    continue
                z = [dict(r, max_sinkage_mm=1000 * r["max_sinkage_m"]) for r in rs]
                lines.append(
                    f"| {fam} | {ter} | {pol} | {len(rs)} | {_rate(rs):.0f}% | {_dist(rs, 'time_s', '.1f')} | "
                    f"{_dist(rs, 'energy_j_per_m', '.0f')} | {_dist(rs, 'spin_share')} | "
                    f"{_dist(z, 'max_sinkage_mm', '.0f')} | {_dist(rs, 'demand_ratio')} |")
    ta = rows["terrain-aware"]
    reg = [(a, b) for a, b in zip(rows["none"], ta)
           if (a["success"] and not b["success"])
           or (a["success"] and b["success"] and (_ratio(a, b, "energy_j_per_m") > 0.03
                                                  or _ratio(a, b, "time_s") > 0.05))]
    lines += ["", f"### Missions where terrain-aware regresses against none ({len(reg)} of {n})", ""]
    if reg:
        lines += ["| family | terrain | seed | start | grade deg | demand | none | terrain-aware | "
                  "energy/m change | time change |", "|---|---|---|---|---|---|---|---|---|---|"]
        for a, b in reg:
            lines.append(
                f"| {a['family']} | {a['terrain']} | {a['seed']} | {a['parameters']['start']} | "
                f"{a['parameters']['grade_deg']:.1f} | {a['demand_ratio']:.2f} | "
                f"{'ok' if a['success'] else 'fails'} {a['time_s']:.1f} s | "
                f"{'ok' if b['success'] else 'fails'} {b['time_s']:.1f} s, stall {b['longest_stall_s']:.1f} s | "
                f"{100 * _ratio(a, b, 'energy_j_per_m'):+.1f}% | {100 * _ratio(a, b, 'time_s'):+.1f}% |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":  # pragma: no cover
    import sys

    print(run(quick="--quick" in sys.argv))
