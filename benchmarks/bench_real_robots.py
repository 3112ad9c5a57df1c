"""Real robots: BorealTC through the servable path (dataset build -> train -> predict).

``run(quick)`` returns the "Real robots" section of BENCHMARKS.md:

1. **Servable path vs protocol (b).** ``--windows chunks`` windows (the BorealTC authors' 1.7 s
   windows in 5 s chunks, :mod:`terrainml.features.chunks`) trained by :func:`terrainml.pipeline.
   train.train` (``svm``, ``hgb``, ``svm+hgb``; grouped 5-fold CV by run, seed 0) next to
   :func:`terrainml.experiments.borealtc.run_protocol` protocol (b) on the same data: balanced
   accuracy and per-class recall side by side. The two paths build the same windows, folds and
   models, so their figures should agree; the section states the difference.
2. **A served course.** Wheels-and-currents only (IMU dropped): a model trained without the last
   run of every class serves a course of 30 s of each of those runs, concatenated; the share of
   moving ticks (3 s after each label change excluded) served the labelled class, per class, and
   the fallback reasons.

Full mode takes about 40 min on 2 cores; ``quick`` uses 4 windows per chunk and the trees only.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from tempfile import TemporaryDirectory

import numpy as np

from terrainml.evaluation.report import markdown_table
from terrainml.experiments.borealtc import (ProtocolData, course_runs, course_score, make_course,
                                            robot_track_m, run_protocol)
from terrainml.features.windows import window_spec
from terrainml.io.ingest import load_dataset
from terrainml.pipeline.dataset import build_from_tables
from terrainml.pipeline.train_options import TrainOptions
from terrainml.pipeline.train import train
from terrainml.robot import load_robot
from terrainml.stream.tick.predictor import Predictor

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "datasets" / "borealtc"
SHORT = {"ASPHALT": "ASP", "FLOORING": "FLO", "ICE": "ICE", "SANDY_LOAM": "SAN", "SNOW": "SNO"}


def _log(msg: str) -> None:
    print(f"[bench_real_robots] {msg}", file=sys.stderr, flush=True)


def _pct(x: float) -> str:
    return f"{100 * x:.2f}" if np.isfinite(x) else "n/a"


def compare_paths(tables, report, robot, models, windows_per_chunk: int) -> tuple[list, dict]:
    """Rows (path, model, balanced acc., recall per class) of train and protocol (b)."""
    ds = build_from_tables(tables, robot, spec=window_spec("chunks", windows_per_chunk=windows_per_chunk))
    with TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = train(ds, Path(tmp) / "m", models, TrainOptions(folds=5, seed=0, ablation=False), progress=_log)
        t_train = time.perf_counter() - t0
    data = ProtocolData(ds.windows, None, report, robot_track_m(robot))  # type: ignore[arg-type]
    t0 = time.perf_counter()
    prot = run_protocol(data, "b", models)
    t_prot = time.perf_counter() - t0
    names = ds.class_names
    rows, diffs = [], {}
    for m in models:
        a, b = res.models[m]["cv"], prot[m]
        diffs[m] = a.pooled["balanced_accuracy"] - b.pooled["balanced_accuracy"]
        for path, r in (("servable (`train --windows chunks`)", a), ("protocol (b)", b)):
            rec = r.recall_per_class()
            rows.append([path, m, _pct(r.pooled["balanced_accuracy"])] + [_pct(rec.get(n, np.nan)) for n in names])
    return rows, {"diff": diffs, "t_train_s": t_train, "t_protocol_s": t_prot, "n_windows": len(ds.windows),
                  "names": names, "kept": ds.class_report[["class", "runs", "kept"]].values.tolist()}


def served_course(tables, report, robot, model: str, held: list[str] | None = None, folds: int = 5) -> dict:
    """Train ``model`` on wheels + currents of every run but ``held`` (default: the last run of
    every class), serve the 30 s course of the held runs tick by tick, score it (course_score)."""
    held = course_runs(tables) if held is None else held
    spec = window_spec("chunks").resolve(robot, ["wheels", "currents"])
    ds = build_from_tables([t for t in tables if str(t["run_id"].iloc[0]) not in held], robot, spec=spec)
    course = make_course(tables, held, segment_s=30.0)
    with TemporaryDirectory() as tmp:
        train(ds, Path(tmp) / "m", [model], TrainOptions(folds=folds, seed=0, ablation=False), progress=_log)
        p = Predictor.from_model_dir(Path(tmp) / "m")
        cols = list(course.columns)
        t0 = time.perf_counter()
        served = [p.step(dict(zip(cols, row))).to_dict() for row in course.itertuples(index=False)]
        t_serve = time.perf_counter() - t0
    out = course_score(course, served, report.classes, robot)
    out.update(held=held, model=model, serve_ms_per_tick=1e3 * t_serve / len(course))
    return out


def run(quick: bool = False) -> str:
    if not DATA.is_dir():
        return "## Real robots\n\nBorealTC not found at `../shared/datasets/borealtc`; skipped.\n"
    robot = load_robot("husky")
    tables, report = load_dataset("borealtc", DATA, robot=robot)
    models = ["hgb"] if quick else ["svm", "hgb", "svm+hgb"]
    rows, info = compare_paths(tables, report, robot, models, 4 if quick else 11)
    names = info["names"]
    course = served_course(tables, report, robot, "hgb")
    out = ["## Real robots", "",
           "BorealTC (Clearpath Husky, five terrains, 71 runs) through the servable path: `terrainml dataset "
           "build --format borealtc --windows chunks` / `terrainml train --format borealtc --windows chunks "
           "--model svm+hgb`, next to `terrainml evaluate-protocol -p b` on the same data "
           f"({info['n_windows']} windows; per class (runs, kept windows): "
           + ", ".join(f"{c} ({r}, {k})" for c, r, k in info["kept"]) + "). The `steady` rules of the "
           "reference robot kept 416 of 3,533 windows here (SANDY_LOAM none); `dataset build` now names "
           "such losses per class with a hint.", "",
           markdown_table(["path", "model", "balanced acc. %"] + [f"recall {SHORT.get(n, n)}" for n in names], rows),
           "", "Difference servable - protocol (b), balanced accuracy points: "
           + ", ".join(f"{m} {100 * d:+.2f}" for m, d in info["diff"].items())
           + f" (train {info['t_train_s'] / 60:.1f} min, protocol {info['t_protocol_s'] / 60:.1f} min).", "",
           "### A served course without IMU", "",
           f"Model `{course['model']}` on wheel speeds and motor currents only (`train --sensors wheels,currents`), "
           f"trained without the runs {', '.join(course['held'])}; a course of 30 s of each of them end to "
           "end, IMU file dropped, served tick by tick by `Predictor` (health checked only on the model's "
           "sensors).", "",
           markdown_table(["", "all classes"] + [SHORT.get(n, n) for n in names],
                          [["moving ticks served the labelled class %", _pct(course["share"])]
                           + [_pct(course["per_class"].get(n, np.nan)) for n in names]]),
           "", f"Moving ticks scored: {course['n_ticks']} (3 s after each label change excluded); "
           f"`estimator_unhealthy` ticks: {course['estimator_unhealthy']}; fallback reasons over all ticks: "
           f"{course['fallback_reasons']}; {course['serve_ms_per_tick']:.3f} ms per tick.", ""]
    return "\n".join(out)


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
