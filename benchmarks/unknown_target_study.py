"""Study: the novelty threshold and the settling distance against known and unknown ground served.

A higher false-alarm target flags more of unknown ground and more of known ground. Known ground
pays where the flags run together: at a change between known terrains, flagged until every
wheel has crossed and the drive has settled (0.8-3.7 m). The filter's ``settle_m``
(:data:`terrainml.stream.tick.fusion.SETTLE_M`) makes flags that begin on known ground enter unknown
only once they outlast that distance; unknown ground entered from known ground pays it as delay.

This study serves held-out *tuning* courses (the ``mixed`` scenario of ``make demo``'s course,
0.8 m/s, 120 s, seeds 9301-9304: the transition tuning seeds, never the demo's
course, seed 10000) through

* the demo's model (``runs/demo/model``, from ``make demo``), with its novelty threshold set for
  each target from out-of-fold scores of the demo's training windows
  (:func:`terrainml.models.novelty.fit_model_novelty`; and none, the closed-set model), and with
  the shipped threshold at each ``settle_m``: moving ticks served the logged class (the demo's
  figure) and served ``unknown_terrain``;
* the open-set suite's models (``runs/open_set_models/no_CLASS``, from
  ``benchmarks/bench_open_set_missions.py``), each trained without one class, at each
  ``settle_m``: the share of that class's moving ticks served ``unknown_terrain``, and the
  metres driven onto each of its stretches before the first ``unknown_terrain`` tick.

Run: ``python -m benchmarks.unknown_target_study [--targets 0.03,0.05] [--settle 0,2,2.5,3]
[--seeds 9301-9304]``.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from terrainml.models.novelty import fit_model_novelty
from terrainml.pipeline.dataset import read_windows
from terrainml.sim.generate import simulate, write_run
from terrainml.stream.tick.config import ServingConfig
from terrainml.stream.tick.fusion import SETTLE_M, FusionConfig
from terrainml.stream.tick.predictor import Predictor
from terrainml.stream.app.options import CLASSIFY_LAG_TICKS
from terrainml.stream.app.scoring import MOVING_TICK_MPS
from terrainml.stream.tick.sample import InvalidSample
from terrainml.stream.transports.sources import open_source

DEMO = Path("runs/demo")
OPEN_SET = Path("runs/open_set_models")


def thresholds(targets: list[float]) -> dict[str, float]:
    """Threshold per setting, from the demo model's features of its training windows: each
    target held out one run at a time (shipped), 3 % in 3 inner folds, and
    no threshold (``inf``: the closed-set model)."""
    clf = Predictor.from_model_dir(DEMO / "model").classifier
    W = read_windows(DEMO / "windows.parquet").windows
    if clf.features is not None:
        raise SystemExit("the demo model has a feature transform before its model; this study takes raw windows")
    out = {"none (closed set)": float("inf"),
           "3 %, 3 folds": float(fit_model_novelty(clf.model, W, seed=0, novelty_false_alarm=0.03,
                                                   inner_folds=3)[0].threshold)}
    for t in targets:
        scorer, _ = fit_model_novelty(clf.model, W, seed=0, novelty_false_alarm=t)
        out[f"{100 * t:.0f} %, one run out"] = float(scorer.threshold)
    print(f"shipped threshold {clf.novelty.threshold:.4f}; per target {out}", flush=True)
    return out


def serve(model: Path, course: Path, settle_m: float, threshold: float | None = None) -> dict:
    """Serve one course: moving ticks of known classes (n, served the logged class, unknown) and
    of classes the model lacks (n, unknown), and the metres onto each such stretch before its
    first ``unknown_terrain`` tick (inf: never)."""
    p = Predictor.from_model_dir(model, config=ServingConfig(classify_lag_ticks=CLASSIFY_LAG_TICKS,
                                                             fusion=FusionConfig(settle_m=settle_m)))
    if threshold is not None:  # flags compare the scorer's threshold (the message's ratio keeps the saved one)
        p.classifier.novelty.threshold = threshold
    known = set(p.policy.class_ids)
    c = {"known": 0, "right": 0, "known_unknown": 0, "new": 0, "new_unknown": 0, "entries_m": []}
    odo_prev, t_prev, start_m, entered = 0.0, None, None, False
    try:
        for sample in open_source(str(course), robot=p.robot):
            try:
                msg = p.step(sample)
            except InvalidSample:
                continue
            if msg is None:
                continue
            lab = sample.columns.get("terrain")
            lab = -1 if lab is None or lab != lab else int(lab)
            dt = 0.0 if t_prev is None else msg.t_s - t_prev
            moving = dt > 0 and (p.odometer_m - odo_prev) / dt >= MOVING_TICK_MPS
            odo_prev, t_prev = p.odometer_m, msg.t_s
            unknown = msg.fallback_reason == "unknown_terrain"
            new = lab >= 0 and lab not in known
            if new and start_m is None:
                start_m, entered = p.odometer_m, False
            if start_m is not None and (not new or unknown) and not entered:
                c["entries_m"].append(p.odometer_m - start_m if unknown else np.inf)
                entered = True
            if not new:
                start_m = None
            if not moving or lab < 0:
                continue
            key = "new" if new else "known"
            c[key] += 1
            c[f"{key}_unknown"] += unknown
            c["right"] += (not new and not msg.fallback and msg.terrain_class == lab)
    finally:
        p.close()
    if start_m is not None and not entered:
        c["entries_m"].append(np.inf)
    return c


def _add(total: dict, c: dict) -> None:
    for k, v in c.items():
        total[k] = total.get(k, [] if isinstance(v, list) else 0) + v


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--targets", default="0.03,0.05")
    ap.add_argument("--settle", default=f"0,2,{SETTLE_M:g},3")
    ap.add_argument("--seeds", default="9301-9304")
    a = ap.parse_args()
    lo, hi = (int(x) for x in a.seeds.split("-"))
    settles = [float(s) for s in a.settle.split(",")]
    thr = thresholds([float(t) for t in a.targets.split(",")])
    demo_rows = {(t, SETTLE_M): v for t, v in thr.items()} | {("shipped", s): None for s in settles}
    open_models = sorted(OPEN_SET.glob("no_*/manifest.json"))
    totals: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(lo, hi + 1):
            course = write_run(simulate(None, "mixed", speed_mps=0.8, duration_s=120.0, seed=seed),
                               Path(tmp) / f"course{seed}.mcap", f"tuning_{seed}")
            for (t, s), v in demo_rows.items():
                _add(totals.setdefault(("demo", t, s), {}), serve(DEMO / "model", course, s, v))
            for m in open_models:
                for s in settles:
                    _add(totals.setdefault((m.parent.name, "shipped", s), {}), serve(m.parent, course, s))
            print(f"seed {seed} served", flush=True)
    print("\n| model | threshold | settle_m | known moving ticks | served the logged class % | "
          "served unknown_terrain % |\n|---|---|---|---|---|---|")
    for (m, t, s), c in totals.items():
        if m == "demo":
            print(f"| demo | {t} | {s:g} | {c['known']} | {100 * c['right'] / c['known']:.1f} | "
                  f"{100 * c['known_unknown'] / c['known']:.1f} |")
    print("\n| model | settle_m | its unseen class's moving ticks | served unknown_terrain % | stretches entered "
          "| m onto each stretch before unknown_terrain |\n|---|---|---|---|---|---|")
    for (m, t, s), c in totals.items():
        if m != "demo" and c["new"]:
            e = np.array(c["entries_m"])
            print(f"| {m} | {s:g} | {c['new']} | {100 * c['new_unknown'] / c['new']:.1f} | "
                  f"{int(np.isfinite(e).sum())} of {e.size} | {', '.join(f'{x:.1f}' for x in e)} |")


if __name__ == "__main__":
    main()
