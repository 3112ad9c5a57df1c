"""Benchmark of the online predictor: per-tick latency, a one-hour replay, and the
closed-loop traction-control comparison in the simulator (design §12; see ``_closed_loop_section``).

Measured in one run:

* **per-tick processing** (``Predictor.step``: order gate, health, EKF step, ring buffer, policy,
  message) p50 / p99 / max, with classification (window cut + features + SVM) inline on the hop
  tick, and the same with classification *amortised*: run in the background thread and applied
  10 ticks later (what ``terrainml predict`` does), measured while paced at 100 Hz;
* **one-hour replay** at full speed (360 000 ticks, inline classification, the worst case for
  the tick path): ticks/s, multiple of real time, missed deadlines when paced at 100 Hz
  (simulated analytically from the measured per-tick times: tick k arrives at k x 10 ms, starts
  when the previous one is done, misses if it ends after the next arrival), peak RSS per minute
  (growth from minute 5 to minute 60);
* the reference: the offline batch path (``estimate_run`` over the same samples), ticks/s.

The classifier is the real chain: ``cut_windows`` + ``SVMClassifier`` (FeatureSet, scaler,
calibrated RBF SVC) trained here on
synthetic kinematic windows (8 slip levels, `terrainml.testing`), so its cost is the
production cost (a simulator-trained model has the same feature count and a similar number of
support vectors).
"""

from __future__ import annotations

import gc
import os
import time

import numpy as np
import pandas as pd

RATE_HZ = 100.0


def _segment(robot, seed: int, duration_s: float = 60.0) -> pd.DataFrame:
    """60 s of driving: start, cruise at 1 m/s with one slip level, brake; terrain = level."""
    from terrainml.testing import kinematic_run, trapezoid_speed

    level = seed % 8
    return kinematic_run(robot, duration_s=duration_s, seed=seed, terrain=level,
                         slip=0.02 + 0.05 * level, imu_acc_noise=0.005,
                         vx=lambda t: trapezoid_speed(t, 1.0, 1.0, 1.0, duration_s - 3.0),
                         run_id=f"bench{seed}")


def _train_classifier(robot):
    """WindowClassifier(cut_windows + the models owner's SVMClassifier) on synthetic windows."""
    from terrainml.estimation.run import estimate_run
    from terrainml.features.sets import FeatureSet
    from terrainml.features.windows import Windows, WindowSpec, cut_windows
    from terrainml.models.svm import SVMClassifier
    from terrainml.stream.tick.classify import WindowClassifier

    wins = []
    spec = WindowSpec()
    for seed in range(8):
        est = estimate_run(_segment(robot, 100 + seed, 40.0), robot)
        w, _ = cut_windows(est, robot, spec)
        wins.append(w)
    allw = Windows.concat(wins)
    model = SVMClassifier(FeatureSet.for_robot(robot), C_grid=[10.0], gamma_grid=["scale"],
                          inner_folds=2).fit(allw, allw.y)
    n_features = len(model.feature_names_)
    return WindowClassifier(model, robot, None, spec), (len(allw), n_features)


def _table(robot):
    from terrainml.lookup.table import DesiredSlipTable

    return DesiredSlipTable.build(robot)


def _samples(robot, n_ticks: int):
    """Generator of n_ticks samples: 60 s segments with fresh seeds, times made continuous."""
    from terrainml.stream.transports.sources import iter_table_samples

    k, seg = 0, 0
    while k < n_ticks:
        table = _segment(robot, seg)
        table["t_s"] = table["t_s"] + seg * 60.0
        for s in iter_table_samples(table):
            if k >= n_ticks:
                return
            yield s
            k += 1
        seg += 1


def _pacing(proc_s: np.ndarray, period_s: float = 1.0 / RATE_HZ) -> tuple[int, float]:
    """Missed deadlines and worst lateness (s) when ticks arrive every period_s."""
    finish = 0.0
    missed = 0
    worst = 0.0
    for k, d in enumerate(proc_s):
        arrive = k * period_s
        start = arrive if arrive > finish else finish
        finish = start + d
        late = finish - (arrive + period_s)
        if late > 0:
            missed += 1
            worst = max(worst, late)
    return missed, worst


