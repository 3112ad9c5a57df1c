"""Classification of the latest online window with the offline window and feature code.

:class:`WindowClassifier` takes the ring buffer's last 2 s of estimator rows (a DataFrame laid
out like the offline EST table), cuts it with :func:`terrainml.features.windows.cut_windows`
(``online=True``: same steady rules and channels as training), computes the artifact's feature
set with :class:`terrainml.features.sets.FeatureSet` and calls the model's ``predict_proba``.
A window the steady rules reject yields ``None`` (the predictor keeps the previous
classification, which ages towards the stale fallback) and leaves the rules it failed, and the
channels that were invalid, in ``last_rejection`` (a :class:`Rejection`): serving counts them per
rule and names them when the robot moves without a classification (:mod:`terrainml.stream.tick.scheduler`).
With the model's novelty scorer (:class:`~terrainml.models.novelty.NoveltyScorer`,
saved with the model by ``train``), each classified window is also scored in the model's own
feature space (:func:`~terrainml.models.novelty.model_features`, the features the scorer was
fitted on; :func:`~terrainml.models.novelty.proba_and_features` computes them once for the
probabilities and the score): ``last_novelty`` holds its score over the threshold and whether
it is over it, which the fusion filter turns into unknown ground (:mod:`terrainml.stream.tick.fusion`).

:func:`load_serving_model` opens a verified model folder (``runs/NAME``) through
:mod:`terrainml.models.artifacts` (hashes checked on load) and returns what the predictor needs.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from terrainml.classes import TERRAIN_CLASSES
from terrainml.features.windows import RULES, Windows, WindowSpec, channel_column, cut_windows
from terrainml.lookup.catalogue import BUILTIN_CATALOGUES
from terrainml.lookup.table import ClassFreeTargets, DesiredSlipTable
from terrainml.models.artifacts import TABLE_FILE, load_artifact
from terrainml.models.novelty import NoveltyScorer, moving_windows, proba_and_features
from terrainml.robot import RobotSpec

log = logging.getLogger("terrainml.stream")


class ModelLoadError(ValueError):
    """The model folder cannot be used for serving (the message names the file)."""


@dataclass
class ServingMember:
    """A sensor member of a model folder: its classifier and the groups it needs.

    ``window_spec`` is the member's own (its classifier cuts it; the predictor's ring holds the
    longest window of the model and its members).
    """

    name: str
    classifier: "WindowClassifier"
    window_spec: WindowSpec
    sensors: list[str] | None


@dataclass
class ServingModel:
    """What :func:`load_serving_model` opens: everything the predictor is built from.

    ``window_spec`` is the one spec of serving: the classifier cuts with it and the predictor
    sizes its ring buffer and classification hop from it (no numbers are split off it).
    """

    robot: RobotSpec
    table: Any
    classifier: "WindowClassifier"
    preset: str
    class_names: list[str]
    window_spec: WindowSpec
    #: sensor groups the model needs (None: every group the robot has; design §9)
    sensors: list[str] | None = None
    #: sensor members, best first (their grouped CV balanced accuracy): served when a group
    #: of the model is missing or unhealthy (:mod:`terrainml.stream.tick.predictor`)
    members: list[ServingMember] = field(default_factory=list)


def _raw_columns(channel: str, robot: RobotSpec) -> tuple[str, ...]:
    col, vcols, _ = channel_column(channel, robot)
    return (col, *vcols)


def _table_for(art: Any, robot: RobotSpec, names: Sequence[str]) -> Any:
    """The table for a folder without a stored one: the reference table for our classes, else the
    first built-in catalogue with every class, else (class names no catalogue knows, e.g. a team's
    own) :class:`~terrainml.lookup.table.ClassFreeTargets`: every class served the class-free safe
    cap, flagged on every tick (design §10)."""
    if all(n in TERRAIN_CLASSES for n in names):
        return DesiredSlipTable.build(robot)
    for cat in BUILTIN_CATALOGUES:
        try:
            return DesiredSlipTable.from_catalogue(cat, robot, list(names))
        except Exception:  # noqa: BLE001 - this catalogue lacks a class: try the next
            continue
    log.warning("%s: no terrain parameters for the model's classes %s (no built-in catalogue has them): "
                "every class is served the class-free safe cap (retrain with `train --catalogue CAT.yaml` "
                "for class targets)", art.path, list(names))
    return ClassFreeTargets.for_robot(robot, list(names))


@dataclass(frozen=True)
class Rejection:
    """Why the latest online window was not classified: the window rules it failed.

    Attributes
    ----------
    rules : names of :data:`~terrainml.features.windows.RULES` the window failed (none: the
        buffer held no candidate window).
    channels : channels valid on too few of its ticks (``channel_valid``), by name.
    """

    rules: tuple[str, ...]
    channels: tuple[str, ...] = ()


def rejection_of(counts: Mapping[str, Any]) -> Rejection:
    """The :class:`Rejection` of one :func:`~terrainml.features.windows.cut_windows` call's counts."""
    rules = tuple(r for r in RULES if counts.get(r, 0))
    return Rejection(rules, tuple(sorted(counts.get("invalid_channels") or {})))


