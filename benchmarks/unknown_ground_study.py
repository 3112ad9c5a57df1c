"""Unknown ground on a real robot: BorealTC SNOW served by a model that never saw SNOW.

Not part of ``make bench`` (a few minutes on 2 cores). The serving goal: ``unknown_terrain``
ticks appear on a SNOW run served by a model without SNOW, within 3 m of moving onto it, and
known ground keeps its served class.

Protocol, fixed before it was run (nothing here is tuned on its figures):

* the model: ``--windows chunks`` (the BorealTC authors' windows), ``svm+hgb`` (the choice of
  default ``train`` on BorealTC), all sensor groups, trained by :func:`terrainml.pipeline.train.train`
  (its novelty scorer and threshold fitted with it, one training run out at a time) on every ASPHALT,
  FLOORING, ICE and SANDY_LOAM run except the last one of each class;
* the course: 30 s from the middle of each run, IMU kept, alternating a held-out known run (the
  four in turn) and a SNOW run, for every SNOW run: known, SNOW_00, known, SNOW_01, ...;
  :class:`~terrainml.stream.tick.predictor.Predictor` serves it tick by tick as ``terrainml predict``;
* per SNOW segment: the wheel distance (mean rim speed integrated) from the segment's start to
  its first ``unknown_terrain`` tick, and the share of its moving ticks served ``unknown_terrain``;
  per known segment: the shares of its moving ticks served ``unknown_terrain`` and the labelled
  class. A tick moves when the mean rim speed exceeds 0.2 m/s.

``python -m benchmarks.unknown_ground_study`` prints the Markdown.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from tempfile import TemporaryDirectory

import numpy as np
import pandas as pd

from benchmarks.bench_real_robots import DATA
from terrainml.evaluation.report import markdown_table
from terrainml.experiments.borealtc import make_course, runs_by_class
from terrainml.features.windows import window_spec
from terrainml.io.ingest import load_dataset
from terrainml.pipeline.dataset import build_from_tables
from terrainml.pipeline.train_options import TrainOptions
from terrainml.pipeline.train import train
from terrainml.robot import load_robot
from terrainml.models.novelty import MOVING_MPS
from terrainml.stream.tick.config import ServingConfig
from terrainml.stream.tick.fusion import SETTLE_M, FusionConfig
from terrainml.stream.tick.predictor import Predictor

UNKNOWN = "SNOW"
SEGMENT_S = 30.0
MODEL = "svm+hgb"
#: the filter's settle_m served: the shipped one first (its table), then 0 (before 2026-12-05)
SETTLES = (SETTLE_M, 0.0)


def _log(msg: str) -> None:
    print(f"[unknown_ground_study {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def _course_order(tables, names: list[str]) -> tuple[list[str], list[str], list[str]]:
    """(course run ids, held-out known runs, SNOW runs): known and SNOW alternating."""
    by_class = runs_by_class(tables)
    snow = by_class[names.index(UNKNOWN)]
    known = [ids[-1] for c, ids in by_class.items() if names[c] != UNKNOWN]
    order = []
    for j, s in enumerate(snow):
        order += [known[j % len(known)], s]
    return order, known, snow


def _segments(tables, course: pd.DataFrame, order: list[str], robot) -> list[dict]:
    """The course's rows of each run (make_course takes up to SEGMENT_S from each, end to end)."""
    by_id = {str(t["run_id"].iloc[0]): t for t in tables}
    om = [c for c in course.columns if c.endswith("_omega_radps")]
    speed = np.abs(course[om].to_numpy(dtype=float)).mean(axis=1) * robot.wheel_radius_m
    dt = float(np.median(np.diff(course["t_s"].to_numpy())))
    out, start = [], 0
    for rid in order:
        n = min(len(by_id[rid]), int(round(SEGMENT_S / dt)))
        out.append({"run": rid, "rows": slice(start, start + n), "speed": speed, "dt": dt})
        start += n
    if start != len(course):
        raise RuntimeError(f"segments cover {start} rows of a {len(course)}-row course")
    return out


def _score(seg: dict, served: list[dict], label: str) -> dict:
    rows = seg["rows"]
    speed = seg["speed"][rows]
    moving = speed > MOVING_MPS
    reason = np.array([m["fallback_reason"] for m in served[rows]], dtype=object)
    name = np.array([m["terrain_name"] for m in served[rows]], dtype=object)
    unknown = reason == "unknown_terrain"
    dist = np.cumsum(speed * seg["dt"])
    first = int(np.argmax(unknown)) if unknown.any() else None
    return {"run": seg["run"], "moving": int(moving.sum()),
            "unknown_share": float(unknown[moving].mean()) if moving.any() else float("nan"),
            "right_share": float((name == label)[moving & ~unknown].sum() / moving.sum()) if moving.any()
            else float("nan"),
            "first_unknown_m": None if first is None else float(dist[first]),
            "reasons": pd.Series(reason[moving]).value_counts(normalize=True).round(3).to_dict()}