def _pacing_amortised(tick_s: np.ndarray, cls_s: np.ndarray, lag: int = 10,
                      period_s: float = 1.0 / RATE_HZ) -> tuple[int, float]:
    """Missed deadlines on one dedicated core when classification runs in the background.

    Tick k (cost ``tick_s[k]``) arrives at k x period and has priority; a classification
    released at tick k (cost ``cls_s[k]``) uses the idle time between ticks and must be done by
    tick k + lag, which otherwise waits for it (as ``Predictor(config=ServingConfig(classify_lag_ticks=lag))`` does).
    """
    from collections import deque

    pending: deque = deque()  # [remaining_s, due_tick]
    t_free = 0.0
    missed, worst = 0, 0.0
    for k in range(len(tick_s)):
        arrive = k * period_s
        gap = arrive - t_free
        while gap > 0 and pending:
            use = min(gap, pending[0][0])
            pending[0][0] -= use
            gap -= use
            if pending[0][0] <= 0:
                pending.popleft()
        start = max(arrive, t_free)
        while pending and pending[0][1] <= k:  # due now: the tick waits for it
            start += pending.popleft()[0]
        finish = start + tick_s[k]
        if cls_s[k] > 0:
            pending.append([float(cls_s[k]), k + lag])
        late = finish - (arrive + period_s)
        if late > 0:
            missed += 1
            worst = max(worst, late)
        t_free = finish
    return missed, worst


class _CpuTimedClassifier:
    """Proxy recording the thread CPU time of each classification (for the pacing model)."""

    def __init__(self, clf):
        self.clf = clf
        self.class_ids = clf.class_ids
        self.last_cpu_s = 0.0

    def classify(self, window):
        u0 = time.thread_time()
        try:
            return self.clf.classify(window)
        finally:
            self.last_cpu_s = time.thread_time() - u0


def _rss_mb() -> float:
    import psutil

    return psutil.Process(os.getpid()).memory_info().rss / 2**20


# ---------------------------------------------------------------- closed loop (design §12)
CL_CLASSES = ("tilled_loam", "dry_sand", "wet_mud")
# (label, policy, run_closed_loop keyword overrides); "model" marks the predictor-served mode
CL_MODES = (
    ("no traction control", "none", {}),
    ("fixed 0.1 target", "fixed", {}),
    ("terrain-aware, true class (oracle)", "terrain-aware", {}),
    ("terrain-aware, SVM served by the predictor", "terrain-aware", {"model": True}),
    ("terrain-aware, served s_S in steady (design §10 literally)", "terrain-aware",
     {"steady_target": "served"}),
    ("terrain-aware, tracking PI + feed-forward, served s_S", "terrain-aware",
     {"steady_target": "served", "pid": {"mode": "track"}}),
)


def _cl_train_model(tmp, runs_per_class: int) -> str:
    """SVM on a small simulated labelled dataset (the `make demo` chain): generate -> windows -> train."""
    from terrainml.pipeline.dataset import build_dataset
    from terrainml.pipeline.train_options import TrainOptions
    from terrainml.pipeline.train import train
    from terrainml.robot import load_robot
    from terrainml.sim.generate import generate_dataset

    logs = os.path.join(tmp, "logs")
    generate_dataset(logs, runs_per_class, seed=2024, n_jobs=2, duration_s=60.0, fmt="parquet")
    ds = build_dataset(logs, load_robot(), n_jobs=2)
    out = os.path.join(tmp, "model")
    train(ds, out, models=("svm",), options=TrainOptions(folds=3, seed=0, n_jobs=2, ablation=False))
    return out


def _cl_one(terrain: str, mode: int, seed: int, scenario: str, duration_s: float,
            model_dir: str | None) -> dict:
    from terrainml.control.traction import tuned_config
    from terrainml.robot import load_robot
    from terrainml.experiments.closed_loop import ClosedLoopControl, run_closed_loop

    _label, policy, kw = CL_MODES[mode]
    kw = dict(kw)
    if kw.pop("model", False):
        kw["model"] = model_dir
    kw["pid"] = tuned_config(load_robot(), **kw.pop("pid", {}))
    rep = run_closed_loop(terrain, policy, control=ClosedLoopControl(**kw), duration_s=duration_s, seed=seed,
                          scenario=scenario)
    rep["mode"] = mode
    return rep


