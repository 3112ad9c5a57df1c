"""Classification of the latest online window with the offline window and feature code.

:class:`WindowClassifier` takes the ring buffer's last 2 s of estimator rows (a DataFrame laid
out like the offline EST table), cuts it with :func:`terrainml.features.windows.cut_windows`
(``online=True``: same steady rules and channels as training), computes the artifact's feature
set with :class:`terrainml.features.sets.FeatureSet` and calls the model's ``predict_proba``.
A window the steady rules reject yields ``None`` (the predictor keeps the previous
classification, which ages towards the stale fallback).

:func:`load_serving_model` opens a verified model folder (``runs/NAME``) through
:mod:`terrainml.models.artifacts` (hashes checked on load) and returns what the predictor needs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from terrainml.classes import TERRAIN_CLASSES
from terrainml.features.windows import WindowSpec, cut_windows
from terrainml.lookup.table import DesiredSlipTable
from terrainml.models.artifacts import load_artifact
from terrainml.robot import RobotSpec, load_robot


class ModelLoadError(ValueError):
    """The model folder cannot be used for serving (the message names the file)."""


@dataclass
class ServingModel:
    robot: RobotSpec
    table: Any
    classifier: "WindowClassifier | None"
    preset: str
    class_names: list[str]
    window_s: float = 2.0
    hop_s: float = 0.5
    rate_hz: float = 100.0


class WindowClassifier:
    """Probabilities for the latest window, or None when it is not steady.

    Parameters
    ----------
    model : fitted classifier with ``predict_proba`` and ``classes_`` (class ids).
    robot : RobotSpec used by the window rules.
    features : fitted/stateless transformer (``FeatureSet``) mapping windows to a feature
        matrix, or None when ``model`` consumes raw windows itself (e.g. the CNN wrapper).
    window_spec : the artifact's ``WindowSpec`` (None: default).
    """

    def __init__(self, model: Any, robot: RobotSpec, features: Any = None, window_spec: Any = None,
                 class_ids: Sequence[int] | None = None):
        self.model = model
        self.robot = robot
        self.features = features
        self.window_spec = window_spec
        ids = class_ids if class_ids is not None else getattr(model, "classes_", None)
        if ids is None:
            raise ModelLoadError("model has no classes_ and no class ids were given")
        self.class_ids = [int(c) for c in ids]

    def classify(self, window: pd.DataFrame) -> np.ndarray | None:
        spec = self.window_spec if self.window_spec is not None else WindowSpec()
        # labels are not known online: never let a logged label gate or inform the window
        drop = [c for c in window.columns if c in ("terrain", "run_id") or c.startswith("gt_")]
        res = cut_windows(window.drop(columns=drop), self.robot, spec=spec, online=True)
        wins = res[0] if isinstance(res, tuple) else res
        if wins is None or len(wins) == 0:
            return None
        x = self.features.transform(wins) if self.features is not None else wins
        p = np.asarray(self.model.predict_proba(x), dtype=float)
        return p[-1]


def load_serving_model(model_dir: str | Path, robot: RobotSpec | str | None = None,
                       model_name: str | None = None) -> ServingModel:
    """Open ``runs/NAME`` for serving, verified by :func:`terrainml.models.artifacts.load_artifact`.

    The desired-slip table stored with the model is used; if the folder has none, the table is
    built from the robot spec (``DesiredSlipTable.build``). ``class_names`` covers every class id
    of :data:`TERRAIN_CLASSES` (the message's ``class_probabilities`` has one entry per id),
    overridden by the artifact's own names.
    """
    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise ModelLoadError(f"{model_dir}: no such model folder (train one with `terrainml train`)")
    try:
        art = load_artifact(model_dir, model_name)
    except Exception as exc:  # noqa: BLE001 - ArtifactError names the file; keep the message
        raise ModelLoadError(str(exc)) from None
    rb = robot if isinstance(robot, RobotSpec) else (load_robot(robot) if robot else art.robot)
    if rb.n_wheels != art.robot.n_wheels:
        raise ModelLoadError(f"{model_dir}: model trained for {art.robot.n_wheels} wheels, robot "
                             f"'{rb.name}' has {rb.n_wheels}")
    stored = art.attachments.get("desired_slip_table.json")  # written by terrainml.pipeline.train
    try:
        table = (DesiredSlipTable.from_json(stored.read_text(), robot=art.robot, source=str(stored))
                 if stored is not None else DesiredSlipTable.build(rb))
    except ValueError as exc:
        raise ModelLoadError(str(exc)) from None
    ids = [int(c) for c in art.class_ids]
    names = list(TERRAIN_CLASSES) + [str(i) for i in range(len(TERRAIN_CLASSES), max(ids) + 1)]
    for cid, name in zip(ids, art.class_names or []):
        names[cid] = str(name)
    clf = WindowClassifier(art.model, rb, art.features, art.window_spec,
                           class_ids=[int(c) for c in art.model.classes_])
    return ServingModel(rb, table, clf, art.preset or "robust", names,
                        window_s=float(art.window_spec.window_s),
                        hop_s=float(art.window_spec.online_hop_s),
                        rate_hz=float(art.window_spec.rate_hz))