class WindowClassifier:
    """Probabilities for the latest window, or None when it is not steady.

    Parameters
    ----------
    model : fitted classifier with ``predict_proba`` and ``classes_`` (class ids).
    robot : RobotSpec used by the window rules.
    features : fitted/stateless transformer (``FeatureSet``) mapping windows to a feature
        matrix, or None when ``model`` consumes raw windows itself (e.g. the CNN wrapper).
    window_spec : the artifact's ``WindowSpec``: the windows are cut with it (the predictor's
        ring buffer and hop come from the same spec).
    class_ids : class ids of the probabilities (default ``model.classes_``).
    novelty : the model's fitted :class:`~terrainml.models.novelty.NoveltyScorer` with its
        threshold, or None (no novelty: ``last_novelty`` stays None).
    class_names : names by class id (``class_names[cid]``, the served message's ``terrain_name``),
        or None (the predictor then names ids as the reference's eight classes).
    """

    def __init__(self, model: Any, robot: RobotSpec, features: Any, window_spec: WindowSpec,
                 class_ids: Sequence[int] | None = None, novelty: NoveltyScorer | None = None,
                 class_names: Sequence[str] | None = None):
        self.model = model
        self.class_names = None if class_names is None else list(class_names)
        self.robot = robot
        self.features = features
        self.window_spec = window_spec
        ids = class_ids if class_ids is not None else getattr(model, "classes_", None)
        if ids is None:
            raise ModelLoadError("model has no classes_ and no class ids were given")
        self.class_ids = [int(c) for c in ids]
        # run-table columns the windows read that the estimator may not pass through (e.g. the
        # gyro roll and pitch rates of the side channels): the predictor copies them into its rows
        chans = window_spec.channels or ()
        self.raw_columns = tuple(dict.fromkeys(c for ch in chans for c in _raw_columns(ch, robot)))
        #: why the latest window was not classified (None after a classified one)
        self.last_rejection: Rejection | None = None
        if novelty is not None and novelty.threshold is None:
            raise ModelLoadError("the model's novelty scorer has no threshold")
        self.novelty = novelty.prepare_serving() if novelty is not None else None
        self._threshold = None if novelty is None else float(novelty.threshold)  # type: ignore[arg-type]
        #: (score over the threshold, over it) of the latest classified window; None without a scorer
        self.last_novelty: tuple[float, bool] | None = None

    def classify(self, window: pd.DataFrame) -> np.ndarray | None:
        """Probabilities (K,) for the latest window of an EST DataFrame, or None."""
        # labels are not known online: never let a logged label gate or inform the window
        drop = [c for c in window.columns if c in ("terrain", "run_id") or c.startswith("gt_")]
        return self.classify_columns(window.drop(columns=drop))

    def classify_columns(self, columns: Mapping[str, np.ndarray] | pd.DataFrame) -> np.ndarray | None:
        """The same on column arrays (the ring buffer's, labels left out): the serving path.

        :func:`~terrainml.features.windows.cut_windows` cuts the artifact's window spec from the
        arrays directly (no DataFrame) and the model computes only the features it uses (the
        SVM's selected columns), which keeps one update well under a millisecond.
        """
        wins, counts = cut_windows(columns, self.robot, spec=self.window_spec, online=True,
                                   with_meta=False)
        if len(wins) == 0:
            self.last_rejection = rejection_of(counts)
            return None
        self.last_rejection = None
        if len(wins) > 1:  # the latest window only
            wins = Windows(wins.X[-1:], wins.channels, None, wins.rate_hz)  # type: ignore[arg-type]
        x = self.features.transform(wins) if self.features is not None else wins
        if self.novelty is None:
            p = self.model.predict_proba(x)
            self.last_novelty = None
        else:  # the model's features are computed once, for its probabilities and the score
            p, F = proba_and_features(self.model, x)
            self.last_novelty = self._novelty(F, wins)
        return np.asarray(p, dtype=float)[-1]

    def _novelty(self, F: np.ndarray, wins: Windows) -> tuple[float, bool]:
        """(score / threshold, flagged) of the latest window, the last row of its features F
        (n, F) in the model's feature space; with the scorer's moving gate, a window at or under
        its rim speed (``wins``, the cut windows) is never flagged, as in training."""
        scorer = self.novelty
        score = float(scorer.score(F)[-1])  # type: ignore[union-attr]
        thr = float(self._threshold)  # type: ignore[arg-type]
        ratio = score / thr if thr > 0 else (math.inf if score > thr else 0.0)
        moving = None if scorer.moving_mps is None else moving_windows(wins, scorer.moving_mps)[-1:]  # type: ignore[union-attr]
        flagged = bool(scorer.flag(np.array([score]), moving)[0])  # type: ignore[union-attr]
        return (ratio if math.isfinite(ratio) else 1e6), flagged


