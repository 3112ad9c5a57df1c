"""``terrainml train`` with ``--windows auto`` / ``--model auto``: select, prove, calibrate, save.

:func:`train_auto` takes the user's ingested runs and

1. cuts them with every candidate window spec (:data:`~terrainml.pipeline.candidates.SELECT_SPECS`;
   a spec that cannot be cut, or keeps too few windows of a class, is named and left out);
2. selects the spec and the model under nested run-grouped CV (:func:`~terrainml.pipeline.
   select.select`): the honest figure of the choice comes from outer folds it never saw;
3. replays each outer fold's held-out runs through the online predictor, with that fold's model
   saved as a model folder and loaded like ``terrainml predict`` loads one
   (:mod:`terrainml.pipeline.replay`), with its novelty score fitted on the fold's training runs
   (so the replay serves ``unknown_terrain`` as ``predict`` would); a model whose replay
   classifies on too few moving ticks is refused (:class:`ReplayRefused`, report written, no
   model saved) unless ``allow_unproven``;
4. fits the chosen candidate on every window of its spec, with the temperature fitted on its
   out-of-fold probabilities (:mod:`terrainml.models.calibration`) and its novelty score
   (:mod:`terrainml.models.novelty`, threshold from inner grouped folds), and saves it with the
   report (every candidate side by side, the choice and why, per-fold replay, ECE before and
   after calibration).

The artifact keeps one served model per folder (its manifest entry carries its calibration);
models for sensor subsets can be added as further entries of the same folder.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from terrainml.atomic import write_text
from terrainml.evaluation.metrics import latency_per_window_ms
from terrainml.evaluation.report import selection_markdown, write_report
from terrainml.features.windows import WindowSpec
from terrainml.models.artifacts import json_safe, save_artifact, write_manifest
from terrainml.models.calibration import CalibratedModel, Temperature
from terrainml.models.ensemble import ProbabilityAverage
from terrainml.pipeline.dataset import Dataset, build_from_tables
from terrainml.pipeline.progress import ProgressFn, report
from terrainml.pipeline.train_options import SelectionOptions, ReplayOptions, TrainOptions
from terrainml.pipeline.replay import ReplayRefused, pooled_replay, replay_refusal
from terrainml.pipeline import train as train_lib  # make_factory read at call time
from terrainml.pipeline.candidates import candidate_window_specs
from terrainml.pipeline.select import Selection, select
from terrainml.pipeline.fold_replay import replay_folds, served_novelty, table_attachment
from terrainml.pipeline.train import (MIN_RUNS_PER_CLASS, TrainResult, class_names_of, dataset_summary,
                                      desired_slip_table_for, fold_model, provenance_of)
from terrainml.robot import RobotSpec

__all__ = ["train_auto", "build_candidates", "AutoResult", "ReplayRefused"]


@dataclass
class AutoResult:
    """What :func:`train_auto` did: the selection, the replay per outer fold, the saved result."""

    selection: Selection
    replay: list
    replay_pooled: dict
    refusal: str
    train: TrainResult | None
    timing_s: dict = field(default_factory=dict)
    dataset: Dataset | None = None  # the chosen spec's windows (its sensor members subset them)


def build_candidates(tables: Sequence[pd.DataFrame], robot: RobotSpec,
                     specs: str | Sequence[str | WindowSpec] = "auto", preset: str = "robust",
                     sensors: Sequence[str] | None = None, n_jobs: int = 1,
                     progress: ProgressFn | None = None) -> tuple[dict, dict]:
    """({spec name: Dataset}, {spec name: why it cannot be cut}) of the runs for every candidate
    spec (``auto``, names or parsed specs; ``progress``: a
    :class:`~terrainml.pipeline.progress.Step` of stage ``windows`` per spec)."""
    out, failed = {}, {}
    parsed = candidate_window_specs(specs)
    names = [s.name for s in parsed]
    for i, (name, unresolved) in enumerate(zip(names, parsed)):
        report(progress, "windows", i, len(names), "specs", f"cutting the runs with the {name!r} spec")
        try:
            spec = unresolved.resolve(robot, sensors)
            ds = build_from_tables(tables, robot, preset, spec, n_jobs=n_jobs)
        except Exception as exc:  # noqa: BLE001 - a spec this robot cannot feed is a reported non-candidate
            failed[name] = f"{type(exc).__name__}: {exc}"
            continue
        if len(ds.windows) == 0:
            failed[name] = "no window passes its rules"
            continue
        out[name] = ds
    report(progress, "windows", len(names), len(names), "specs")
    return out, failed


def _fit_final(ds: Dataset, model: str, seed: int, say) -> tuple[dict, dict, dict]:
    """Fitted models to save ({name: model}), fit times and chosen parameters of the chosen model."""
    W = ds.windows
    fitted, times, params = {}, {}, {}
    bases = model.split("+")
    for i, base in enumerate(bases):
        report(say, "final fit", i, len(bases), "models", f"{base} on {len(W)} windows")
        m = train_lib.make_factory(base, ds, seed)()
        t0 = time.perf_counter()
        m.fit(W, W.y, groups=W.groups)
        times[base] = time.perf_counter() - t0
        params[base] = dict(getattr(m, "best_params_", {}) or {})
        fitted[base] = m
        report(say, "final fit", i + 1, len(bases), "models", base)
    if "+" in model:
        fitted[model] = ProbabilityAverage.from_fitted([fitted[b] for b in model.split("+")])
    return fitted, times, params


def _save(out: Path, ds: Dataset, fitted: dict, served: str, temperature: float, table: Any,
          extra: dict | None = None, metrics: dict | None = None, novelty: Any = None) -> dict:
    """Save a model folder as ``terrainml predict`` loads it; ``novelty``: (name, scorer, info) or None."""
    classes = sorted(set(ds.windows.y.tolist()))
    return save_artifact(out, fitted, provenance_of(ds, classes), metrics_summary=metrics or {},
                         default_model=served,
                         attachments=table_attachment(table),
                         extra=extra or {}, calibration={served: Temperature(temperature).to_dict()},
                         novelty=novelty)


def _replay_folds(sel: Selection, data: dict, tables, table, serve: ReplayOptions, opt: TrainOptions,
                  say) -> list[dict]:
    """Replay of every outer fold's held-out runs through its calibrated model and its novelty score
    (fitted on the fold's training runs only), saved and loaded as ``predict`` loads them, with the
    sensor members its held-out runs call on when ``serve.members``
    (:func:`~terrainml.pipeline.fold_replay.replay_folds`). The outer folds hold the runs of the
    selection's classes only (a class with a single run is never held out, nor known to a fold model)."""
    folds = []
    for k, o in enumerate(sel.outer):
        spec, name = o["chosen"].split("/")  # a fold's spec may differ from another's (chosen per fold)
        model = sel.outer_models[k]
        fitted = {name: model}
        if isinstance(model, ProbabilityAverage):
            fitted = {**dict(zip(name.split("+"), model.members_)), **fitted}
        W = data[spec].windows
        train_idx = np.flatnonzero(~np.isin(np.asarray(W.groups).astype(str), o["runs"])
                                   & np.isin(W.y, sel.class_ids))
        folds.append(fold_model(data[spec], o["runs"], fitted, name, W.subset(train_idx), tables, serve, opt.seed,
                                o["temperature"], o["chosen"]))
    return replay_folds(folds, table, opt.seed, say, opt.novelty_false_alarm, n_jobs=opt.n_jobs)


def train_auto(tables: Sequence[pd.DataFrame] | None, robot: RobotSpec, out: str | Path,
               options: TrainOptions | None = None, selection: SelectionOptions | None = None,
               serve: ReplayOptions | None = None, *, datasets: dict | None = None,
               progress: ProgressFn | None = None, preflight: dict | None = None) -> AutoResult:
    """Select, validate on the served path, calibrate and save a model (see the module docstring).

    Parameters
    ----------
    tables : ingested run tables (one per run, per-row ``terrain`` labels): the candidates are cut
        from them and every outer fold's held-out runs replayed; or None with ``datasets`` (e.g. a
        windows file: no other spec can be cut and nothing replayed).
    robot : RobotSpec. out : model folder, created.
    options : :class:`~terrainml.pipeline.train_options.TrainOptions`: folds (K run groups), seed, joblib
        jobs, the novelty threshold's target (for the served model, the replay's fold models and
        the open-set evaluation alike) and ``open_set`` (also the leave-one-class-out evaluation
        of the chosen model's novelty score on the chosen windows: report section). None: defaults.
    selection : :class:`~terrainml.pipeline.train_options.SelectionOptions`: candidate window specs
        and models, time budget (:func:`~terrainml.pipeline.select.select`), nested or not, the
        preset and sensor groups the windows are cut with. None: defaults.
    serve : :class:`~terrainml.pipeline.train_options.ReplayOptions`: replay length, refusal threshold,
        ``allow_unproven``, terrain catalogue of the desired-slip table. None: defaults.
    datasets : {spec: Dataset} already cut (then ``selection.specs`` is not used).
    progress : callback with a short message per step and a
        :class:`~terrainml.pipeline.progress.Step` per unit of the stages ``windows``,
        ``selection`` (per fit), ``served replay`` (per fold), ``final fit`` and ``open set``.
    preflight : the report entry of the checks run before (:mod:`terrainml.pipeline.preflight`).

    Returns
    -------
    AutoResult. Raises :class:`ReplayRefused` (after writing the report) when the replay refuses
    the model and ``serve.allow_unproven`` is False.
    """
    say = progress or (lambda msg: None)
    out = Path(out)
    opt, choice, serve = options or TrainOptions(), selection or SelectionOptions(), serve or ReplayOptions()
    t0 = time.perf_counter()
    data, failed = _candidate_data(tables, robot, choice, opt.n_jobs, datasets, say)
    t_windows = time.perf_counter() - t0
    first = next(iter(data.values()))
    table = desired_slip_table_for(first, robot, serve.catalogue)
    budget_s = None if choice.budget_min is None else 60.0 * float(choice.budget_min)
    sel = select(data, choice.models, folds=opt.folds, seed=opt.seed, n_jobs=opt.n_jobs, budget_s=budget_s,
                 table=table, progress=say, nested=choice.nested)
    sel.infeasible = {**failed, **sel.infeasible}
    t_sel = time.perf_counter() - t0 - t_windows
    replay = tables is not None
    folds_replay = (_replay_folds(sel, data, tables, table, serve, opt, say) if replay else [])
    pooled = pooled_replay([f for f in folds_replay if f.get("moving_ticks")]) if folds_replay else {}
    refusal = replay_refusal(pooled, serve.min_classified_share) if replay else ""
    t_replay = time.perf_counter() - t0 - t_windows - t_sel
    ds = data[sel.chosen.spec]
    res_doc = {"selection": _selection_doc(sel), "preflight": preflight,
               "replay": {"folds": folds_replay, "pooled": pooled, "refusal": refusal,
                          "overridden": bool(refusal and serve.allow_unproven), "segment_s": serve.segment_s,
                          "min_classified_share": serve.min_classified_share}}
    if refusal and not serve.allow_unproven:
        out.mkdir(parents=True, exist_ok=True)
        _write_docs(out, None, res_doc, sel)
        raise ReplayRefused(f"{refusal}; not saved; override with --allow-unproven", out)
    tr, final_s = _fit_and_save(out, ds, sel, table, opt, say)
    timing = {"windows_s": t_windows, "select_s": t_sel, "replay_s": t_replay, "final_fit_s": final_s,
              "total_s": time.perf_counter() - t0}
    if opt.open_set:
        report(say, "open set", 0, None, "", f"each class of {sel.chosen.name} held out in turn")
        tr.open_set = train_lib.evaluate_open_set(ds, sel.chosen.model, opt, progress=say)
    res_doc["timing_s"] = timing
    _write_docs(out, tr, res_doc, sel)
    tr.manifest = write_manifest(out)
    return AutoResult(sel, folds_replay, pooled, refusal, tr, timing, ds)


def _fit_and_save(out: Path, ds: Dataset, sel: Selection, table: Any, opt: TrainOptions,
                  say) -> tuple[TrainResult, float]:
    """The chosen candidate fitted on every window, calibrated, with its novelty score, saved.

    Returns the TrainResult of the report and the seconds of the final fits.
    """
    seed = opt.seed
    fitted, times, params = _fit_final(ds, sel.chosen.model, seed, say)
    served = sel.chosen.model
    cal = CalibratedModel(fitted[served], Temperature(sel.temperature))
    lat = latency_per_window_ms(cal, ds.windows, n_calls=min(200, max(20, len(ds.windows))))
    cv = sel.cv[sel.chosen.name]
    cv.name = served
    fit_s = float(sum(times.values()))
    tr = TrainResult(out, {served: {"cv": cv, "fit_time_s": fit_s, "latency": lat,
                                    "params": params if len(params) > 1 else next(iter(params.values()))}},
                     served, sel.class_ids, sel.class_names, len(sel.partition), seed, _summary(ds), None,
                     fitted={served: cal})
    # the novelty score of the windows the served model was fitted on
    novelty = served_novelty(fitted[served], served, ds.windows, seed, say, opt.novelty_false_alarm)
    _save(out, ds, fitted, served, sel.temperature, table, novelty=novelty,
          extra={"folds": len(sel.partition), "seed": seed, "n_windows": len(ds.windows),
                 "latency_ms": {served: lat}, "selection": {"chosen": sel.chosen.name,
                                                           "nested_balanced_accuracy": sel.honest}},
          metrics={served: cv.summary})
    return tr, fit_s


def _candidate_data(tables, robot: RobotSpec, choice: SelectionOptions, n_jobs: int,
                    datasets: dict | None, say) -> tuple[dict, dict]:
    """({spec: Dataset}, {spec: why not}) of the candidates; ValueError when none can be cut."""
    if datasets is not None:
        data, failed = dict(datasets), {}
    else:
        sensors = None if choice.sensors is None else list(choice.sensors)
        data, failed = build_candidates(tables, robot, choice.specs, choice.preset, sensors, n_jobs, say)
    if not data:
        raise ValueError("no window spec can be cut from these runs: " +
                         "; ".join(f"{s}: {r}" for s, r in failed.items()))
    return data, failed


def _summary(ds: Dataset) -> dict:
    """The report's dataset summary of the chosen spec's windows (runs per class from its runs table)."""
    classes = sorted(set(ds.windows.y.tolist()))
    runs = ds.runs[ds.runs["run_class"] >= 0]
    per = {int(c): int(n) for c, n in runs.groupby("run_class").size().to_dict().items()}
    excluded = [c for c, n in per.items() if n < MIN_RUNS_PER_CLASS]
    return dataset_summary(ds, dict(zip(classes, class_names_of(ds, classes))), per, excluded)


def _selection_doc(sel: Selection) -> dict:
    rows = []
    for c in sel.candidates:
        cv = sel.cv.get(c.name)
        inner = [lv.scores.get(c.name) for lv in sel.inner]
        rows.append({"candidate": c.name, "spec": c.spec, "model": c.model,
                     "cv_balanced_accuracy": None if cv is None else cv.summary["balanced_accuracy"]["mean"],
                     "cv_balanced_accuracy_std": None if cv is None else cv.summary["balanced_accuracy"]["std"],
                     "cv_pooled_balanced_accuracy": None if cv is None else cv.pooled["balanced_accuracy"],
                     "cv_ece": None if cv is None else cv.pooled.get("ece"),
                     "n_windows": None if cv is None else int(len(cv.y_true)),
                     "inner_scores": inner, "chosen_in_outer_folds": sum(o["chosen"] == c.name for o in sel.outer),
                     "screened": sel.top.screened.get(c.spec, "")})
    return json_safe({"candidates": rows, "chosen": sel.chosen.name, "infeasible": sel.infeasible,
                      "nested": sel.honest, "outer": sel.outer, "temperature": sel.temperature,
                      "screen_scores": {"top": sel.top.screen_scores,
                                        "inner": [lv.screen_scores for lv in sel.inner]},
                      "partition": [list(map(str, p)) for p in sel.partition], "timing_s": sel.timing_s,
                      "budget_note": sel.budget_note, "nested_cv": sel.nested})


def _write_docs(out: Path, tr: TrainResult | None, doc: dict, sel: Selection) -> None:
    """report.md/json: the chosen model's sections (when saved) and the selection, replay, calibration."""
    base = write_report(out, tr) if tr is not None else {}
    full = json_safe({**base, **doc, "nested_balanced_accuracy": sel.honest["mean"],
                      "nested_balanced_accuracy_std": sel.honest["std"],
                      "nested_balanced_accuracy_pooled": sel.honest["pooled"], "chosen": sel.chosen.name})
    write_text(out / "report.json", json.dumps(full, indent=2, sort_keys=True, allow_nan=False) + "\n")
    md = (out / "report.md").read_text().splitlines() if tr is not None else [f"# Training report: {out.name}", ""]
    head, rest = md[:2], md[2:]
    write_text(out / "report.md", "\n".join(head + selection_markdown(full) + rest) + "\n")
