"""Study: can a window that straddles a terrain transition name the new terrain?

Not part of ``make bench`` (``python -m benchmarks.straddle_study``, about 3 min on 2 cores); it
reproduces the offline figures behind the transition work in docs/stream.md and BENCHMARKS.md
("Serving through stop-and-go and transitions"). Training windows: both simulated courses
(``course_stop_and_go``, ``mixed``) of the training seeds 9501-9508; test windows: the tuning
courses (seeds 9201-9202, 9301-9312). No held-out serving seed is read. ``short`` windows,
labelled with the terrain at their end; a window *straddles* when the terrain under the body
origin changes inside it.

1. Classifier families on the same features (``FeatureSet`` "all"): share right on clean and
   on straddling test windows, and the cost of one window's ``predict_proba`` (thread CPU);
   then the SVM again on the courses of 48 training seeds (9801-9848, what
   ``benchmarks/bench_serving.py`` trains on): more transitions seen, more straddles named.
2. Per-wheel terrain: one SVM on a wheel's own slip and current plus the body channels,
   labelled with the terrain under that wheel (the simulator's wheel positions); share right
   on the wheel's own clean windows, and how often each wheel names the origin's new terrain
   on the windows where the robot straddles.
3. Unmixing given the class before the change (A, true): the straddling window's standardised
   features as (1 - w) mu_A + w mu_B, B and w searched, diagonal pooled variance.
"""

from __future__ import annotations

import time

import numpy as np
from joblib import Parallel, delayed
from sklearn.ensemble import ExtraTreesClassifier, HistGradientBoostingClassifier
from sklearn.linear_model import LogisticRegression
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC

TRAIN_SEEDS = tuple(range(9501, 9509))
MANY_TRAIN_SEEDS = tuple(range(9801, 9849))
TUNING_SEEDS = (9201, 9202) + tuple(range(9301, 9313))
SCENARIOS = ("course_stop_and_go", "mixed")


def _course(scenario: str, seed: int):
    """Run table of one course and the terrain under each wheel per row (n_rows, N): the class of
    the layout cell the simulator's physics used for that wheel (its ``cell`` log block)."""
    from terrainml.sim.generate import simulate
    from terrainml.sim.output import _rows100, run_table

    from benchmarks.bench_serving import SPEED_MPS

    res = simulate(None, scenario, speed_mps=SPEED_MPS, duration_s=120.0, seed=seed)
    rows = _rows100(res)
    wheel_terrain = res.terrain.cell_class[res.wblock("cell")[rows].astype(np.int64)]
    return run_table(res, f"{scenario}{seed}"), wheel_terrain


def _windows(seeds, robot, spec):
    """Windows of both courses of ``seeds`` with straddle flags and per-wheel end labels."""
    from terrainml.pipeline.dataset import build_from_tables

    out = Parallel(n_jobs=2)(delayed(_course)(sc, s) for s in seeds for sc in SCENARIOS)
    tables = [t for t, _ in out]
    ds = build_from_tables(tables, robot, "robust", spec, n_jobs=2)
    truth = {str(t["run_id"].iloc[0]): (t["t_s"].to_numpy(), t["terrain"].to_numpy(), wt) for t, wt in out}
    meta = ds.windows.meta
    n, N = len(meta), robot.n_wheels
    straddle, first = np.zeros(n, bool), np.zeros(n, int)
    wheel_label, wheel_straddle = np.zeros((n, N), int), np.zeros((n, N), bool)
    for i, (rid, a, b) in enumerate(zip(meta["run_id"], meta["t_start_s"], meta["t_end_s"])):
        t, ter, wt = truth[str(rid)]
        sel = (t >= a) & (t <= b)
        lab = ter[sel]
        straddle[i], first[i] = len(np.unique(lab[lab >= 0])) > 1, lab[0]
        for k in range(N):
            w = wt[sel, k]
            wheel_label[i, k], wheel_straddle[i, k] = w[-1], len(np.unique(w[w >= 0])) > 1
    return ds, straddle, first, wheel_label, wheel_straddle


def _cost_ms(clf, x: np.ndarray, n: int = 50) -> float:
    clf.predict_proba(x)
    c0 = time.thread_time()
    for _ in range(n):
        clf.predict_proba(x)
    return (time.thread_time() - c0) / n * 1e3


def _families(F_tr, y_tr, F_te, y_te, strad) -> list[str]:
    lines = ["| classifier | clean windows right | straddling windows right | one window, ms |", "|---|---|---|---|"]
    models = {"SVM (RBF, C 10)": make_pipeline(StandardScaler(), SVC(C=10, gamma="scale", class_weight="balanced",
                                                                       probability=True, random_state=0)),
              "logistic regression": make_pipeline(StandardScaler(), LogisticRegression(C=1.0, max_iter=3000)),
              "boosted trees (300)": HistGradientBoostingClassifier(max_iter=300, random_state=0),
              "extra trees (500)": ExtraTreesClassifier(500, n_jobs=1, random_state=0)}
    for name, clf in models.items():
        clf.fit(F_tr, y_tr)
        p = clf.predict(F_te)
        lines.append(f"| {name} | {np.mean(p[~strad] == y_te[~strad]):.1%} | "
                     f"{np.mean(p[strad] == y_te[strad]):.1%} | {_cost_ms(clf, F_te[:1]):.2f} |")
    return lines


