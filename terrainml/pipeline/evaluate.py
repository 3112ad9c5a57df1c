"""Score a saved model folder (verified on load) on another window dataset, classes matched by name.

:func:`evaluate` (``terrainml evaluate MODEL_DIR``) relabels the data's classes to the model's by
name (:func:`match_classes`, with ``--class-map`` renames: :func:`parse_class_map`) and computes
the metrics of :func:`~terrainml.evaluation.metrics.classification_metrics`, the desired-slip
error through the table stored with the model. Given the labelled run tables too (``evaluate``
on a folder of logs), :func:`served_replay` serves them tick by tick through the online predictor
and says where the moving ticks went, as ``train``'s served replay does.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from terrainml.classes import TERRAIN_CLASSES
from terrainml.evaluation.metrics import classification_metrics, is_ordered
from terrainml.models.artifacts import load_artifact
from terrainml.pipeline.dataset import Dataset
from terrainml.pipeline.replay import make_course, replay_course
from terrainml.pipeline.train import served_table
from terrainml.pipeline.train_options import REPLAY_SEGMENT_S

__all__ = ["evaluate", "served_replay", "ClassMismatchError", "parse_class_map", "match_classes"]


class ClassMismatchError(ValueError):
    """The data's (or a table's) class names differ from the model's (both sets listed)."""


def parse_class_map(text: str | None) -> dict[str, str]:
    """``"A=B,C=D"`` -> ``{"A": "B", "C": "D"}`` (data class name -> model class name)."""
    out: dict[str, str] = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        if item.count("=") != 1 or not all(p.strip() for p in item.split("=")):
            raise ValueError(f"--class-map: {item!r} is not DATA_CLASS=MODEL_CLASS")
        a, b = (p.strip() for p in item.split("="))
        out[a] = b
    return out


def match_classes(data_names: Sequence[str], model_names: Sequence[str],
                  class_map: dict[str, str] | None = None, source: str = "the data") -> dict[str, str]:
    """Data class name -> model class name, matched by name (never by id).

    Every data class must be one of the model's (after ``class_map``); otherwise
    :class:`ClassMismatchError` lists both sets and the names that differ.
    """
    class_map = dict(class_map or {})
    unknown_keys = sorted(set(class_map) - set(data_names))
    if unknown_keys:
        raise ClassMismatchError(f"--class-map names {unknown_keys}, which {source} does not have "
                                 f"(its classes: {sorted(data_names)})")
    mapping = {n: class_map.get(n, n) for n in data_names}
    missing = sorted({n for n, m in mapping.items() if m not in set(model_names)})
    if missing:
        raise ClassMismatchError(
            f"class names differ: {source} has {sorted(data_names)}, the model has {sorted(model_names)}; "
            f"not in the model: {missing}. Map them with --class-map DATA=MODEL,... if they are the "
            "same terrain under another name")
    return mapping


def evaluate(model_dir: str | Path, ds: Dataset, model: str | None = None,
             class_map: dict[str, str] | None = None, tables: Sequence[pd.DataFrame] | None = None,
             **load_kwargs: Any) -> dict:
    """Score a saved model (verified on load) on a dataset, classes matched by name.

    ``class_map`` maps data class names to model class names (``--class-map A=B``); a data class
    the model lacks is refused (:class:`ClassMismatchError`, both sets listed). ``tables``: the
    labelled run tables the dataset was built from; given, they are also served tick by tick
    (:func:`served_replay`). ``load_kwargs`` go to
    :func:`~terrainml.models.artifacts.load_artifact` (e.g. ``trusted_keys``).

    Returns
    -------
    dict with ``balanced_accuracy, accuracy, macro_f1, desired_slip_error_mean, n_windows``, the
    other metrics of :func:`classification_metrics`, ``model``, ``model_dir``,
    ``training_fingerprint`` and ``data_fingerprint``; with ``tables``, ``served_replay``.
    """
    art = load_artifact(model_dir, model, **load_kwargs)
    W = ds.windows
    model_names = list(art.class_names) or [str(c) for c in art.class_ids]
    data_ids = sorted(set(W.y.tolist()))
    all_names = W.attrs.get("all_class_names")
    if all_names is not None:
        data_name = {i: str(all_names[i]) if 0 <= i < len(all_names) else str(i) for i in data_ids}
    else:
        data_name = {i: n for i, n in zip(ds.class_ids, ds.class_names)}
        data_name = {i: data_name.get(i, TERRAIN_CLASSES[i] if 0 <= i < len(TERRAIN_CLASSES) else str(i))
                     for i in data_ids}
    mapping = match_classes([data_name[i] for i in data_ids], model_names, class_map)
    model_id = dict(zip(model_names, art.class_ids))
    relabel = {i: int(model_id[mapping[data_name[i]]]) for i in data_ids}
    missing = [c for c in art.channels if c not in W.channels]
    if missing:
        raise ValueError(f"the data lacks channels {missing} the model {art.model_name!r} was trained on")
    W = W.select_channels(art.channels)
    if len(W) == 0:
        raise ValueError("the evaluation data has no windows")
    proba = np.asarray(art.model.predict_proba(W), dtype=float)
    classes = np.asarray(art.model.classes_)
    y_pred = classes[np.argmax(proba, axis=1)]
    y_true = np.asarray([relabel[int(v)] for v in W.y], dtype=np.int64)
    m = classification_metrics(y_true, y_pred, proba, classes, served_table(art),
                               ordered=is_ordered(art.class_names or None))
    m.update({"model": art.model_name, "model_kind": art.kind, "model_dir": str(model_dir),
              "training_fingerprint": art.manifest.get("training_fingerprint"),
              "data_fingerprint": ds.fingerprint,
              "class_names": art.class_names,
              "class_map": {k: v for k, v in mapping.items() if k != v}})
    if tables:
        m["served_replay"] = served_replay(model_dir, tables, relabel)
    return m


def served_replay(model_dir: str | Path, tables: Sequence[pd.DataFrame], relabel: dict[int, int],
                  segment_s: float = REPLAY_SEGMENT_S) -> dict[str, Any]:
    """Serve ``segment_s`` s of every labelled run (from its middle, classes interleaved) through
    the online predictor of ``model_dir``, as ``train``'s served replay does.

    ``relabel`` maps the data's class ids to the model's (matched by name); a row whose class the
    model lacks, or without a label, is unlabelled (-1) and not scored.

    Returns
    -------
    dict: :func:`~terrainml.pipeline.replay.replay_course`'s figures, with ``losses`` (where the
    moving ticks went, :mod:`terrainml.stream.app.tick_losses`) and ``runs``.
    """
    labelled = []
    for df in tables:
        if not len(df) or "terrain" not in df.columns:
            continue
        df = df.copy()
        lab = df["terrain"].to_numpy()
        df["terrain"] = [relabel.get(int(v), -1) if v == v and v >= 0 else -1 for v in lab]
        if (df["terrain"] >= 0).any():
            labelled.append(df)
    if not labelled:
        raise ValueError("no run has a terrain label the model knows: nothing to serve and score")
    out = replay_course(model_dir, make_course(labelled, segment_s=segment_s))
    out["runs"] = len(labelled)
    return out
