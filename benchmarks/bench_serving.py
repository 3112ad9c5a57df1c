"""Benchmark of serving through stop-and-go and terrain transitions (design §10-11).

Measured in one run, on held-out simulated courses (:data:`EVAL_SEEDS`, fixed here before any
tuning and never used for it; the fusion settings were tuned on :data:`TUNING_SEEDS` only):

* courses ``course_stop_and_go`` (the mixed-terrain course driven stop-and-go: legs 1-4 m, stops
  1-3 s, ramped and step starts, five terrains, >= 4 classes with transitions) and ``mixed``
  (the demo's course, cruising), replayed through ``Predictor`` with the model's window spec;
* **served-class accuracy** over ALL moving ticks (true body speed >= 0.05 m/s), fallback ticks
  counted wrong;
* **after a transition**: distance travelled (true odometry) until the right class is served,
  median over transitions; fallback share of moving ticks after the first 2 m of a run;
  served-class switches (changes of the named class, fallback gaps skipped) against the true
  number of transitions;
* **cost**: one classification update (cut + features + model) on the serving path (column
  arrays from the ring, selected features only) against today's path in the same run
  (``to_frame`` DataFrame of the ring + ``cut_windows`` on it + features + model), on the same
  ring snapshots; per-tick p50 / p99 with updates inline at the spec's online hop.

The model: ``SVMClassifier`` as ``terrainml train`` builds it, trained on the simulated recipe
``sim_default`` (5 runs per class, so each class has each of the recipe's 5 scenarios, cached)
plus both courses on :data:`TRAIN_COURSE_SEEDS` (terrain transitions: with the ``short`` spec the
windows that straddle one are labelled with the terrain at their end), cut with the window spec
under test. ``$TERRAINML_SERVING_SEEDS`` names another held-out set (comma-separated seeds).

A second section serves the same held-out courses with the model a team trains on its first
logs, through the CLI (:func:`user_model`: ``sim generate --runs-per-class 6 --seed 101``, then
``train --model svm --folds 3``, windows chosen by ``train``, no transition course), scored by
``train``'s own replay engine (:func:`terrainml.pipeline.replay.replay_course`): where the moving
ticks went (:mod:`terrainml.stream.app.tick_losses`) and the most any classifier of the model's
windows could serve right (:func:`window_bound`). ``--user-model`` prints that section alone
(``--tuning``: on the tuning seeds).
"""

from __future__ import annotations

import copy
import functools
import json
import os
import time

import numpy as np

from terrainml.features.windows import Windows, cut_windows
from terrainml.models.novelty import proba_and_features
from terrainml.stream.app.scoring import MOVING_TICK_MPS
from terrainml.stream.tick.predictor import Predictor
from terrainml.stream.tick.ring import is_label
from terrainml.stream.transports.sources import iter_table_samples

#: held out: declared on 2026-12-02 before the 48-seed training courses and the 3-window confirmation
#: were measured on them, never tuned on (9101-9104, 9401-9404 and 9601-9604 were used and retired)
EVAL_SEEDS = tuple(range(9701, 9709))
TUNING_SEEDS = (9201, 9202) + tuple(range(9301, 9313))  # fusion settings were chosen on these
#: a fresh held-out set can be named without editing this file: ``TERRAINML_SERVING_SEEDS=9401,9402``
SEEDS_ENV = "TERRAINML_SERVING_SEEDS"
#: transition courses added to the training set (disjoint from every tuning and held-out seed):
#: 48 seeds, 96 courses. With the courses of 8 seeds (9501-9508) straddling windows were named
#: right 47% of the time and switches were 1.38 / 1.69 per transition on held-out courses;
#: with 48, 81% (benchmarks/straddle_study.py, docs/stream.md "Transitions")
TRAIN_COURSE_SEEDS: tuple[int, ...] = tuple(range(9801, 9849))
SPEED_MPS = 0.8


