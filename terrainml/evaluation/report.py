"""Training reports: ``report.md``, ``report.json``, confusion-matrix PNGs, per-fold CSVs, ablation.

:func:`write_report` takes the results of :func:`terrainml.pipeline.train.train` and writes, into
the model folder:

* ``report.json``: dataset summary (runs, windows, classes, rejection counts, fingerprint), per
  model the CV summary (mean ± std per metric), per-fold metrics, pooled out-of-fold metrics
  (confusion matrix, per-class recall), latency p50/p99, best hyper-parameters, and the
  feature-set ablation;
* ``report.md``: the same as readable tables (models side by side);
* ``confusion_<model>.png`` (matplotlib, Agg backend; row-normalised, counts annotated);
* ``folds_<model>.csv`` (one row per fold) and ``ablation.csv``;
* ``evaluate --open-set`` (:func:`write_open_set_report`): ``open_set.md`` / ``.json``, every
  window's out-of-fold novelty score per held-out class (``open_set_scores.parquet``) and the ROC
  curves (``open_set_roc.png``);
* with ``TrainOptions(open_set=True)``, the leave-one-class-out table of the served model's novelty
  score (:mod:`terrainml.evaluation.open_set`; ``report.json``: ``open_set``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from matplotlib.figure import Figure  # no pyplot: no global backend or figure registry
from sklearn.metrics import roc_curve

from terrainml.atomic import atomic_output, write_text
from terrainml.evaluation.open_set import open_set_markdown
from terrainml.models.artifacts import json_safe

__all__ = ["write_report", "plot_confusion", "markdown_table", "write_open_set_report", "OPEN_SET_FILES"]

#: the report files of ``terrainml evaluate --open-set``: markdown, JSON, every window's out-of-fold
#: score per held-out class (Parquet), and the ROC curves on moving windows (PNG)
OPEN_SET_FILES = ("open_set.md", "open_set.json", "open_set_scores.parquet", "open_set_roc.png")

METRIC_ROWS = (("balanced_accuracy", "balanced accuracy"), ("accuracy", "accuracy"),
               ("macro_f1", "macro-F1"), ("adjacent_accuracy", "adjacent-class accuracy"),
               ("desired_slip_error_mean", "desired-slip error (mean)"), ("ece", "ECE"))


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    out = ["| " + " | ".join(map(str, header)) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(map(str, r)) + " |" for r in rows]
    return "\n".join(out)


def _pm(summary: dict, key: str, digits: int = 3) -> str:
    s = summary.get(key)
    if not s or s.get("mean") is None or not np.isfinite(s["mean"]):
        return "n/a"
    return f"{s['mean']:.{digits}f} ± {s['std']:.{digits}f}"


def _num(x: float, digits: int) -> str:
    return f"{x:.{digits}f}" if np.isfinite(x) else "n/a"


def plot_confusion(cm: np.ndarray, names: Sequence[str], path: Path, title: str) -> Path:
    """Row-normalised confusion matrix with counts, saved as PNG."""
    cm = np.asarray(cm, dtype=float)
    rows = cm.sum(axis=1, keepdims=True)
    norm = np.divide(cm, rows, out=np.zeros_like(cm), where=rows > 0)
    k = len(names)
    fig = Figure(figsize=(1.2 + 0.75 * k, 1.0 + 0.7 * k), dpi=100)
    ax = fig.add_subplot()
    im = ax.imshow(norm, vmin=0, vmax=1, cmap="Blues")
    ax.set_xticks(range(k), names, rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(k), names, fontsize=8)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    ax.set_title(title, fontsize=9)
    for i in range(k):
        for j in range(k):
            if cm[i, j]:
                ax.text(j, i, int(cm[i, j]), ha="center", va="center", fontsize=7,
                        color="white" if norm[i, j] > 0.5 else "black")
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format=Path(path).suffix.lstrip(".") or "png", metadata={"Software": None})
    return path


def _novelty_lines(result: Any, doc: dict) -> list[str]:
    """The leave-one-class-out table of the served model's novelty score, when it was run."""
    os_res = getattr(result, "open_set", None)
    md: list[str] = []
    if os_res is not None:
        doc["open_set"] = os_res.to_dict()
        md += ["## Unknown ground: leave-one-class-out (served model)", "",
               _open_set_settings(os_res.settings, "on the same folds"), "", *open_set_markdown(os_res), ""]
    return md