def measure() -> dict:
    robot = load_robot("husky")
    tables, report = load_dataset("borealtc", DATA, robot=robot)
    names = list(report.classes)
    order, known, snow = _course_order(tables, names)
    train_tables = [t for t in tables if str(t["run_id"].iloc[0]) not in known
                    and names[int(t["terrain"].iloc[0])] != UNKNOWN]
    spec = window_spec("chunks").resolve(robot, ["wheels", "currents", "imu"])
    ds = build_from_tables(train_tables, robot, spec=spec)
    course = make_course(tables, order, segment_s=SEGMENT_S, drop_imu=False)
    with TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = train(ds, Path(tmp) / "m", [MODEL], TrainOptions(folds=2, seed=0, ablation=False), progress=_log)
        t_train = time.perf_counter() - t0
        served = {s: _serve(Path(tmp) / "m", course, s) for s in SETTLES}
    segs = _segments(tables, course, order, robot)
    lab = [names[int(course["terrain"].iloc[s["rows"].start])] for s in segs]
    out = {"train_runs": len(train_tables), "held_known": known, "t_train_s": t_train,
           "cv": res.models[MODEL]["cv"].pooled["balanced_accuracy"], "by_settle": {}}
    for settle_m, ticks in served.items():
        rows = [_score(s, ticks, label) for s, label in zip(segs, lab)]
        out["by_settle"][settle_m] = {"snow": [r for r, label in zip(rows, lab) if label == UNKNOWN],
                                      "known": [r for r, label in zip(rows, lab) if label != UNKNOWN]}
    return out


def _serve(model: Path, course: pd.DataFrame, settle_m: float) -> np.ndarray:
    """The messages (as dicts) served tick by tick on ``course`` with the filter's ``settle_m``."""
    p = Predictor.from_model_dir(model, config=ServingConfig(fusion=FusionConfig(settle_m=settle_m)))
    cols = list(course.columns)
    _log(f"serving {len(course)} ticks, settle_m {settle_m:g}")
    try:
        return np.array([p.step(dict(zip(cols, row))).to_dict() for row in course.itertuples(index=False)],
                        dtype=object)
    finally:
        p.close()


def _f(x, d=1, scale=100.0) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{scale * x:.{d}f}"


def _weighted(rows: list[dict], key: str) -> float:
    """Moving-tick-weighted mean of ``key`` over segments that have moving ticks."""
    use = [r for r in rows if r["moving"] > 0]
    w = np.array([r["moving"] for r in use], dtype=float)
    return float(np.sum(w * [r[key] for r in use]) / w.sum()) if w.sum() > 0 else float("nan")


def _summary(snow: list[dict], known: list[dict]) -> tuple[int, list[float], float, float, float]:
    """(SNOW segments entered within 3 m, distances to each first unknown tick, SNOW moving ticks
    unknown, known moving ticks unknown, known moving ticks served their class)."""
    first = [r["first_unknown_m"] for r in snow]
    reached = [f for f in first if f is not None]
    return (sum(f <= 3.0 for f in reached), reached, _weighted(snow, "unknown_share"),
            _weighted(known, "unknown_share"), _weighted(known, "right_share"))


def markdown(m: dict) -> str:
    snow, known = m["by_settle"][SETTLES[0]]["snow"], m["by_settle"][SETTLES[0]]["known"]
    within, reached, snow_unknown, false_unknown, right_known = _summary(snow, known)
    w = np.array([r["moving"] for r in known], dtype=float)
    other = [f"- settle_m {s:g} m instead: within 3 m {a} of {len(snow)}, any {len(b)}; SNOW moving ticks "
             f"unknown {100 * c:.1f}%; known moving ticks unknown {100 * d:.1f}%, labelled class {100 * e:.1f}%."
             for s in SETTLES[1:] for a, b, c, d, e in [_summary(**m["by_settle"][s])]]
    still = sum(r["moving"] == 0 for r in snow)
    rows = [[r["run"], r["moving"], _f(r["unknown_share"]), _f(r["first_unknown_m"], 2, 1.0),
             ", ".join(f"{k or 'class'} {100 * v:.0f}%" for k, v in r["reasons"].items())] for r in snow]
    return "\n".join([
        "### SNOW served by a model that never saw SNOW (`benchmarks/unknown_ground_study.py`)", "",
        f"`{MODEL}` on `chunks` windows, all sensors, trained on {m['train_runs']} runs of the four other classes "
        f"(grouped 2-fold CV balanced accuracy {m['cv']:.3f}; {m['t_train_s'] / 60:.1f} min); held-out known runs "
        f"{', '.join(m['held_known'])}; a course of {SEGMENT_S:.0f} s segments alternating a held-out known run and "
        f"each of the {len(snow)} SNOW runs, served tick by tick.", "",
        f"- SNOW segments with an `unknown_terrain` tick within 3 m of wheel travel from their start: "
        f"**{within} of {len(snow)}**; with one at all: {len(reached)}; median distance to the first "
        f"{_f(float(np.median(reached)), 2, 1.0) if reached else 'n/a'} m.",
        f"- SNOW moving ticks served `unknown_terrain`: **{100 * snow_unknown:.1f}%** ({still} SNOW segments have "
        f"no moving tick: rim speed at or under {MOVING_MPS} m/s).",
        f"- Known held-out segments ({int(w.sum())} moving ticks): `unknown_terrain` on "
        f"**{100 * false_unknown:.1f}%**, the labelled class on {100 * right_known:.1f}%.",
        f"- The filter's settle_m {SETTLES[0]:g} m (stream/tick/fusion.SETTLE_M) serves these figures.", *other, "",
        markdown_table(["SNOW run", "moving ticks", "unknown_terrain %", "m to first unknown",
                        "served on moving ticks (fallback reason)"], rows), "",
        "Known held-out runs (each served several times, after a SNOW segment; moving ticks pooled):", "",
        markdown_table(["known run", "segments", "moving ticks", "unknown_terrain %", "labelled class %"],
                       [[run, sum(r["run"] == run for r in known), sum(r["moving"] for r in known if r["run"] == run),
                         _f(_weighted([r for r in known if r["run"] == run], "unknown_share")),
                         _f(_weighted([r for r in known if r["run"] == run], "right_share"))]
                        for run in m["held_known"]]), ""])


def main() -> int:
    print(markdown(measure()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