def _with_courses(ds, scenarios, seeds, duration_s: float):
    """``ds`` plus the windows of simulated courses with terrain transitions (same spec, robot)."""
    import pandas as pd

    from terrainml.pipeline.dataset import Dataset, build_from_tables

    tables = [_course(sc, seed, duration_s) for seed in seeds for sc in scenarios]
    extra = build_from_tables(tables, ds.robot, ds.preset, ds.spec, n_jobs=2)
    wins = Windows.concat([ds.windows, extra.windows], channels=ds.windows.channels,
                          n_samples=ds.spec.n_samples, rate_hz=ds.spec.rate_hz)
    wins.attrs.update(ds.windows.attrs)
    ids = sorted(set(ds.class_ids) | set(extra.class_ids))
    names = dict(zip(ds.class_ids, ds.class_names)) | dict(zip(extra.class_ids, extra.class_names))
    return Dataset(wins, pd.concat([ds.runs, extra.runs], ignore_index=True), ds.counts, ds.robot,
                   ds.spec, ds.preset, ids, [names[i] for i in ids], ds.class_report)


def _model(spec_name: str, runs_per_class: int, out, course_seeds=TRAIN_COURSE_SEEDS):
    from terrainml.experiments.recipes import load_recipe, simulated_dataset
    from terrainml.features.windows import window_spec
    from terrainml.pipeline.train_options import TrainOptions
    from terrainml.pipeline.train import train

    r = load_recipe("sim_default")
    r["window"] = window_spec(spec_name).to_dict()
    ds = simulated_dataset(r, runs_per_class=runs_per_class, fmt="parquet")
    if course_seeds:
        ds = _with_courses(ds, ("course_stop_and_go", "mixed"), course_seeds, 120.0)
    res = train(ds, out, models=("svm",), options=TrainOptions(folds=3, seed=0, n_jobs=2, ablation=False))
    summ = (res.manifest.get("metrics_summary") or {}).get("svm", {})
    return out, len(ds.windows), summ.get("balanced_accuracy", {}).get("mean", float("nan"))


@functools.lru_cache(maxsize=None)
def _held_out_course(scenario: str, seed: int, duration_s: float):
    """A held-out course's run table, simulated once per run of the benchmark (read only: every
    section and the bound read the same tables)."""
    return _course(scenario, seed, duration_s)


def _course(scenario: str, seed: int, duration_s: float):
    from terrainml.sim.generate import simulate
    from terrainml.sim.output import run_table

    return run_table(simulate(None, scenario, speed_mps=SPEED_MPS, duration_s=duration_s,
                              seed=seed), f"{scenario}{seed}")


def serve_course(model_dir, table, **predictor_kw) -> dict:
    """Replay a labelled course; metrics of what was served against the truth under the robot."""
    truth = table["terrain"].to_numpy()
    speed = np.hypot(table["gt_vx_mps"], table["gt_vy_mps"]).to_numpy()
    odo = np.concatenate([[0.0], np.cumsum(speed[1:] * np.diff(table["t_s"].to_numpy()))])
    inp = table.drop(columns=[c for c in table.columns if c.startswith("gt_") or c in ("terrain", "run_id")])
    pred = Predictor.from_model_dir(model_dir, **predictor_kw)
    served, fb, tick_ms = [], [], []
    for s in iter_table_samples(inp):
        m = pred.step(s)
        served.append(m.terrain_class)
        fb.append(m.fallback)
        tick_ms.append(m.processing_ms)
    pred.close()
    served, fb = np.array(served), np.array(fb)
    moving = speed >= MOVING_TICK_MPS
    right = (served == truth) & ~fb
    trans = np.flatnonzero(np.diff(truth) != 0) + 1
    dist = []
    for k in trans:
        ok = np.flatnonzero(right[k:])
        dist.append(odo[k + ok[0]] - odo[k] if ok.size else np.inf)
    named = served[~fb]
    switches = int(np.sum(named[1:] != named[:-1])) if named.size else 0
    after2 = moving & (odo >= 2.0)
    return {"moving": int(moving.sum()), "right": int((right & moving).sum()),
            "fallback_after_2m": int((fb & after2).sum()), "after_2m": int(after2.sum()),
            "dist_m": dist, "switches": switches, "transitions": int(len(trans)),
            "tick_ms": tick_ms, "stats": pred.stats()}


def _ring_snapshots(model_dir, table, n: int):
    """A (closed) predictor replayed over ``table`` and up to ``n`` of its full ring snapshots
    (every 7th tick)."""
    inp = table.drop(columns=[c for c in table.columns if c.startswith("gt_") or c in ("terrain", "run_id")])
    pred = Predictor.from_model_dir(model_dir)
    snaps = []
    for k, s in enumerate(iter_table_samples(inp)):
        pred.step(s)
        if pred.ring.full and k % 7 == 0:
            snaps.append(pred.ring.snapshot())
        if len(snaps) >= n:
            break
    pred.close()
    return pred, snaps