def _open_set_settings(st: dict, folds: str) -> str:
    return (f"Each class in turn held out of training {folds}; novelty `{st['method']}` (k = {st['k']}), "
            f"threshold at {100 * st['false_alarm_target']:.0f} % false alarms of the moving known windows in "
            f"inner grouped folds of the training runs ({st.get('inner_folds', 3)}); moving: rim speed > "
            f"{st['moving_mps']} m/s.")


def write_open_set_report(out: str | Path, result: Any, context: dict) -> dict:
    """Write the files of :data:`OPEN_SET_FILES` (table, JSON, per-window scores, ROC curves) of a
    leave-one-class-out :class:`~terrainml.evaluation.open_set.OpenSetResult` into folder ``out``;
    return the JSON's dict.

    ``context``: what was evaluated (data, model, window spec, robot, windows, runs), written at
    the top of both files.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {**context, **result.to_dict()}
    st = result.settings
    md = [f"# Unknown ground: leave-one-class-out ({context.get('model', '?')} on {context.get('data', '?')})", "",
          ", ".join(f"{k}: {v}" for k, v in context.items()), "",
          _open_set_settings(st, f"in grouped {st['folds']}-fold CV by run (seed {st['seed']})"), "",
          *open_set_markdown(result), ""]
    write_text(out / OPEN_SET_FILES[0], "\n".join(md))
    write_text(out / OPEN_SET_FILES[1], json.dumps(json_safe(doc), indent=2, sort_keys=True) + "\n")
    with atomic_output(out / OPEN_SET_FILES[2]) as tmp:
        result.window_table().to_parquet(tmp, index=False)
    plot_open_set_roc(result, out / OPEN_SET_FILES[3])
    return doc


def plot_open_set_roc(result: Any, path: Path) -> Path:
    """ROC curve of the novelty score per held-out class on moving windows (the unknown's against
    the known classes' held-out moving ones), with the issue's false-alarm share on that axis and
    each class's operating point at its inner-fold threshold; saved as PNG."""
    fig = Figure(figsize=(5.5, 4.5), dpi=100)
    ax = fig.add_subplot()
    w = result.windows
    for row in result.table.itertuples():
        score = np.asarray(result.scores[row.unknown])
        keep = w["moving"].to_numpy() & np.isfinite(score)
        unknown = (w["label"].to_numpy() == row.unknown)[keep]
        if 0 < unknown.sum() < len(unknown):
            fpr, tpr, _ = roc_curve(unknown, score[keep])
            line, = ax.plot(fpr, tpr, lw=1.2, label=f"{row.unknown} (AUROC {row.auroc_moving:.2f})")
            ax.plot([row.false_alarm_moving], [row.unknown_flagged], "o", color=line.get_color(), ms=4)
    fa = result.settings.get("reach_false_alarm", 0.05)
    # on this axis (moving windows) the line is stricter than the reach column's, whose false
    # alarms count every known window (a gated scorer never flags one standing still)
    ax.axvline(fa, color="grey", ls="--", lw=0.8, label=f"{100 * fa:.0f} % of moving known windows")
    ax.plot([0, 1], [0, 1], color="lightgrey", lw=0.8)
    ax.set_xlabel("known held-out moving windows flagged (false alarms)")
    ax.set_ylabel("unknown moving windows flagged")
    ax.set_title("novelty score, each class held out (dot: inner-fold threshold)", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png", metadata={"Software": None})
    return path


def write_report(out: str | Path, result: Any) -> dict:
    """Write the report files for a :class:`terrainml.pipeline.train.TrainResult`; return report.json's dict."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = list(result.class_names)
    served = result.models[result.default_model]["cv"].summary
    excluded = list(result.dataset_summary.get("excluded_classes") or [])
    # top level: the served model's CV balanced accuracy, and the classes left out of it (named)
    doc: dict[str, Any] = {"dataset": result.dataset_summary, "folds": result.n_folds, "seed": result.seed,
                           "default_model": result.default_model, "models": {}, "ablation": None,
                           "balanced_accuracy": served["balanced_accuracy"]["mean"],
                           "balanced_accuracy_std": served["balanced_accuracy"]["std"],
                           "excluded_classes": excluded}
    md = [f"# Training report: {out.name}", "",
          f"Dataset: {result.dataset_summary['n_runs']} runs, {result.dataset_summary['n_windows']} windows, "
          f"{len(names)} classes ({', '.join(names)}); robot `{result.dataset_summary['robot']}`; "
          f"training-data fingerprint `{result.dataset_summary['fingerprint'][:16]}…`.", "",
          f"Grouped {result.n_folds}-fold cross-validation by run (StratifiedGroupKFold, seed "
          f"{result.seed}); no run is in two folds. Served model: **{result.default_model}**.", ""]
    for e in excluded:
        md += [f"**Warning:** class `{e['class']}` has {e['runs']} run(s): {e['reason']}. Record another "
               "run of it to measure it.", ""]
    # side-by-side summary
    header = ["metric (CV mean ± std)"] + list(result.models)
    rows = [[label] + [_pm(result.models[m]["cv"].summary, key) for m in result.models]
            for key, label in METRIC_ROWS]
    rows.append(["inference latency p50 / p99 (ms/window)"] +
                [f"{result.models[m]['latency']['p50_ms']:.3f} / {result.models[m]['latency']['p99_ms']:.3f}"
                 for m in result.models])
    rows.append(["final fit time (s)"] + [f"{result.models[m]['fit_time_s']:.1f}" for m in result.models])
    md += ["## Models", "", markdown_table(header, rows), ""]
    for name, r in result.models.items():
        cv = r["cv"]
        frame = cv.per_fold_frame()
        write_text(out / f"folds_{name}.csv", frame.to_csv(index=False))
        png = plot_confusion(np.asarray(cv.pooled["confusion_matrix"]), list(cv.class_names),
                             out / f"confusion_{name}.png",
                             f"{name}: out-of-fold confusion (balanced acc. "
                             f"{cv.pooled['balanced_accuracy']:.3f})")
        doc["models"][name] = {"summary": cv.summary, "per_fold": frame.to_dict(orient="records"),
                               "pooled": cv.pooled, "latency": r["latency"], "fit_time_s": r["fit_time_s"],
                               "params": r.get("params", {}), "confusion_png": png.name}
        md += [f"## {name}: per fold", "",
               markdown_table(["fold", "windows", "runs", "bal. acc.", "acc.", "macro-F1", "adjacent",
                               "slip err.", "ECE", "fit s"],
                              [[int(f.fold), int(f.n_windows), int(f.n_test_groups), f"{f.balanced_accuracy:.3f}",
                                f"{f.accuracy:.3f}", f"{f.macro_f1:.3f}", _num(f.adjacent_accuracy, 3),
                                _num(f.desired_slip_error_mean, 4), f"{f.ece:.3f}", f"{f.fit_time_s:.1f}"]
                               for f in frame.itertuples()]), "",
               "Per-class recall (pooled out-of-fold): " + ", ".join(
                   f"{k} {v:.2f}" for k, v in zip(cv.class_names,
                                                  [cv.pooled["recall_per_class"].get(str(c), float('nan'))
                                                   for c in cv.classes])), "",
               f"![confusion {name}]({png.name})", ""]
        if r.get("params"):
            md += [f"Chosen hyper-parameters (final fit): `{json.dumps(json_safe(r['params']))}`", ""]
    if result.ablation is not None and len(result.ablation):
        ab = result.ablation
        write_text(out / "ablation.csv", ab.to_csv(index=False))
        doc["ablation"] = ab.to_dict(orient="records")
        md += ["## Feature-set ablation (SVM, same folds)", "",
               markdown_table(["feature set", "features", "bal. acc.", "macro-F1", "desired-slip error"],
                              [[a.subset, int(a.n_features),
                                f"{a.balanced_accuracy_mean:.3f} ± {a.balanced_accuracy_std:.3f}",
                                f"{a.macro_f1_mean:.3f} ± {a.macro_f1_std:.3f}", _num(a.desired_slip_error_mean, 4)]
                               for a in ab.itertuples()]), ""]
    md += _novelty_lines(result, doc)
    if getattr(result, "replay", None) is not None:
        doc["replay"] = result.replay
        md += replay_markdown(result.replay)
    if getattr(result, "preflight", None):
        doc["preflight"] = result.preflight
        md += preflight_markdown(result.preflight)
    counts = result.dataset_summary.get("rejections", {})
    if counts:
        md += ["## Window rejections (steady rules, design §8)", "",
               markdown_table(["rule", "windows rejected"], [[k, v] for k, v in counts.items()]), ""]
    doc = json_safe(doc)
    write_text(out / "report.json", json.dumps(doc, indent=2, sort_keys=True, allow_nan=False) + "\n")
    write_text(out / "report.md", "\n".join(md) + "\n")
    return doc


def _f(x: Any, digits: int = 3, scale: float = 1.0, suffix: str = "") -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{scale * x:.{digits}f}{suffix}"


def _selection_rows(sel: dict) -> list[list[str]]:
    rows = []
    for c in sel["candidates"]:
        inner = ", ".join(_f(v) for v in c["inner_scores"])
        cv = "n/a" if c["cv_balanced_accuracy"] is None else \
            f"{c['cv_balanced_accuracy']:.3f} ± {c['cv_balanced_accuracy_std']:.3f}"
        rows.append([("**" + c["candidate"] + "**") if c["candidate"] == sel["chosen"] else c["candidate"],
                     "n/a" if c["n_windows"] is None else c["n_windows"], cv, _f(c["cv_pooled_balanced_accuracy"]),
                     _f(c["cv_ece"]), inner, c["chosen_in_outer_folds"], c["screened"] or "-"])
    return rows


def _pooled_line(sel: dict, best: dict | None) -> list[str]:
    """The nested figure pooled over every outer fold's held-out windows, beside the best candidate's
    pooled CV figure (the evaluation engine's definition, as in ``train --windows X``'s report)."""
    pooled = sel["nested"].get("pooled")
    if pooled is None or not np.isfinite(pooled):
        return []
    ref = best.get("cv_pooled_balanced_accuracy") if best else None
    gap = (f"; the best candidate's pooled CV figure is {ref:.3f} ({100 * (pooled - ref):+.1f} points)"
           if ref is not None and np.isfinite(ref) else "")
    return [f"Pooled over the held-out windows of all outer folds (one balanced accuracy, as the grouped CV of "
            f"`train --windows X` reports it): **{pooled:.3f}**{gap}.", ""]


def _nested_line(sel: dict, best: dict | None) -> list[str]:
    return [f"**Honest figure of this choice (nested CV): {sel['nested']['mean']:.3f} ± {sel['nested']['std']:.3f}** "
            f"balanced accuracy: in outer fold k the choice is made again without group k (inner scores below) and "
            f"its winner, fitted without group k, is scored on it"
            + (f"; {100 * (sel['nested']['mean'] - best['cv_balanced_accuracy']):+.1f} points from the best "
               f"candidate's CV figure" if best else "") + ".", ""]


def selection_markdown(doc: dict) -> list[str]:
    """Markdown of ``train --windows auto --model auto`` (:mod:`terrainml.pipeline.autotrain`):
    every candidate side by side, the choice and why, the nested (honest) figure per outer
    fold with ECE before and after calibration, and the served replay per fold."""
    sel, rep = doc["selection"], doc.get("replay") or {}
    K = len(sel["partition"])
    scored = [c for c in sel["candidates"] if c["cv_balanced_accuracy"] is not None]
    best = max(scored, key=lambda c: c["cv_balanced_accuracy"]) if scored else None
    others = sorted((c for c in scored if c["candidate"] != sel["chosen"]), key=lambda c: -c["cv_balanced_accuracy"])
    chosen = next(c for c in sel["candidates"] if c["candidate"] == sel["chosen"])
    md = ["## Selection: window spec and model, nested run-grouped CV", "",
          f"The runs are split into {K} groups (stratified by class, weighted by run length); every candidate "
          f"is scored on the same runs. **Chosen: `{sel['chosen']}`**: the highest grouped {K}-fold CV balanced "
          f"accuracy ({chosen['cv_balanced_accuracy']:.3f})"
          + (f"; next `{others[0]['candidate']}` ({others[0]['cv_balanced_accuracy']:.3f})" if others else "")
          + ".", "",
          *(_nested_line(sel, best) if sel.get("nested_cv", True) else
            [f"**Honest figure: {sel['nested']['mean']:.3f} ± {sel['nested']['std']:.3f}** balanced accuracy, "
             f"the grouped {K}-fold CV itself: the spec and the model were fixed beforehand (a sensor member "
             "of a chosen model), so nothing is chosen on these folds and no nested CV is needed.", ""]),
          *_pooled_line(sel, best),
          markdown_table(["candidate", "windows", f"CV bal. acc. (mean ± std, {K} folds)", "pooled", "ECE (raw)",
                          "inner scores (outer fold 1..K)", "chosen in outer folds", "screened out"],
                         _selection_rows(sel)), ""]
    if sel.get("infeasible"):
        md += ["Not candidates: " + "; ".join(f"`{s}`: {r}" for s, r in sel["infeasible"].items()) + ".", ""]
    if sel.get("budget_note"):
        md += [f"Time budget: {sel['budget_note']}.", ""]
    md += ["### Outer folds (the honest figure) and calibration", "",
           ("The temperature of fold k is fitted on its winner's inner out-of-fold probabilities (never group k) "
            if sel.get("nested_cv", True) else
            "The temperature of fold k is fitted on the out-of-fold probabilities of the other groups ")
           + "and applied to its predictions on group k; ECE before and after on those runs.", "",
           markdown_table(["fold", "runs", "chosen", "inner score", "bal. acc.", "ECE before", "ECE after",
                           "temperature"],
                          [[o["fold"] + 1, len(o["runs"]), o["chosen"], _f(o["inner_score"]),
                            _f(o["balanced_accuracy"]), _f(o["ece_before"]), _f(o["ece_after"]),
                            _f(o["temperature"], 2)] for o in sel["outer"]]), "",
           f"Served model: temperature {sel['temperature']:.2f}, fitted on the out-of-fold probabilities of all "
           "runs (the fusion, the uncertain-class fallback and the safe cap read the calibrated values).", ""]
    md += replay_markdown(rep, "outer fold") if rep.get("folds") or "replay" in doc else []
    md += preflight_markdown(doc.get("preflight"))
    if doc.get("timing_s"):
        t = doc["timing_s"]
        md += ["Time: " + ", ".join(f"{k.removesuffix('_s').replace('_', ' ')} {v / 60:.1f} min" for k, v in t.items())
               + ".", ""]
    return md


def replay_markdown(rep: dict, fold_word: str = "fold") -> list[str]:
    """Markdown of the served replay of every fold's held-out runs (``rep``: the report's ``replay``)."""
    if not rep.get("folds"):
        return ["### Served replay", "", "Not run (no run logs: trained from a windows file, or `--no-replay`).", ""]
    fr = rep["folds"]
    pooled = rep["pooled"]
    md = ["### Served replay of the held-out runs", "",
          f"Each {fold_word}'s model, saved and loaded as `terrainml predict` loads it, serves a course of "
          f"{rep['segment_s']:.0f} s of each of the fold's held-out runs (classes interleaved) tick by tick. "
          "Right: the labelled class served on a moving tick (a fallback is never right). Sensor members: "
          "those the fold's model is served with, as the saved folder is (one for each sensor group its held-out "
          "runs flag invalid somewhere, fitted on the fold's training windows), and the ticks each served.", "",
          markdown_table(["fold", "runs", "moving ticks", "right %", "right % (3 s after changes left out)",
                          "fallback %", "classifications / m", "median m to the right class after a change",
                          "changes never served right", "sensor members"],
                         [[f["fold"] + 1, f["runs"], f.get("moving_ticks", 0), _f(f.get("right_share"), 1, 100),
                           _f(f.get("right_share_settled"), 1, 100), _f(f.get("fallback_share"), 1, 100),
                           _f(f.get("classifications_per_m"), 2), _f(f.get("median_change_m"), 2),
                           f.get("changes_never_right", "n/a"), _members_served(f)]
                          for f in fr]
                         + [["all", sum(f["runs"] for f in fr), pooled.get("moving_ticks", 0),
                             _f(pooled.get("right_share"), 1, 100), "", _f(pooled.get("fallback_share"), 1, 100),
                             _f(pooled.get("classifications_per_m"), 2), _f(pooled.get("median_change_m"), 2),
                             pooled.get("changes_never_right", "n/a"), ""]]), ""]
    md += tick_losses_markdown([(str(f["fold"] + 1), f.get("losses")) for f in fr] + [("all", pooled.get("losses"))],
                               fold_word)
    if rep.get("refusal"):
        md += [f"**Refused:** {rep['refusal']}" + (" (saved anyway: `--allow-unproven`)." if rep.get("overridden")
                                                  else "; no model saved."), ""]
    return md


def _members_served(fold: dict) -> str:
    """A fold's sensor members and the ticks each served, e.g. ``no_imu (2995 ticks)``; ``-``: none."""
    served = fold.get("member_ticks") or {}
    return ", ".join(f"{m} ({served.get(m, 0)} ticks)" for m in fold.get("members") or []) or "-"


def tick_losses_markdown(rows: list[tuple[str, dict | None]], fold_word: str = "fold") -> list[str]:
    """Markdown of where the moving ticks went (:func:`terrainml.stream.app.tick_losses.tick_losses`),
    one row per (name, losses); rows without losses are left out."""
    rows = [(name, los) for name, los in rows if los and los.get("moving_ticks")]
    if not rows:
        return []

    def pct(los: dict, kind: str) -> str:
        return _f(los["kinds"].get(kind, 0) / los["moving_ticks"], 1, 100)

    def reasons(los: dict) -> str:
        top = sorted(los["fallback_reasons"].items(), key=lambda kv: -kv[1])[:3]
        return ", ".join(f"{r} {_f(n / los['moving_ticks'], 1, 100)}" for r, n in top) or "-"

    settle_s = rows[0][1].get("settle_s", float("nan"))
    return ["#### Where the moving ticks went", "",
            "Windows right: the windows the served path classified on moving labelled ground, each "
            "scored by its own class against the label at its end. Every moving labelled tick is then "
            "one of: served right; a fallback (top reasons, % of moving ticks; `unknown_terrain` is "
            "unknown ground flagged on known ground); a wrong class within "
            f"{settle_s:g} s of a change (transition); "
            "a wrong class while the latest window was right (fusion lag); a wrong class with the "
            "window wrong too (classifier).", "",
            markdown_table([fold_word, "windows right %", "ticks right %", "fallback %", "top fallback reasons",
                            "transition %", "fusion lag %", "classifier %"],
                           [[name, _f(los["windows_right"] / los["windows"], 1, 100) if los["windows"] else "n/a",
                             pct(los, "right"), pct(los, "fallback"), reasons(los), pct(los, "transition"),
                             pct(los, "fusion_lag"),
                             _f((los["kinds"]["window_wrong"] + los["kinds"]["no_window"]) / los["moving_ticks"],
                                1, 100)] for name, los in rows]), ""]


def preflight_markdown(pre: dict | None) -> list[str]:
    """Markdown of the data checks run before training: the rule applied to each class it names
    (a class with a single run, classes without terrain parameters) and the desired-slip source."""
    if not pre:
        return []
    md = ["### Data checks and the rules applied", "",
          "Runs per class: " + ", ".join(f"{k} {v}" for k, v in pre.get("runs_per_class", {}).items()) + ".", "",
          f"Desired slip: {pre.get('desired_slip')}.", ""]
    for name, rule in (pre.get("rules") or {}).items():
        md += [f"- class `{name}`: {rule}"]
    return md + ([""] if pre.get("rules") else [])