def _cruise_bound_rows() -> list[str]:
    """Steady cruise on nominal soil: energy per metre of the equal-slip equilibrium (what any
    controller that keeps the speed ends at) against the best unequal slip allocation over the
    three wheels (one wheel rolling free, two pushing), from the terramechanics curves."""
    from scipy.optimize import brentq

    from terrainml.classes import class_id
    from terrainml.lookup import terramechanics as tm
    from terrainml.robot import load_robot

    rb = load_robot()
    w = rb.static_wheel_loads_n()[0]
    n = rb.n_wheels
    rows = []
    for name in CL_CLASSES:
        p = tm.nominal_params(class_id(name))

        def h(x):
            return float(tm.gross_thrust_n(p, w, x, rb))

        def r(x):
            return float(tm.motion_resistance_n(p, w, x, rb))

        s_eq = brentq(lambda x: h(x) - r(x), p.free_slip + 1e-6, 0.8)
        e_eq = n * r(s_eq) / (1.0 - s_eq)
        g = lambda x: (n - 1) * (h(x) - r(x)) - r(0.0)  # noqa: E731
        grid = [x for x in np.linspace(s_eq, 0.9, 500) if g(x) > 0]
        if grid:
            s2 = brentq(g, s_eq, grid[0])
            e_free = (n - 1) * h(s2) / (1.0 - s2)
            free = f"{e_free:.1f} ({100 * (e_free / e_eq - 1):+.1f}%)"
        else:
            free = "infeasible"
        loose = n * r(0.0) / (1.0 - p.free_slip)
        rows.append(f"| {name} | {s_eq:.3f} | {e_eq:.1f} | {free} | {loose:.1f} "
                    f"({100 * (loose / e_eq - 1):+.1f}%) |")
    return rows