def _thread_ms(f) -> float:
    c0 = time.thread_time_ns()
    f()
    return (time.thread_time_ns() - c0) / 1e6


def update_parts(model_dir, table, n: int = 200, passes: int = 5) -> dict:
    """Median ms (thread CPU) of each part of one update of a window that passes the rules.

    On the ring snapshots of :func:`update_cost` whose window is classified, ``passes`` times:
    ``cut`` (the window cut from the ring columns), ``features_model`` (the model's features and
    probabilities, :func:`~terrainml.models.novelty.proba_and_features`), of which ``model``
    (the probabilities from those features, for a model with ``predict_proba_from_features``,
    else NaN), ``novelty`` (the scorer on those features) and ``fusion`` (the filter's update,
    on a copy of the predictor's). Each part is timed on its own, so the sum is a little under
    ``new_kept_ms`` (no call overhead between the parts).
    """
    pred, snaps = _ring_snapshots(model_dir, table, n)
    clf, times = pred.classifier, {k: [] for k in ("cut", "features_model", "model", "novelty", "fusion")}
    base = getattr(clf.model, "model", clf.model)  # a CalibratedModel's wrapped model
    fused = copy.deepcopy(pred.scheduler.fused)
    for _ in range(passes):
        for snap in snaps:
            cols = pred.ring.column_view(snap, is_label)
            wins, _ = cut_windows(cols, clf.robot, spec=clf.window_spec, online=True, with_meta=False)
            if not len(wins) or clf.novelty is None:
                continue
            times["cut"].append(_thread_ms(lambda: cut_windows(cols, clf.robot, spec=clf.window_spec,
                                                               online=True, with_meta=False)))
            x = Windows(wins.X[-1:], wins.channels, None, wins.rate_hz)
            x = clf.features.transform(x) if clf.features is not None else x
            p, F = proba_and_features(clf.model, x)
            times["features_model"].append(_thread_ms(lambda: proba_and_features(clf.model, x)))
            if hasattr(base, "predict_proba_from_features"):
                times["model"].append(_thread_ms(lambda: base.predict_proba_from_features(F)))
            times["novelty"].append(_thread_ms(lambda: clf.novelty.score(F)))
            score = float(clf.novelty.score(F)[-1])
            q = np.asarray(p, dtype=float)[-1]
            times["fusion"].append(_thread_ms(lambda: fused.update(q / q.sum(), score > clf.novelty.threshold,
                                                                   score / clf.novelty.threshold)))
    return {k: float(np.median(v)) if v else float("nan") for k, v in times.items()}


def update_cost(model_dir, table, n: int = 200, passes: int = 5) -> dict:
    """ms (thread CPU) of one update: serving path (columns) and today's path (DataFrame).

    Both paths run on the same ring snapshots, interleaved, ``passes`` times over the whole set;
    ``new_ms`` / ``old_ms`` average every attempt of a pass (windows the rules reject cost the
    cut only), ``new_kept_ms`` / ``old_kept_ms`` only the windows that were classified (cut +
    features + SVM). Each figure is the median over the passes, with the fastest pass as
    ``*_min``: on a shared virtual machine the same code's pass mean varies by up to 2x from
    one pass to the next (CPU contention), and the median and the minimum say how much of a
    figure is the code and how much the machine.
    """
    pred, snaps = _ring_snapshots(model_dir, table, n)
    clf = pred.classifier
    for snap in snaps[:5]:  # warm both paths
        pred.scheduler.classify_snapshot(snap)
        clf.classify(pred.ring.to_frame(snap))
    per_pass = []
    for _ in range(passes):
        t_new, t_old, kept = [], [], []
        for snap in snaps:  # thread CPU time: a shared machine's preemption is not the update's cost
            c0 = time.thread_time()
            p_new = pred.scheduler.classify_snapshot(snap)  # what the predictor runs: ring columns in place
            c1 = time.thread_time()
            p_old = clf.classify(pred.ring.to_frame(snap))
            c2 = time.thread_time()
            t_new.append(c1 - c0)
            t_old.append(c2 - c1)
            kept.append(p_new is not None)
            if (p_new is None) != (p_old is None) or (p_new is not None and not np.allclose(p_new, p_old, atol=1e-9)):
                raise AssertionError("the serving path and today's path disagree on a window")
        t_new, t_old, kept = np.array(t_new) * 1e3, np.array(t_old) * 1e3, np.array(kept)
        nan = float("nan")
        per_pass.append({"new_ms": t_new.mean(), "old_ms": t_old.mean(),
                         "new_kept_ms": t_new[kept].mean() if kept.any() else nan,
                         "old_kept_ms": t_old[kept].mean() if kept.any() else nan})
    cols = pred.ring.to_columns(snaps[0], is_label)
    assert len(cut_windows(cols, clf.robot, spec=clf.window_spec, online=True)[0]) <= 1
    out = {"n": int(len(snaps)), "n_kept": int(kept.sum()), "passes": passes}
    for key in per_pass[0]:
        vals = np.array([p[key] for p in per_pass], dtype=float)
        out[key], out[f"{key}_min"] = float(np.median(vals)), float(vals.min())
    return out


