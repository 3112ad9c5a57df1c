"""Real robots: the rotation sweep of served BorealTC courses without IMU, design §9, §11.

``run(quick)`` returns the "Course rotation sweep" section of BENCHMARKS.md.

The acceptance test of the servable path (``tests/realdata/test_servable_path.py``) serves one course, the
last run of every class, which a single run (ICE_12, driven faster than any other ICE run) can
sink or another pick can flatter. This sweep is the pre-declared, neutral measurement: for
k = 0, 1, ... up to the run count of the class with the fewest runs (runs sorted by id within each
class), the k-th run of every class is held out; a wheels-and-currents ``hgb`` model is trained on
all the other runs with the test's options (``--windows chunks``, grouped 2-fold CV, seed 0); the
held-out runs make one course (30 s from the middle of each, IMU columns dropped) built by
:func:`terrainml.experiments.borealtc.make_course`; :class:`terrainml.stream.tick.predictor.Predictor`
serves it tick by tick and :func:`terrainml.experiments.borealtc.course_score` scores it (moving
ticks, 3 s after each label change excluded) -- the same helpers the test uses.

Reported: per k, the share of moving ticks served the labelled class, their count and the share
per class; over all k, the tick-weighted and the unweighted mean share. Full mode trains 7 models
(about 2 min each on 2 cores with ``OMP_NUM_THREADS=1``); ``quick`` runs k = 0 and 1 only.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from benchmarks.bench_real_robots import DATA, SHORT, _pct, served_course
from terrainml.evaluation.report import markdown_table
from terrainml.experiments.borealtc import course_runs, runs_by_class
from terrainml.io.ingest import load_dataset
from terrainml.robot import load_robot

SEGMENT_S = 30.0


def _log(msg: str) -> None:
    print(f"[bench_course_sweep] {msg}", file=sys.stderr, flush=True)


def sweep(tables, report, robot, ks) -> list[dict]:
    rows = []
    for k in ks:
        held = course_runs(tables, k)
        t0 = time.perf_counter()
        score = served_course(tables, report, robot, "hgb", held=held, folds=2)
        score.update(k=k, held=held, secs=time.perf_counter() - t0)
        _log(f"k={k} {held}: share {_pct(score['share'])}% of {score['n_ticks']} moving ticks "
             f"({score['secs']:.0f} s)")
        rows.append(score)
    return rows


def means(rows: list[dict]) -> tuple[float, float]:
    """Tick-weighted and unweighted mean share over the courses that have moving ticks."""
    ok = [r for r in rows if r["n_ticks"] > 0 and np.isfinite(r["share"])]
    n = np.array([r["n_ticks"] for r in ok], float)
    s = np.array([r["share"] for r in ok], float)
    return (float((s * n).sum() / n.sum()) if n.sum() else float("nan"),
            float(s.mean()) if len(s) else float("nan"))


def run(quick: bool = False) -> str:
    if not DATA.is_dir():
        return "## Course rotation sweep\n\nBorealTC not found at `../shared/datasets/borealtc`; skipped.\n"
    robot = load_robot("husky")
    tables, report = load_dataset("borealtc", DATA, robot=robot)
    names = list(report.classes)
    n_k = min(len(ids) for ids in runs_by_class(tables).values())
    ks = list(range(min(2, n_k) if quick else n_k))
    rows = sweep(tables, report, robot, ks)
    w_mean, u_mean = means(rows)
    table = [[str(r["k"]), ", ".join(r["held"]), _pct(r["share"]), str(r["n_ticks"])]
             + [_pct(r["per_class"].get(n, np.nan)) for n in names] + [str(r["estimator_unhealthy"])]
             for r in rows]
    header = ["k", "held-out runs", "served %", "moving ticks", *(f"{SHORT.get(n, n)} %" for n in names),
              "unhealthy ticks"]
    n_ticks, n_unhealthy = (sum(r[key] for r in rows) for key in ("n_ticks", "estimator_unhealthy"))
    summary = (f"Mean share over {len(rows)} courses: tick-weighted {_pct(w_mean)}%, unweighted "
               f"{_pct(u_mean)}% ({n_ticks} moving ticks in all); `estimator_unhealthy` ticks in all: "
               f"{n_unhealthy}.")
    out = ["## Course rotation sweep", "",
           "Measured over every held-out course rather than one: for k = 0 .. "
           f"{n_k - 1} (the class with the fewest runs has {n_k}), the k-th run (by id) of every class is held "
           "out, `hgb` is trained on wheel speeds and motor currents of all other runs (`--windows chunks`, "
           f"seed 0), and a course of {SEGMENT_S:.0f} s of each held-out run, IMU dropped, is served tick by "
           "tick by `Predictor`. Score: share of moving ticks (> 0.2 m/s, 3 s after each label change "
           "excluded) served the labelled class; per-class shares are `n/a` where a run's segment has no "
           "moving tick. Goal: >= 80%." + (" Quick: k = 0, 1 only." if quick else ""), "",
           markdown_table(header, table), "", summary, ""]
    return "\n".join(out)


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