def _leaves(d: Any, prefix: str = "") -> dict[str, Any]:
    """Flat ``{"wheels[0].x_m": -0.5, ...}`` of a robot spec dict."""
    if isinstance(d, dict):
        out: dict[str, Any] = {}
        for k, v in d.items():
            out.update(_leaves(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    if isinstance(d, (list, tuple)):
        out = {}
        for i, v in enumerate(d):
            out.update(_leaves(v, f"{prefix}[{i}]"))
        return out
    return {prefix: d}


def robot_differences(trained: RobotSpec, served: RobotSpec, rel_tol: float = 1e-6) -> list[str]:
    """The fields (name and description aside) where ``served`` differs from ``trained``, each as
    ``"mass_kg 240 vs 80 (x3)"`` (served vs trained); [] when they agree."""
    a, b = _leaves(trained.to_dict()), _leaves(served.to_dict())
    out = []
    for key in sorted(set(a) | set(b)):
        if key in ("name", "description"):
            continue
        va, vb = a.get(key), b.get(key)
        num = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (va, vb))
        if num and math.isclose(float(va), float(vb), rel_tol=rel_tol, abs_tol=1e-12):  # type: ignore[arg-type]
            continue
        if not num and va == vb:
            continue
        ratio = f" (x{float(vb) / float(va):.3g})" if num and float(va) != 0 else ""  # type: ignore[arg-type]
        out.append(f"{key} {vb} vs {va}{ratio}")
    return out


def load_serving_model(model_dir: str | Path, robot: RobotSpec | None = None,
                       model_name: str | None = None,
                       trusted_keys: Sequence[str | Path] | None = None,
                       open_set: bool = True) -> ServingModel:
    """Open ``runs/NAME`` for serving, verified by :func:`terrainml.models.artifacts.load_artifact`.

    The desired-slip table stored with the model is used; if the folder has none, the table is
    built from the robot spec (``DesiredSlipTable.build``). ``class_names`` covers every class id
    of :data:`TERRAIN_CLASSES` (the message's ``class_probabilities`` has one entry per id),
    overridden by the artifact's own names. With ``trusted_keys`` (``KEY.pub`` paths) the folder
    must be signed by one of them (:mod:`terrainml.models.signing`); a refusal names the folder.
    ``open_set`` False serves without the artifact's novelty scores (model and members; the
    artifact is still verified whole): closed-set serving (:class:`ServingConfig`).
    """
    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise ModelLoadError(f"{model_dir}: no such model folder (train one with `terrainml train`)")
    try:
        art = load_artifact(model_dir, model_name, trusted_keys=trusted_keys, members=True)
    except Exception as exc:  # noqa: BLE001 - Artifact/SignatureError name the file; keep the message
        raise ModelLoadError(str(exc)) from None
    rb = robot if robot is not None else art.robot
    if rb.n_wheels != art.robot.n_wheels:
        raise ModelLoadError(f"{model_dir}: model trained for {art.robot.n_wheels} wheels, robot "
                             f"'{rb.name}' has {rb.n_wheels}")
    if robot is not None:
        differ = robot_differences(art.robot, rb)
        if differ:  # served anyway (the user chose the robot), but never silently
            log.warning("%s: serving robot '%s' differs from the model's training robot '%s': %s",
                        model_dir, rb.name, art.robot.name, "; ".join(differ))
    stored = art.attachments.get(TABLE_FILE)  # written by terrainml.pipeline.train
    ids = [int(c) for c in art.class_ids]
    own = [str(n) for n in (art.class_names or [])]
    try:
        table = (DesiredSlipTable.from_json(stored.read_text(), robot=art.robot, source=str(stored))
                 if stored is not None else _table_for(art, rb, own or [TERRAIN_CLASSES[i] for i in ids]))
        if own:  # the policy looks targets up by id: the table's class cid must be the model's
            table.check_classes(ids, own, str(stored or model_dir))
    except ValueError as exc:
        raise ModelLoadError(str(exc)) from None
    # names by class id: the reference's eight (a model on some of them keeps their ids), or the
    # model's own class set, so class_probabilities has the model's length and names
    if not own or all(n in TERRAIN_CLASSES for n in own):
        names = list(TERRAIN_CLASSES) + [str(i) for i in range(len(TERRAIN_CLASSES), max(ids) + 1)]
    else:
        names = [str(i) for i in range(max(ids) + 1)]
    for cid, name in zip(ids, own):
        names[cid] = name
    clf = WindowClassifier(art.model, rb, art.features, art.window_spec,
                           class_ids=[int(c) for c in art.model.classes_],
                           novelty=art.novelty if open_set else None, class_names=names)
    return ServingModel(rb, table, clf, art.preset or "robust", names, art.window_spec,
                        sensors=None if art.sensors is None else list(art.sensors),
                        members=_members(art, rb, clf.class_ids, open_set))


def _members(art: Any, robot: RobotSpec, class_ids: Sequence[int],
             open_set: bool = True) -> list[ServingMember]:
    """The folder's sensor members for serving, best first (ModelLoadError: other class ids);
    ``open_set`` False: without their novelty scores."""
    entries = art.manifest.get("sensor_members") or []
    out = []
    for entry, m in zip(entries, art.members):
        clf = WindowClassifier(m.model, robot, m.features, m.window_spec,
                               class_ids=[int(c) for c in m.model.classes_],
                               novelty=m.novelty if open_set else None)
        if clf.class_ids != list(class_ids):
            raise ModelLoadError(f"{m.path}: member classes {clf.class_ids} differ from the model's {list(class_ids)}")
        out.append((-(entry.get("balanced_accuracy") or 0.0), len(out),
                    ServingMember(str(entry["name"]), clf, m.window_spec,
                                  None if m.sensors is None else list(m.sensors))))
    return [m for *_, m in sorted(out, key=lambda e: e[:2])]


def one_window_spec(window_spec: WindowSpec | None, classifier: Any) -> WindowSpec:
    """The one window spec of serving: the given one, else the classifier's, else the default."""
    own = getattr(classifier, "window_spec", None)
    if window_spec is None:
        return own if own is not None else WindowSpec()
    if own is not None and own != window_spec:
        raise ValueError(f"the classifier cuts windows of {own!r} but the predictor was given "
                         f"{window_spec!r}: serving takes one window spec")
    return window_spec