def _closed_loop_section(quick: bool) -> str:
    import tempfile

    from joblib import Parallel, delayed

    seeds = range(2 if quick else 5)
    step_seeds = range(1 if quick else 3)
    duration_s = 60.0
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        model_dir = _cl_train_model(tmp, 3 if quick else 5)
        t_train = time.perf_counter() - t0
        jobs = [(c, m, s, "straight", duration_s) for c in CL_CLASSES
                for m in range(len(CL_MODES)) for s in seeds]
        jobs += [(c, m, s, "step_stop_and_go", 30.0) for c in CL_CLASSES for m in (0, 1, 2)
                 for s in step_seeds]
        reps = Parallel(n_jobs=2)(delayed(_cl_one)(*j, model_dir) for j in jobs)
    t_all = time.perf_counter() - t0

    def agg(terrain, mode, scenario):
        rs = [r for r in reps if r["terrain"] == _cid(terrain) and r["mode"] == mode
              and r["scenario"] == scenario]
        return {k: float(np.mean([r[k] for r in rs])) for k in
                ("energy_j_per_m", "mean_speed_mps", "mean_tractive_efficiency",
                 "cruise_true_slip", "fallback_fraction")} | {
                "stuck_events": int(sum(r["stuck_events"] for r in rs)), "n": len(rs)}

    lines = [
        "## Closed-loop traction control in the simulator (`terrainml control closed-loop`)",
        "",
        f"Straight runs (design §6 scenario: 1 m/s^2 start to 1 m/s, cruise, brake), "
        f"{duration_s:.0f} s, seeds {list(seeds)} (each seed = one terrain draw, the same for every "
        f"mode), reference robot. Energy = mechanical energy at the wheels (integral of tau omega, "
        f"regeneration negative) / distance. Slip PID: `terrainml.control.traction.tuned_config` "
        f"(one-sided limiter, feed-forward of the wheel speed of the target slip at the estimated "
        f"wheel-centre speed, PI trim, 40 rad/s^2 slew) unless the mode says otherwise. Ratios are "
        f"against no traction control on the same seeds. SVM: trained here on "
        f"{3 if quick else 5} simulated runs per class ({t_train:.0f} s). Command per run: "
        f"`terrainml control closed-loop --terrain NAME --policy none|fixed|terrain-aware "
        f"[--model runs/NAME] --duration-s 60 --seed S`.",
        "",
        "| terrain | mode | energy J/m | ratio vs none | mean speed m/s | speed vs none | stuck "
        "events | mean tractive eff. | true cruise slip | fallback ticks |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    verdicts = []
    for terrain in CL_CLASSES:
        base = agg(terrain, 0, "straight")
        fixed = agg(terrain, 1, "straight")
        for m, (label, _p, _kw) in enumerate(CL_MODES):
            a = agg(terrain, m, "straight")
            lines.append(
                f"| {terrain} | {label} | {a['energy_j_per_m']:.1f} | "
                f"{a['energy_j_per_m'] / base['energy_j_per_m']:.3f} | {a['mean_speed_mps']:.3f} | "
                f"{100 * (a['mean_speed_mps'] / base['mean_speed_mps'] - 1):+.1f}% | "
                f"{a['stuck_events']} | {a['mean_tractive_efficiency']:.3f} | "
                f"{a['cruise_true_slip']:.3f} | {a['fallback_fraction']:.0%} |")
        for m in (2, 3):
            a = agg(terrain, m, "straight")
            e_ok = a["energy_j_per_m"] <= 0.85 * base["energy_j_per_m"]
            v_ok = abs(a["mean_speed_mps"] / base["mean_speed_mps"] - 1) <= 0.05
            s_ok = a["stuck_events"] <= fixed["stuck_events"]
            verdicts.append(
                f"| {terrain} | {CL_MODES[m][0]} | "
                f"{100 * (1 - a['energy_j_per_m'] / base['energy_j_per_m']):+.1f}% "
                f"({'met' if e_ok else 'NOT met'}) | "
                f"{100 * (a['mean_speed_mps'] / base['mean_speed_mps'] - 1):+.1f}% "
                f"({'met' if v_ok else 'NOT met'}) | {a['stuck_events']} vs {fixed['stuck_events']} "
                f"({'met' if s_ok else 'NOT met'}) |")
    lines += [
        "",
        "**Acceptance** (goals: terrain-aware >= 15% less energy per metre than no traction "
        "control, mean speed within 5%, no more stuck events than the fixed 0.1 target):",
        "",
        "| terrain | mode | energy saving vs none (goal >= 15%) | speed vs none (goal within 5%) "
        "| stuck events vs fixed 0.1 |",
        "|---|---|---|---|---|",
        *verdicts,
        "",
        "**Why the energy goal is not reachable here: the cruise slip is pinned by the soil.** On "
        "level ground at constant speed the wheels' net traction must be zero, H(s) = R(s). The "
        "deformable classes have a free slip s_f (no shear thrust below it) and a thrust curve that "
        "rises steeply just above it, so the equilibrium slip s_S sits just above s_f, and the "
        "energy per metre at cruise is sum R(s_S) / (1 - s_S), whatever the controller. The "
        "uncontrolled robot already cruises there (its velocity loop holds the wheel speed; the "
        "body settles at (1 - s_S) of it), and in these runs its slip never passes the traction "
        "peak: the 1 m/s^2 start needs mu_net of only 0.1, which all three soils give just above "
        "s_S. A controller can only (a) hold a lower slip: no thrust, the robot slows and stalls "
        "(the fixed 0.1 rows), (b) govern the slip instead of the speed (tracking with "
        "feed-forward): on a terrain draw whose cruise slip differs from the nominal s_S the "
        "robot is pushed to more slip (more sinkage and shear, more energy) or held below what "
        "the soil needs (slower, stuck events) (the tracking rows), or (c) cap the slip at the traction peak: "
        "identical to no control, because the cap is never reached (the oracle / SVM rows). The "
        "best possible allocation of slip over the three wheels at cruise, from the same "
        "terramechanics curves (nominal soil):",
        "",
        "| terrain | cruise slip s_S | E/m, equal slips (J/m) | E/m, one wheel free-rolling, two "
        "pushing | loose lower bound 3 R(0) / (1 - s_f) (not reachable: H(s_f) = 0) |",
        "|---|---|---|---|---|",
        *_cruise_bound_rows(),
        "",
        "So at most about 4% (tilled loam, by dragging one wheel) is available at cruise, and a "
        "per-class desired slip (one target for every wheel) cannot take even that.",
        "",
        "Where traction control does pay (supplementary): a *step* speed command (no "
        "acceleration limit; 4 s go, 2 s stop, 30 s, seeds "
        f"{list(step_seeds)}) spins the wheels far past the traction peak at every start; the "
        "limiter caps them at the class's peak:",
        "",
        "| terrain | mode | energy J/m | ratio vs none | mean speed m/s | speed vs none | stuck events |",
        "|---|---|---|---|---|---|---|",
    ]
    for terrain in CL_CLASSES:
        base = agg(terrain, 0, "step_stop_and_go")
        for m in (0, 1, 2):
            a = agg(terrain, m, "step_stop_and_go")
            lines.append(
                f"| {terrain} | {CL_MODES[m][0]} | {a['energy_j_per_m']:.1f} | "
                f"{a['energy_j_per_m'] / base['energy_j_per_m']:.3f} | {a['mean_speed_mps']:.3f} | "
                f"{100 * (a['mean_speed_mps'] / base['mean_speed_mps'] - 1):+.1f}% | "
                f"{a['stuck_events']} |")
    lines += ["", f"Closed-loop section: {len(jobs)} simulated runs + training in {t_all:.0f} s "
              "(2 processes).", ""]
    return "\n".join(lines)


def _cid(name: str) -> int:
    from terrainml.classes import class_id

    return class_id(name)


def run(quick: bool = False) -> str:
    from terrainml.estimation.run import estimate_run
    from terrainml.robot import load_robot
    from terrainml.stream.tick.config import ServingConfig
    from terrainml.stream.tick.predictor import Predictor

    robot = load_robot()
    table = _table(robot)
    clf, xshape = _train_classifier(robot)

    # ---- reference: offline batch estimation over 10 minutes of the same samples
    ref_ticks = 6000 if quick else 60000
    frames = []
    for seg in range(ref_ticks // 6000):
        t = _segment(robot, seg)
        t["t_s"] += seg * 60.0
        frames.append(t)
    big = pd.concat(frames, ignore_index=True)
    t0 = time.perf_counter()
    estimate_run(big, robot)
    ref_tps = len(big) / (time.perf_counter() - t0)
    del big, frames

    # ---- the long replay at full speed, inline classification (worst case on the tick path)
    minutes = 10 if quick else 60
    n = int(minutes * 60 * RATE_HZ)
    proc = np.empty(n)
    cpu = np.empty(n)
    cls_cpu = np.zeros(n)
    is_cls = np.zeros(n, dtype=bool)
    rss = []
    timed = _CpuTimedClassifier(clf)
    pred = Predictor(robot, table, timed)
    gc.collect()
    gc.freeze()  # as `terrainml predict` does after loading the model
    t_start = time.perf_counter()
    for k, s in enumerate(_samples(robot, n)):
        timed.last_cpu_s = 0.0
        c0, u0 = time.perf_counter(), time.thread_time()
        pred.step(s)
        proc[k] = time.perf_counter() - c0
        cpu[k] = time.thread_time() - u0
        cls_cpu[k] = timed.last_cpu_s
        is_cls[k] = pred.scheduler.last_attempt_t == s.t_s
        if k % 6000 == 5999:
            rss.append(_rss_mb())
    wall = time.perf_counter() - t_start
    missed, worst = _pacing(proc)
    missed_cpu, worst_cpu = _pacing(cpu)
    missed_am, worst_am = _pacing_amortised(cpu - cls_cpu, cls_cpu)
    n_slow = int(np.count_nonzero(cpu - cls_cpu > 1.0 / RATE_HZ))
    cls = np.array(pred.scheduler.classify_ms)
    stats = pred.stats()
    tps = n / wall
    ms = proc * 1e3
    p50, p99, pmax = np.percentile(ms, [50, 99, 100])
    c50, c99 = np.percentile(cpu * 1e3, [50, 99])
    hop = int(round(0.5 * RATE_HZ))
    plain_p99 = float(np.percentile(ms[~is_cls], 99))
    mean_cls = float(cls.mean()) if cls.size else 0.0
    cls_cpu_mean = float(cls_cpu[is_cls].mean() * 1e3) if is_cls.any() else 0.0
    rss5 = rss[4] if len(rss) >= 5 else rss[0]
    growth = (max(rss[4:]) - rss5) / rss5 * 100 if len(rss) >= 5 else float("nan")

    # ---- amortised for real: background classification, paced at 100 Hz
    paced_s = 10 if quick else 30
    pred2 = Predictor(robot, table, clf, config=ServingConfig(classify_lag_ticks=10))
    m = int(paced_s * RATE_HZ)
    proc2 = np.empty(m)
    cpu2 = np.empty(m)
    paced_samples = list(_samples(robot, m))
    t_wall0 = time.perf_counter()
    for k, s in enumerate(paced_samples):
        delay = t_wall0 + k / RATE_HZ - time.perf_counter()
        if delay > 0:
            time.sleep(delay)  # sleeping releases the GIL, as a blocking socket read does
        c0, u0 = time.perf_counter(), time.thread_time()
        pred2.step(s)
        proc2[k] = time.perf_counter() - c0
        cpu2[k] = time.thread_time() - u0
    pred2.close()
    q50, q99, qmax = np.percentile(proc2 * 1e3, [50, 99, 100])
    u50, u99 = np.percentile(cpu2 * 1e3, [50, 99])
    missed2, _ = _pacing(proc2)

    lines = [
        "## Online predictor (`terrainml predict`)",
        "",
        f"Chain: order gate + health + EKF step (`OnlineEstimator`, preset robust) + ring buffer + "
        f"policy + message per tick; every 0.5 s `cut_windows` + `FeatureSet` "
        f"({xshape[1]} features) + SVM on the latest 2 s window. Reference robot (3 wheels). "
        f"Synthetic kinematic drives (60 s segments, start/cruise/brake, 8 slip levels).",
        "",
        "| measure | value |",
        "|---|---|",
        f"| per-tick p50 / p99 / max, classification inline (full-speed replay) | "
        f"{p50:.3f} / {p99:.3f} / {pmax:.3f} ms |",
        f"| per-tick p99 of the ticks without a classification ({(~is_cls).mean():.0%} of ticks) | "
        f"{plain_p99:.3f} ms |",
        f"| classification (cut + features + SVM) mean / p99 | {mean_cls:.2f} / "
        f"{np.percentile(cls, 99) if cls.size else 0:.2f} ms (once per 50 ticks: "
        f"{mean_cls / hop:.3f} ms per tick amortised) |",
        f"| **per-tick p50 / p99 / max, classification amortised** (background thread, "
        f"applied 10 ticks later; paced at 100 Hz for {paced_s} s) | "
        f"**{q50:.3f} / {q99:.3f} / {qmax:.3f} ms** (goal p99 <= 2 ms) |",
        f"| same run, CPU time of the tick thread p50 / p99 (excludes preemption by other "
        f"processes on a shared machine) | {u50:.3f} / {u99:.3f} ms |",
        f"| missed 10 ms deadlines in the paced run | {missed2} of {m} |",
        f"| machine load average during the run (2 cores) | {os.getloadavg()[0]:.2f} |",
        f"| {minutes}-minute replay at full speed | {tps:,.0f} ticks/s = {tps / RATE_HZ:.0f}x real time "
        f"({wall:.0f} s) |",
        f"| same replay, CPU time of the tick thread p50 / p99 | {c50:.3f} / {c99:.3f} ms |",
        f"| **missed deadlines paced at 100 Hz, classification amortised** (analytic, one dedicated "
        f"core, from the replay's per-tick CPU times: ticks first, classification ({cls_cpu_mean:.1f} ms "
        f"CPU each) in the idle time, due 10 ticks later) | **{missed_am} of {n}** "
        f"(worst lateness {worst_am * 1e3:.2f} ms; ticks over 10 ms CPU without classification: {n_slow}) |",
        f"| missed deadlines paced at 100 Hz, classification inline (analytic, CPU times / wall "
        f"times) | {missed_cpu} / {missed} of {n} (worst lateness {worst_cpu * 1e3:.1f} / "
        f"{worst * 1e3:.1f} ms) |",
        f"| peak RSS minute 5 -> minute {minutes} | {rss5:.0f} -> {max(rss[4:]) if len(rss) >= 5 else 0:.0f} MiB "
        f"({growth:+.1f}%; goal <= 5%) |",
        f"| classifications / classifier errors / unsteady windows | {stats['classifications']} / "
        f"{stats['classifier_errors']} / {stats['unsteady_windows']} |",
        f"| reference: offline `estimate_run` (batch) | {ref_tps:,.0f} ticks/s; online / offline = "
        f"{tps / ref_tps:.2f} |",
        "",
    ]
    return "\n".join(lines) + "\n" + _closed_loop_section(quick)


if __name__ == "__main__":  # pragma: no cover
    import sys

    print(run(quick="--quick" in sys.argv))