def _summary(rows: list[dict]) -> dict:
    moving = sum(r["moving"] for r in rows)
    dist = [d for r in rows for d in r["dist_m"]]
    ticks = np.concatenate([r["tick_ms"] for r in rows])
    return {"accuracy": sum(r["right"] for r in rows) / max(moving, 1),
            "median_dist_m": float(np.median(dist)) if dist else float("nan"),
            "never_m": sum(1 for d in dist if not np.isfinite(d)),
            "fallback_after_2m": sum(r["fallback_after_2m"] for r in rows) / max(sum(r["after_2m"] for r in rows), 1),
            "switch_ratio": sum(r["switches"] for r in rows) / max(sum(r["transitions"] for r in rows), 1),
            "p50": float(np.percentile(ticks, 50)), "p99": float(np.percentile(ticks, 99))}


def held_out_seeds(default=EVAL_SEEDS) -> tuple[int, ...]:
    """Seeds of the held-out courses: ``$TERRAINML_SERVING_SEEDS`` (comma-separated) or ``default``."""
    text = os.environ.get(SEEDS_ENV, "").strip()
    if not text:
        return tuple(default)
    try:
        return tuple(int(s) for s in text.split(",") if s.strip())
    except ValueError:
        raise ValueError(f"{SEEDS_ENV} must be comma-separated integers, got {text!r}") from None


#: the user's model: ``sim generate --runs-per-class 6`` with this seed, then ``train --model svm
#: --folds 3`` on the logs (windows chosen by ``train``), as a team trains on its first logs
USER_LOGS_SEED = 101
USER_RUNS_PER_CLASS = 6


def _cli(*args: str) -> None:
    """``terrainml ARGS`` in a child process, as a user runs it; raises with its stderr's tail."""
    import subprocess
    import sys
    from pathlib import Path

    exe = Path(sys.executable).with_name("terrainml")
    res = subprocess.run([str(exe), *args], capture_output=True, text=True)
    if res.returncode:
        raise RuntimeError(f"terrainml {' '.join(args)} failed (exit {res.returncode}): {res.stderr[-2000:]}")


def user_model(out, runs_per_class: int = USER_RUNS_PER_CLASS, seed: int = USER_LOGS_SEED) -> tuple:
    """(model folder, wall s): the model a team trains on its first simulated logs, through the
    CLI: ``sim generate --runs-per-class R --seed S`` then ``train --model svm --folds 3``, with
    its sensor members (the one without the camera serves the courses' camera confidence drops)."""
    from pathlib import Path

    out = Path(out)
    t0 = time.perf_counter()
    _cli("sim", "generate", "--runs-per-class", str(runs_per_class), "--seed", str(seed), "--out", str(out / "logs"))
    _cli("train", "--data", str(out / "logs"), "--model", "svm", "--folds", "3", "--out", str(out / "model"))
    return out / "model", time.perf_counter() - t0


def replay_courses(model_dir, seeds, duration_s: float = 120.0) -> dict:
    """Each course of ``seeds`` served through the replay engine of ``train``
    (:func:`terrainml.pipeline.replay.replay_course`, ``predict``'s settings), pooled per scenario
    (:func:`terrainml.pipeline.replay.pooled_replay`)."""
    from terrainml.pipeline.replay import pooled_replay, replay_course

    return {sc: pooled_replay([replay_course(model_dir, _held_out_course(sc, seed, duration_s)) for seed in seeds])
            for sc in ("course_stop_and_go", "mixed")}


