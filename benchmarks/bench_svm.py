"""SVM benchmark: grouped 5-fold CV on the simulated dataset, ablation, transfer,
dataset-build throughput, train time and per-window latency.

``run(quick)`` returns a Markdown section:

1. Dataset: recipe ``datasets/sim_default.yaml`` (12 runs per class, mixed scenarios, seed 0;
   quick: 5 runs per class, 40 s, Parquet logs) built with ``terrainml.pipeline.dataset``.
2. SVM (``terrainml.models.svm.SVMClassifier``: features, StandardScaler, RBF SVC balanced,
   nested grouped search, calibrated) under grouped 5-fold CV by run, seed 0: per fold and
   mean ± std of balanced accuracy, macro-F1, desired-slip error; acceptance checks.
   Reference in the same run and on the same folds and features: scikit-learn's default
   ``make_pipeline(StandardScaler(), SVC())`` (no search, no class weights); ratio ours/reference.
3. Feature-set ablation (kinematic / currents / imu / all) on the same folds.
4. Transfer: the model trained on all of dataset A scored on dataset B (recipe
   ``sim_eval_seed1``: another seed) with ``terrainml.pipeline.train.evaluate``.
5. Speed: dataset build throughput (runs/s, windows/s) with 1 and 2 joblib jobs on the same
   logs (ratio); SVM final-fit time; per-window inference latency p50/p99 (one window per call).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from terrainml.evaluation.report import markdown_table

SEED = 0
N_FOLDS = 5


def _recipe(quick: bool, name: str) -> dict:
    from terrainml.experiments.recipes import load_recipe

    r = load_recipe(name)
    if quick:
        # 5 runs per class: every class then drives every scenario once (the simulator cycles
        # scenarios per class), so scenario and class are not confounded as with fewer runs
        r.update({"runs_per_class": 5 if name == "sim_default" else 2, "duration_s": 40.0, "format": "parquet"})
    return r


def _reference_cv(ds, folds) -> dict:
    """Default sklearn SVC on the same features and folds (the reference)."""
    from sklearn.metrics import balanced_accuracy_score, f1_score
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVC

    from terrainml.features.sets import FeatureSet

    W = ds.windows
    F = FeatureSet.for_robot(ds.robot).fit_transform(W)
    y = W.y
    bal, f1 = [], []
    for tr, te in folds:
        m = make_pipeline(StandardScaler(), SVC()).fit(F[tr], y[tr])
        p = m.predict(F[te])
        bal.append(balanced_accuracy_score(y[te], p))
        f1.append(f1_score(y[te], p, average="macro"))
    return {"balanced_accuracy": (float(np.mean(bal)), float(np.std(bal))),
            "macro_f1": (float(np.mean(f1)), float(np.std(f1)))}


def _throughput(logs: list[Path], robot, spec) -> list[list[str]]:
    from terrainml.pipeline.dataset import build_dataset

    rows = []
    for jobs in (1, 2):
        t0 = time.perf_counter()
        ds = build_dataset(logs, robot, "robust", spec, n_jobs=jobs)
        dt = time.perf_counter() - t0
        rows.append((jobs, len(logs), len(ds.windows), dt))
    base = rows[0][3]
    return [[str(j), str(n), str(w), f"{dt:.1f}", f"{n / dt:.2f}", f"{w / dt:.1f}", f"{base / dt:.2f}"]
            for j, n, w, dt in rows]


def run(quick: bool = False) -> str:
    from terrainml.experiments.recipes import simulated_dataset
    from terrainml.pipeline.dataset import find_logs
    from terrainml.pipeline.evaluate import evaluate
    from terrainml.pipeline.train_options import TrainOptions
    from terrainml.pipeline.train import train

    ra, rb = _recipe(quick, "sim_default"), _recipe(quick, "sim_eval_seed1")
    t0 = time.perf_counter()
    ds_a = simulated_dataset(ra, n_jobs=2)
    ds_b = simulated_dataset(rb, n_jobs=2)
    t_data = time.perf_counter() - t0
    W = ds_a.windows
    out = [f"## SVM terrain classifier on simulated windows{' [quick]' if quick else ''}", ""]
    per_class = {n: int((W.y == c).sum()) for c, n in zip(ds_a.class_ids, ds_a.class_names)}
    runs_per_class = {n: len(set(W.groups[W.y == c])) for c, n in zip(ds_a.class_ids, ds_a.class_names)}
    out += [f"Dataset A: recipe `{ra['name']}` ({ra['runs_per_class']} runs per class, seed {ra['seed']}, "
            f"mixed scenarios, {ra.get('format')} logs): {len(ds_a.runs)} logs, {len(W)} steady windows "
            f"from {len(set(W.groups))} runs; dataset B: recipe `{rb['name']}` (seed {rb['seed']}): "
            f"{len(ds_b.windows)} windows. Generation + build (or cache) took {t_data:.0f} s.", "",
            markdown_table(["class", "windows", "runs with windows"],
                           [[n, per_class[n], runs_per_class[n]] for n in per_class]), "",
            "Steady-window rejections (design §8), dataset A: "
            + ", ".join(f"{k} {v}" for k, v in ds_a.counts.items()) + ".", ""]
    if len(ds_a.class_ids) < 2:
        return "\n".join(out + ["Fewer than two classes have steady windows: nothing to train."]) + "\n"
    with tempfile.TemporaryDirectory() as tmp:
        t1 = time.perf_counter()
        res = train(ds_a, Path(tmp) / "svm", models=("svm",),
                    options=TrainOptions(folds=N_FOLDS, seed=SEED, n_jobs=1, ablation=True))
        t_train = time.perf_counter() - t1
        cv = res.models["svm"]["cv"]
        ev = evaluate(Path(tmp) / "svm", ds_b) if len(ds_b.windows) else {}
        ref = _reference_cv(ds_a, cv.folds)
    s = cv.summary
    frame = cv.per_fold_frame()
    out += [f"### Grouped {len(cv.folds)}-fold CV by run (seed {SEED}), SVM", "",
            markdown_table(["fold", "test runs", "windows", "balanced acc.", "macro-F1", "desired-slip error",
                            "ECE", "fit s"],
                           [[int(f.fold), int(f.n_test_groups), int(f.n_windows), f"{f.balanced_accuracy:.3f}",
                             f"{f.macro_f1:.3f}", f"{f.desired_slip_error_mean:.4f}", f"{f.ece:.3f}",
                             f"{f.fit_time_s:.1f}"] for f in frame.itertuples()]), ""]
    ba, f1 = s["balanced_accuracy"], s["macro_f1"]
    dse = s.get("desired_slip_error_mean", {"mean": np.nan, "std": np.nan})
    trans = ev.get("balanced_accuracy", float("nan"))
    checks = [["CV balanced accuracy (mean ± std)", f"{ba['mean']:.3f} ± {ba['std']:.3f}", ">= 0.95",
               "PASS" if ba["mean"] >= 0.95 else "FAIL"],
              ["CV macro-F1 (mean ± std)", f"{f1['mean']:.3f} ± {f1['std']:.3f}", ">= 0.95",
               "PASS" if f1["mean"] >= 0.95 else "FAIL"],
              ["desired-slip error mean", f"{dse['mean']:.4f} ± {dse['std']:.4f}", "<= 0.01",
               "PASS" if dse["mean"] <= 0.01 else "FAIL"],
              ["transfer to dataset B (other seed), balanced accuracy", f"{trans:.3f}", ">= 0.93",
               "PASS" if trans >= 0.93 else "FAIL"]]
    out += ["### Acceptance", "", markdown_table(["figure", "measured", "target", ""], checks), ""]
    names = dict(zip(ds_a.class_ids, ds_a.class_names))
    cm = np.asarray(cv.pooled["confusion_matrix"])
    rec_rows = []
    for k, c in enumerate(cv.classes.tolist()):
        row = cm[k].copy()
        row[k] = 0
        worst = int(np.argmax(row)) if row.sum() else None
        recall = cv.pooled["recall_per_class"].get(str(c), float("nan"))
        rec_rows.append([names.get(c, c), int(cm[k].sum()), f"{recall:.3f}",
                         "-" if worst is None else f"{names.get(cv.classes[worst], worst)} ({int(row[worst])})"])
    out += ["Per-class recall, pooled out-of-fold (with the class it is most often mistaken for):", "",
            markdown_table(["class", "windows", "recall", "most confused with"], rec_rows), ""]
    rba, rf1 = ref["balanced_accuracy"], ref["macro_f1"]
    out += ["### Reference on the same folds and features", "",
            markdown_table(["model", "balanced acc.", "macro-F1"],
                           [["ours: nested grouped search, balanced, calibrated",
                             f"{ba['mean']:.3f} ± {ba['std']:.3f}",
                             f"{f1['mean']:.3f} ± {f1['std']:.3f}"],
                            ["reference: `make_pipeline(StandardScaler(), SVC())` defaults",
                             f"{rba[0]:.3f} ± {rba[1]:.3f}", f"{rf1[0]:.3f} ± {rf1[1]:.3f}"],
                            ["ratio ours / reference", f"{ba['mean'] / max(rba[0], 1e-9):.3f}",
                             f"{f1['mean'] / max(rf1[0], 1e-9):.3f}"]]), ""]
    if res.ablation is not None:
        out += ["### Feature-set ablation (same folds)", "",
                markdown_table(["feature set", "features", "balanced acc.", "macro-F1", "desired-slip error"],
                               [[a.subset, int(a.n_features),
                                 f"{a.balanced_accuracy_mean:.3f} ± {a.balanced_accuracy_std:.3f}",
                                 f"{a.macro_f1_mean:.3f} ± {a.macro_f1_std:.3f}", f"{a.desired_slip_error_mean:.4f}"]
                                for a in res.ablation.itertuples()]), ""]
    # throughput on the same logs with 1 and 2 jobs
    logs_dir = None
    import os

    root = Path(os.environ.get("TERRAINML_CACHE") or Path.home() / ".cache" / "terrainml")
    cands = sorted(root.glob(f"{ra['name']}_*/logs"), key=lambda p: p.stat().st_mtime)
    if cands:
        logs_dir = cands[-1]
    lat = res.models["svm"]["latency"]
    out += ["### Speed", ""]
    if logs_dir is not None:
        logs = find_logs(logs_dir)[: (8 if quick else 16)]
        out += [f"Dataset build (ingest + EKF + windows) on the same {len(logs)} logs:", "",
                markdown_table(["jobs", "logs", "windows", "time s", "runs/s", "windows/s", "speed-up vs 1 job"],
                               _throughput(logs, ds_a.robot, ds_a.spec)), ""]
    out += [markdown_table(["figure", "value"],
                           [["SVM final fit (nested search + calibration), s",
                             f"{res.models['svm']['fit_time_s']:.1f}"],
                            ["whole `train` (5-fold CV + ablation + final fit + report), s", f"{t_train:.0f}"],
                            ["inference latency per window p50 / p99, ms (features + SVM, one window per call)",
                             f"{lat['p50_ms']:.2f} / {lat['p99_ms']:.2f}"],
                            ["chosen C, gamma", f"{res.models['svm']['params']}"]]), ""]
    return "\n".join(out) + "\n"


if __name__ == "__main__":  # pragma: no cover
    import sys

    print(run(quick="--quick" in sys.argv))
