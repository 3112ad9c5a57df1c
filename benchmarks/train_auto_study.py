"""The figures of ``terrainml train`` choosing on the user's data, reproducible.

Not part of ``make bench`` (about an hour on 2 shared cores). Two measurements:

1. **BorealTC, the default** (``terrainml train --data ../shared/datasets/borealtc --format
   borealtc --out runs/boreal``: ``--windows auto --model auto``): every candidate's grouped
   5-fold CV figure, the nested (honest) figure, ECE before and after calibration per outer fold,
   the served replay of every outer fold's held-out runs, wall time and CPU time.
2. **The simulator** (``terrainml sim generate --runs-per-class 4 --duration-s 60 --seed 0
   --format parquet``; ``--windows short --model svm``, the simulator's served default, 4 folds):
   the same figures, for the ECE before and after calibration.

``python -m benchmarks.train_auto_study [--only boreal|sim] [-j N]`` prints the Markdown; the
model folders go to ``runs/train_auto_study/``.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from terrainml.evaluation.report import markdown_table
from terrainml.io.ingest import load_dataset
from terrainml.io.ingest import load_run
from terrainml.features.windows import window_spec
from terrainml.pipeline.autotrain import train_auto
from terrainml.pipeline.train_options import SelectionOptions, ReplayOptions, TrainOptions
from terrainml.pipeline.dataset import find_logs
from terrainml.robot import load_robot

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "datasets" / "borealtc"
OUT = Path("runs") / "train_auto_study"


def _log(msg: str) -> None:
    print(f"[train_auto_study {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def _f(x, d: int = 3, scale: float = 1.0) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{scale * x:.{d}f}"


def _cpu_s() -> float:
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _section(title: str, res, wall_s: float, cpu_s: float) -> list[str]:
    sel = res.selection
    rows = []
    for c in sel.candidates:
        cv = sel.cv.get(c.name)
        rows.append([c.name + (" (chosen)" if c == sel.chosen else ""),
                     "screened out" if cv is None else _f(cv.summary["balanced_accuracy"]["mean"]),
                     "" if cv is None else _f(cv.summary["balanced_accuracy"]["std"]),
                     "" if cv is None else _f(cv.pooled["balanced_accuracy"]),
                     str(sum(o["chosen"] == c.name for o in sel.outer))])
    best = max((sel.cv[c.name].summary["balanced_accuracy"]["mean"] for c in sel.candidates if c.name in sel.cv))
    best_pooled = max(sel.cv[c.name].pooled["balanced_accuracy"] for c in sel.candidates if c.name in sel.cv)
    outer = [[o["fold"] + 1, o["chosen"], _f(o["balanced_accuracy"]), _f(o["ece_before"]), _f(o["ece_after"]),
              _f(o["temperature"], 2)] for o in sel.outer]
    w = np.array([o["n_windows"] for o in sel.outer], dtype=float)
    ece_b = float(np.sum(w * [o["ece_before"] for o in sel.outer]) / w.sum())
    ece_a = float(np.sum(w * [o["ece_after"] for o in sel.outer]) / w.sum())
    rep = [[f["fold"] + 1, f["runs"], f.get("moving_ticks", 0), _f(f.get("right_share"), 1, 100),
            _f(f.get("right_share_settled"), 1, 100), _f(f.get("fallback_share"), 1, 100),
            _f(f.get("classifications_per_m"), 2), _f(f.get("median_change_m"), 2)] for f in res.replay]
    p = res.replay_pooled
    rep.append(["all", sum(f["runs"] for f in res.replay), p.get("moving_ticks", 0), _f(p.get("right_share"), 1, 100),
                "", _f(p.get("fallback_share"), 1, 100), _f(p.get("classifications_per_m"), 2),
                _f(p.get("median_change_m"), 2)])
    return [f"#### {title}", "",
            markdown_table(["candidate", "grouped CV bal. acc. (mean of folds)", "std", "pooled",
                            "chosen in outer folds"], rows), "",
            f"Chosen **{sel.chosen.name}**; nested (honest) balanced accuracy **{sel.honest['mean']:.3f} ± "
            f"{sel.honest['std']:.3f}** over the outer folds, {100 * (sel.honest['mean'] - best):+.1f} points from "
            f"the best candidate's CV figure ({best:.3f}); pooled over all outer folds' held-out windows "
            f"**{sel.honest['pooled']:.3f}**, {100 * (sel.honest['pooled'] - best_pooled):+.1f} points from the best "
            f"candidate's pooled CV figure ({best_pooled:.3f}). Not candidates: "
            + ("; ".join(f"`{s}` ({r})" for s, r in sel.infeasible.items()) or "none") + ".", "",
            markdown_table(["outer fold", "chosen", "bal. acc.", "ECE before", "ECE after", "temperature"], outer), "",
            f"ECE over the outer folds (window-weighted): **{ece_b:.3f} before, {ece_a:.3f} after** calibration "
            f"(temperature fitted on each fold's inner out-of-fold probabilities); served model's temperature "
            f"{sel.temperature:.2f}.", "",
            markdown_table(["fold", "runs", "moving ticks", "right %", "right % (3 s after changes out)",
                            "fallback %", "classifications / m", "median m to right class after a change"], rep), "",
            f"Wall time {wall_s / 60:.1f} min, CPU time {cpu_s / 60:.1f} min ("
            + ", ".join(f"{k.removesuffix('_s')} {v / 60:.1f}" for k, v in res.timing_s.items()) + " min); "
            f"{sel.timing_s.get('fits', 0)} fits.", ""]


def boreal(n_jobs: int) -> list[str]:
    robot = load_robot("husky")
    t0, c0 = time.perf_counter(), _cpu_s()
    tables, _ = load_dataset("borealtc", DATA, robot=robot)
    res = train_auto(tables, robot, OUT / "boreal", TrainOptions(n_jobs=n_jobs), progress=_log)
    return _section("BorealTC, `terrainml train --data ... --format borealtc --out ...` (defaults)", res,
                    time.perf_counter() - t0, _cpu_s() - c0)


def sim(n_jobs: int) -> list[str]:
    logs = OUT / "sim4_logs"
    if not logs.is_dir():
        cli = [str(Path(sys.executable).with_name("terrainml"))]
        subprocess.run(cli + ["sim", "generate", "--runs-per-class", "4", "--duration-s", "60", "--seed", "0",
                              "--format", "parquet", "--out", str(logs)], check=True)
    robot = load_robot(None)
    t0, c0 = time.perf_counter(), _cpu_s()
    tables = [load_run(p, robot=robot).table for p in find_logs(logs)]
    res = train_auto(tables, robot, OUT / "sim", TrainOptions(folds=4, n_jobs=n_jobs),
                     SelectionOptions(specs=(window_spec("short"),), models=("svm",)), ReplayOptions(segment_s=20.0),
                     progress=_log)
    return _section("Simulator (4 runs per class, 60 s, seed 0), `--windows short --model svm`, 4 folds", res,
                    time.perf_counter() - t0, _cpu_s() - c0)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", choices=["boreal", "sim"])
    ap.add_argument("-j", type=int, default=1)
    a = ap.parse_args()
    out = []
    if a.only in (None, "sim"):
        out += sim(a.j)
    if a.only in (None, "boreal"):
        out += boreal(a.j)
    print("\n".join(out))


if __name__ == "__main__":
    main()