def window_bound(seeds, window_s: float = 1.0, duration_s: float = 120.0) -> dict:
    """Per scenario, the share of moving ticks (true speed >= 0.05 m/s) that come later than
    ``window_s`` of moving time after the start or a terrain change: the most a classifier of
    ``window_s`` windows (labelled at their end) can serve right, with no confirmation, no
    straddle of the robot's wheels and every window right."""
    out = {}
    for sc in ("course_stop_and_go", "mixed"):
        moving = blind = 0
        for seed in seeds:
            c = _held_out_course(sc, seed, duration_s)
            speed = np.hypot(c["gt_vx_mps"], c["gt_vy_mps"]).to_numpy()
            label = c["terrain"].to_numpy()
            dt = np.diff(c["t_s"].to_numpy(), prepend=c["t_s"].iloc[0])
            mv = speed >= MOVING_TICK_MPS
            moving_s = np.cumsum(np.where(mv, dt, 0.0))
            # moving time since the start or the latest change: the cumulative time less its value
            # just before the tick that began the current stretch
            first = np.maximum.accumulate(np.where(np.r_[True, label[1:] != label[:-1]], np.arange(len(c)), 0))
            since = moving_s - (moving_s[first] - np.where(mv, dt, 0.0)[first])
            moving += int(mv.sum())
            blind += int((mv & (since < window_s)).sum())
        out[sc] = 1.0 - blind / max(moving, 1)
    return out


def user_model_section(seeds, out, duration_s: float = 120.0) -> list[str]:
    """Markdown: where the ticks of the held-out courses went, served by :func:`user_model`."""
    from terrainml.evaluation.report import tick_losses_markdown

    model_dir, wall_s = user_model(out)
    pooled = replay_courses(model_dir, seeds, duration_s)
    window_s = float(json.loads((model_dir / "manifest.json").read_text())["window_spec"]["window_s"])
    bound = window_bound(seeds, window_s, duration_s)
    rows = []
    for sc, p in pooled.items():
        los = p["losses"]
        unknown = los["fallback_reasons"].get("unknown_terrain", 0) / max(los["moving_ticks"], 1)
        rows.append(f"| {sc} | {p['moving_ticks']} | **{p['right_share']:.1%}** | {p['fallback_share']:.1%} | "
                    f"{unknown:.2%} | {p['median_change_m']:.2f} | {p['classifications_per_m']:.2f} | "
                    f"{bound[sc]:.1%} |")
    return ([f"### The model a team trains on its first logs (`sim generate --runs-per-class {USER_RUNS_PER_CLASS} "
             f"--seed {USER_LOGS_SEED}`, `train --model svm --folds 3`)", "",
             f"Trained through the CLI in {wall_s / 60:.1f} min (windows chosen by `train`); the same held-out "
             f"courses, {duration_s:.0f} s each, served by `train`'s replay engine with `predict`'s settings "
             "(moving = the predictor's odometer, or on an `estimator_unhealthy` tick the wheels' rim speed, as "
             "in `train`'s report; fallback counted wrong). "
             "`unknown_terrain` here is unknown ground flagged on known ground (every course terrain is a "
             "trained class).", "",
             f"The last column bounds any classifier of the model's {window_s:g} s windows: the share of "
             f"moving ticks (true speed) later than {window_s:g} s of moving time after the start or a "
             "terrain change, i.e. served right with every window right, no confirmation and no wheel "
             "straddling the change.", "",
             "| course | moving ticks | served right (>= 92% stop-and-go, >= 94% mixed) | fallback | "
             "`unknown_terrain` on known ground (<= 1%) | median m to the right class after a change | "
             "classifications per m | bound: moving ticks a full window after a change |",
             "|---|---|---|---|---|---|---|---|", *rows, ""]
            + tick_losses_markdown([(sc, p["losses"]) for sc, p in pooled.items()], fold_word="course"))