def _per_wheel(tr, te, robot) -> list[str]:
    from terrainml.features.sets import FeatureSet

    ch = list(tr[0].windows.channels)
    body = [c for c in ch if not c.startswith(("slip_", "current_"))]
    names = ["slip_1", "current_1"] + body
    fs = FeatureSet(subset="all", channel_names=names, torque_constant_nm_per_a=robot.torque_constant_nm_per_a,
                    wheel_radius_m=robot.wheel_radius_m, wheel_loads_n=tuple(robot.static_wheel_loads_n()[:1]))

    def one_wheel(ds, k):  # wheel k's own channels in the place of wheel 1's, body channels as they are
        idx = [ch.index(f"slip_{k}"), ch.index(f"current_{k}")] + [ch.index(c) for c in body]
        return np.nan_to_num(ds.windows.X[:, idx, :])

    fs.fit(one_wheel(tr[0], 1))
    N = robot.n_wheels
    F_tr = np.concatenate([fs.transform(one_wheel(tr[0], k)) for k in range(1, N + 1)])
    y_tr = np.concatenate([tr[3][:, k] for k in range(N)])
    ok = np.isfinite(F_tr).all(axis=1)
    clf = make_pipeline(StandardScaler(), SVC(C=10, gamma="scale", class_weight="balanced")).fit(F_tr[ok], y_tr[ok])
    y_te, strad = te[0].windows.y, te[1]
    lines = ["| wheel (x, y in m) | own clean windows right | robot straddling: names the origin's new terrain |",
             "|---|---|---|"]
    for k, w in enumerate(robot.wheels):
        p = clf.predict(np.nan_to_num(fs.transform(one_wheel(te[0], k + 1))))
        clean = ~te[4][:, k]
        lines.append(f"| {w.name} ({w.x_m:+.2f}, {w.y_m:+.2f}) | {np.mean(p[clean] == te[3][clean, k]):.1%} | "
                     f"{np.mean(p[strad] == y_te[strad]):.1%} |")
    return lines


def _unmix(F_tr, y_tr, clean_tr, F_te, y_te, strad, first) -> float:
    mu0, sd0 = F_tr[clean_tr].mean(axis=0), F_tr[clean_tr].std(axis=0) + 1e-9
    Z, Zt = (F_tr - mu0) / sd0, (F_te - mu0) / sd0
    classes = np.unique(y_tr)
    mu = {k: Z[clean_tr & (y_tr == k)].mean(axis=0) for k in classes}
    var = np.mean([Z[clean_tr & (y_tr == k)].var(axis=0) for k in classes], axis=0) + 1e-3
    weights = np.linspace(0.1, 1.0, 10)
    right = []
    for i in np.flatnonzero(strad):
        a = first[i]
        cost = {(b, w): np.sum((Zt[i] - ((1 - w) * mu[a] + w * mu[b])) ** 2 / var)
                for b in classes if b != a for w in weights}
        right.append(min(cost, key=cost.get)[0] == y_te[i])
    return float(np.mean(right))


def run(quick: bool = False) -> str:
    from terrainml.features.sets import FeatureSet
    from terrainml.features.windows import window_spec
    from terrainml.robot import load_robot

    t0 = time.perf_counter()
    robot = load_robot()
    spec = window_spec("short", label_at="end")
    tr = _windows(TRAIN_SEEDS[:2] if quick else TRAIN_SEEDS, robot, spec)
    te = _windows(TUNING_SEEDS[:2] if quick else TUNING_SEEDS, robot, spec)
    fs = FeatureSet.for_robot(robot, subset="all").fit(tr[0].windows)
    F_tr, F_te = fs.transform(tr[0].windows), np.nan_to_num(fs.transform(te[0].windows))
    ok = np.isfinite(F_tr).all(axis=1)
    F_tr, y_tr, strad_tr = F_tr[ok], tr[0].windows.y[ok], tr[1][ok]
    y_te, strad = te[0].windows.y, te[1]
    lines = ["## Straddling windows (`benchmarks/straddle_study.py`)", "",
             f"Training windows {len(y_tr)} ({strad_tr.sum()} straddling) from the courses of seeds "
             f"{TRAIN_SEEDS[0]}-{TRAIN_SEEDS[-1]}; test windows {len(y_te)} ({strad.sum()} straddling) from the "
             f"tuning courses; `short` windows labelled at their end.", ""]
    lines += _families(F_tr, y_tr, F_te, y_te, strad)
    many = _windows(MANY_TRAIN_SEEDS[:4] if quick else MANY_TRAIN_SEEDS, robot, spec)
    F_many, y_many = fs.transform(many[0].windows), many[0].windows.y
    ok = np.isfinite(F_many).all(axis=1)
    svm = make_pipeline(StandardScaler(), SVC(C=10, gamma="scale", class_weight="balanced")).fit(F_many[ok], y_many[ok])
    p = svm.predict(F_te)
    lines += [f"| SVM (RBF, C 10), courses of {len(MANY_TRAIN_SEEDS)} training seeds ({ok.sum()} windows, "
              f"{many[1][ok].sum()} straddling) | {np.mean(p[~strad] == y_te[~strad]):.1%} | "
              f"{np.mean(p[strad] == y_te[strad]):.1%} | - |", ""]
    lines += ["Per-wheel terrain (one SVM, a wheel's own slip and current plus the body channels):", ""]
    lines += _per_wheel(tr, te, robot) + [""]
    lines += [f"Unmixing given the class before the change: the new terrain named on "
              f"{_unmix(F_tr, y_tr, ~strad_tr, F_te, y_te, strad, te[2]):.1%} of the straddling windows.", "",
              f"_straddle_study took {time.perf_counter() - t0:.0f} s._", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    import sys

    print(run(quick="--quick" in sys.argv))