def run(quick: bool = False, spec_name: str = "short", seeds=None) -> str:
    import tempfile
    from pathlib import Path

    seeds = held_out_seeds() if seeds is None else tuple(seeds)
    duration = 60.0 if quick else 120.0
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        # 5 runs per class: the recipe cycles its 5 labelled scenarios per class, so every class
        # is trained on every one, stop-and-go included (with 4, each class missed one)
        runs = 2 if quick else 5
        model_dir, n_win, bacc = _model(spec_name, runs, Path(tmp) / "svm")
        t_model = time.perf_counter() - t0
        courses = (f" plus {2 * len(TRAIN_COURSE_SEEDS)} transition courses (seeds "
                   f"{TRAIN_COURSE_SEEDS[0]}-{TRAIN_COURSE_SEEDS[-1]})" if TRAIN_COURSE_SEEDS else "")
        lines = ["## Serving through stop-and-go and transitions (`benchmarks/bench_serving.py`)", "",
                 f"Model: SVM on recipe `sim_default` ({runs} runs per class, parquet){courses}, "
                 f"window spec `{spec_name}`: {n_win} windows, grouped 3-fold CV balanced accuracy "
                 f"{bacc:.3f} ({t_model:.0f} s). Held-out seeds {list(seeds)}, {duration:.0f} s courses at "
                 f"{SPEED_MPS} m/s; moving = true speed >= {MOVING_TICK_MPS} m/s; fallback counted wrong.", "",
                 "| course | accuracy, all moving ticks (>= 0.90) | median distance to the right class "
                 "after a transition, m (<= 1.0) | transitions never served right | fallback after 2 m "
                 "(<= 5%) | switches / true transitions (<= 1.2) | tick p50 / p99 ms, updates inline "
                 "(p99 <= 2) |", "|---|---|---|---|---|---|---|"]
        cost_table = None
        for scenario in ("course_stop_and_go", "mixed"):
            rows = []
            for seed in seeds:
                table = _held_out_course(scenario, seed, duration)
                rows.append(serve_course(model_dir, table))
                if cost_table is None:
                    cost_table = table
            s = _summary(rows)
            lines.append(f"| {scenario} | {s['accuracy']:.1%} | {s['median_dist_m']:.2f} | {s['never_m']} | "
                         f"{s['fallback_after_2m']:.1%} | {s['switch_ratio']:.2f} | "
                         f"{s['p50']:.3f} / {s['p99']:.3f} |")
        c = update_cost(model_dir, cost_table, 60 if quick else 200)
        parts = update_parts(model_dir, cost_table, 60 if quick else 200)
        lines += ["", f"One classification update (cut + features + SVM, window spec `{spec_name}`, thread "
                  f"CPU, {c['n']} ring snapshots of a stop-and-go course, both paths interleaved on the "
                  f"same snapshots, same probabilities; median of {c['passes']} passes over them, "
                  f"fastest pass in brackets): **{c['new_ms']:.3f} ms** [{c['new_ms_min']:.3f}] mean "
                  f"per attempt on the serving path (ring columns read in place, selected features "
                  f"only) against {c['old_ms']:.3f} ms [{c['old_ms_min']:.3f}] on today's path (ring "
                  f"DataFrame + `cut_windows` on it), ratio **{c['old_ms'] / c['new_ms']:.1f}x**; on "
                  f"the {c['n_kept']} windows that pass the rules (the others cost the cut only) "
                  f"**{c['new_kept_ms']:.3f} ms** [{c['new_kept_ms_min']:.3f}] against "
                  f"{c['old_kept_ms']:.3f} ms [{c['old_kept_ms_min']:.3f}] (goal <= 0.5 ms). Updates "
                  f"every online hop ({'0.1' if spec_name == 'short' else '0.5'} s) while moving.", "",
                  f"Parts of one update of a window that passes the rules (thread CPU, median, each "
                  f"timed alone on the same snapshots): cut {parts['cut']:.3f} ms, features + model "
                  f"{parts['features_model']:.3f} ms (of which the model's probabilities "
                  f"{parts['model']:.3f} ms), novelty score {parts['novelty']:.3f} ms, fusion "
                  f"{parts['fusion']:.3f} ms.", ""]
        if not quick:
            lines += user_model_section(seeds, Path(tmp) / "user", duration)
    return "\n".join(lines)


if __name__ == "__main__":
    import sys
    import tempfile
    from pathlib import Path

    if "--user-model" in sys.argv:   # only the section of the model a team trains on its first logs
        with tempfile.TemporaryDirectory() as tmp:
            print("\n".join(user_model_section(TUNING_SEEDS if "--tuning" in sys.argv else held_out_seeds(),
                                                Path(tmp))))
        sys.exit(0)

    print(run(quick="--quick" in sys.argv, spec_name=next((a.split("=")[1] for a in sys.argv
                                                         if a.startswith("--spec=")), "short"),
              seeds=TUNING_SEEDS if "--tuning" in sys.argv else None))
