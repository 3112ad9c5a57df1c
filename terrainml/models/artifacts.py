"""Model artifacts: a folder of files plus a ``manifest.json`` that hashes every one of them.

Layout of ``runs/NAME/`` (design §9)::

    manifest.json                 this module's manifest (written last)
    svm/model.skops               SVM (skops, no pickle)
    cnn/cnn_weights.safetensors   CNN weights (safetensors) } written by CNNClassifier.save
    cnn/cnn_config.json           CNN config (JSON)         }
    desired_slip_table.json       an attachment: the lookup table served with this model
    report.md, report.json, confusion_<model>.png, folds_<model>.csv, ...

The manifest records: ``schema``/``schema_version``, terrainml version, UTC time, classes
(ids and names, from the data), channels and the window spec, feature names per model, the
robot spec and its sha256, the training-data fingerprint, a metrics summary, the models
(name, kind, files) with the default one, ``attachments`` (names of files the caller stores with
the models, e.g. the desired-slip table written by :mod:`terrainml.pipeline.train`; this module
does not read them), and ``files``: sha256 and size of every other file in the folder. It is
written in one canonical form (sorted keys, 2-space indent) and carries ``manifest_sha256``, the
sha256 of that canonical text without the field, so one changed byte anywhere in it is detected.

:func:`load_artifact` verifies, before anything is deserialised: the manifest's canonical form,
self-hash, schema and version; every listed file's presence, size and sha256; the robot spec's
sha256. Then the SVM is loaded with ``skops.io.load`` after checking
``skops.io.get_untrusted_types`` against :data:`ALLOWED_SKOPS_TYPES` (an explicit allow-list; an
unknown type refuses), the CNN through safetensors + JSON. Nothing is unpickled. Every refusal
raises :class:`ArtifactError` with a message naming the file.

Sensor members: a folder may hold, under ``members/NAME/``, complete model folders
of its own trained on subsets of its sensor groups (without IMU, without currents); the
manifest lists them under ``sensor_members`` (:func:`attach_members`) with their sensors, window
spec and manifest hash, and hashes their files like any other. Serving switches to the best
member whose groups are healthy (:mod:`terrainml.stream.tick.predictor`).

The hashes prove integrity, not origin. With ``trusted_keys``, :func:`load_artifact` first checks
the ed25519 signature ``manifest.sig`` (:mod:`terrainml.models.signing`; not listed in the
manifest, which it signs) and raises :class:`SignatureError` naming the folder.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import skops.io as sio

from terrainml import __version__
from terrainml.atomic import write_text
from terrainml.features.windows import WindowSpec
from terrainml.models.calibration import CalibratedModel, Temperature
from terrainml.models.manifest import (SCHEMA, SCHEMA_VERSION, ArtifactError, json_safe, read_manifest,
                                       verify_artifact, write_manifest)
from terrainml.models.ensemble import ProbabilityAverage
from terrainml.models.novelty import NoveltyError, NoveltyScorer, model_feature_names
from terrainml.models.signing import (MANIFEST_NAME, SIGNATURE_NAME, PublicKeyLike, SignatureError,
                                      verify_artifact_signature)
from terrainml.robot import RobotSpec

__all__ = ["ArtifactError", "Artifact", "TrainingProvenance", "save_artifact", "load_artifact", "verify_artifact",
           "TABLE_FILE", "attach_members", "load_members", "MEMBERS_DIR",
           "read_manifest", "write_manifest", "ALLOWED_SKOPS_TYPES", "MANIFEST_NAME", "SCHEMA",
           "SCHEMA_VERSION", "SIGNATURE_NAME", "SignatureError", "json_safe"]

SKOPS_NAME = "model.skops"
#: the desired-slip table served with a model (an attachment of its folder)
TABLE_FILE = "desired_slip_table.json"

#: Types skops may instantiate besides its own defaults (checked against
#: ``skops.io.get_untrusted_types``). Anything else makes loading refuse.
ALLOWED_SKOPS_TYPES: frozenset[str] = frozenset({
    "terrainml.models.svm.SVMClassifier",
    "terrainml.features.sets.FeatureSet",
    # boosted trees and the side-channel feature family (design §9)
    "terrainml.models.trees.BoostedTrees",
    "terrainml.features.side_channel.SideChannelFeatures",
    "sklearn.ensemble._hist_gradient_boosting.gradient_boosting.HistGradientBoostingClassifier",
    "sklearn.ensemble._hist_gradient_boosting.binning._BinMapper",
    "sklearn.ensemble._hist_gradient_boosting.predictor.TreePredictor",
    "sklearn._loss.loss.HalfMultinomialLoss",
    "sklearn._loss.loss.HalfBinomialLoss",
    "sklearn._loss.link.MultinomialLogit",
    "sklearn._loss.link.LogitLink",
    "sklearn._loss.link.Interval",
    "sklearn._loss._loss.CyHalfMultinomialLoss",
    "sklearn._loss._loss.CyHalfBinomialLoss",
    "sklearn.ensemble._hist_gradient_boosting.gradient_boosting.TreeGrower",
    "numpy.uint8",
    "numpy.float32",
    "numpy.int32",
    "numpy.uint32",
    "numpy.int8",
    "builtins.object",
    "sklearn.calibration.CalibratedClassifierCV",
    "sklearn.calibration._CalibratedClassifier",
    "sklearn.calibration._SigmoidCalibration",
    "sklearn.pipeline.Pipeline",
    "sklearn.preprocessing._data.StandardScaler",
    "sklearn.svm._classes.SVC",
    "sklearn.preprocessing._label.LabelEncoder",
    "sklearn.utils._bunch.Bunch",
    "sklearn.model_selection._split.StratifiedGroupKFold",
    "sklearn.model_selection._split.StratifiedKFold",
    "builtins.slice",
    "numpy.dtype",
    "numpy.ndarray",
    "numpy.int64",
    "numpy.float64",
    "numpy.str_",
    "numpy.bool_",
})


# ---------------------------------------------------------------------------- saving
def _model_kind(model: Any) -> str:
    name = type(model).__name__
    if name == "SVMClassifier":
        return "svm"
    if name == "CNNClassifier":
        return "cnn"
    if name == "BoostedTrees":
        return "hgb"
    if name == "ProbabilityAverage":
        return "average"
    raise ArtifactError(f"cannot persist a model of type {type(model).__module__}.{name}")


def save_model_files(directory: Path, name: str, model: Any) -> tuple[str, list[Path]]:
    """Write one model's files under ``directory/name``; returns (kind, files)."""
    kind = _model_kind(model)
    if kind == "average":  # its members are saved as models of their own (named in the manifest)
        return kind, []
    sub = Path(directory) / name
    sub.mkdir(parents=True, exist_ok=True)
    if kind in ("svm", "hgb"):
        path = sub / SKOPS_NAME
        sio.dump(model, path)
        return kind, [path]
    return kind, [Path(p) for p in model.save(sub)]


@dataclass(frozen=True)
class TrainingProvenance:
    """What the models of a folder were trained on, as the manifest records it.

    Attributes
    ----------
    classes : class ids (labels of the models), physical order. class_names : their names.
    channels : raw-window channel names. window_spec : WindowSpec used to cut them.
    robot : RobotSpec the data came from. training_fingerprint : sha256 of the training windows.
    preset : estimation preset used to build the data.
    sensors : sensor groups the models need (``wheels``, ``currents``, ``imu``, ``cam``); the
        predictor checks health only on those (None: all the robot has).
    feature_family : ``canonical`` or ``side_channel`` (design §8), or None.
    """

    classes: Sequence[int]
    class_names: Sequence[str]
    channels: Sequence[str]
    window_spec: WindowSpec
    robot: RobotSpec
    training_fingerprint: str
    preset: str = "robust"
    sensors: Sequence[str] | None = None
    feature_family: str | None = None


def save_artifact(directory: str | Path, models: dict[str, Any], provenance: TrainingProvenance, *,
                  default_model: str | None = None, metrics_summary: dict | None = None,
                  attachments: Mapping[str, str] | None = None, extra: dict | None = None,
                  calibration: Mapping[str, dict] | None = None,
                  novelty: tuple[str, NoveltyScorer, dict] | None = None) -> dict:
    """Write models and attachments, then the manifest over all files.

    Parameters
    ----------
    directory : output folder (created).
    models : {name: fitted model} (``SVMClassifier``, ``CNNClassifier``, ``BoostedTrees`` or a
        ``ProbabilityAverage`` whose members are also in ``models`` under the names of its
        ``A+B`` name), e.g. {"svm": m, "hgb": t, "svm+hgb": avg}.
    provenance : :class:`TrainingProvenance`, the classes, channels, window spec, robot, data
        fingerprint, preset, sensor groups and feature family of the training.
    default_model : model served by default (first of ``models`` when None).
    metrics_summary : {model: {metric: {mean, std}}}, stored as is.
    attachments : {file name: text} written into ``directory`` and listed in the manifest under
        ``attachments`` (e.g. ``{"desired_slip_table.json": table.to_json()}``); verified on load
        like every file, read by whoever knows their format (:attr:`Artifact.attachments`).
    extra : more JSON-able fields stored under ``extra``.
    calibration : {model name: :meth:`~terrainml.models.calibration.Temperature.to_dict`}, stored
        in that model's entry; :func:`load_artifact` then serves the model's probabilities
        through it (:class:`~terrainml.models.calibration.CalibratedModel`).
    novelty : (model name, fitted :class:`~terrainml.models.novelty.NoveltyScorer`, info) or
        None: the novelty score of that model's windows, written to ``novelty/novelty.safetensors``
        and described in the manifest's ``novelty`` entry (settings, threshold, info, file).

    Other files already in ``directory`` (reports) are hashed into the manifest too; call
    :func:`write_manifest` again after adding files.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    entries = {name: _model_entry(directory, name, model, models, calibration)
               for name, model in models.items()}
    for fname, text in (attachments or {}).items():
        if Path(fname).name != fname or fname == MANIFEST_NAME:
            raise ArtifactError(f"{directory / fname}: an attachment is a plain file name, not {MANIFEST_NAME}")
        write_text(directory / fname, text)
    nov_entry = None if novelty is None else _novelty_entry(directory, novelty, models)
    doc = {
        "schema": SCHEMA, "schema_version": SCHEMA_VERSION, "terrainml_version": __version__,
        "created_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        **_provenance_fields(provenance),
        "models": entries, "default_model": default_model or next(iter(models)),
        "attachments": sorted(attachments or {}),
        "metrics_summary": metrics_summary or {}, "extra": extra or {},
    }
    if nov_entry is not None:  # absent (not null) without a scorer: older folders read the same
        doc["novelty"] = nov_entry
    return write_manifest(directory, doc)


def _provenance_fields(p: TrainingProvenance) -> dict:
    """The manifest's fields of the training's provenance."""
    return {"classes": [int(c) for c in p.classes], "class_names": [str(c) for c in p.class_names],
            "channels": [str(c) for c in p.channels], "window_spec": p.window_spec.to_dict(),
            "robot": {"name": p.robot.name, "sha256": p.robot.sha256(), "spec": p.robot.to_dict()},
            "training_fingerprint": str(p.training_fingerprint), "preset": str(p.preset),
            "sensors": None if p.sensors is None else [str(g) for g in p.sensors],
            "feature_family": p.feature_family}


def _model_entry(directory: Path, name: str, model: Any, models: dict[str, Any],
                 calibration: Mapping[str, dict] | None) -> dict:
    """Save one model's files; its manifest entry (kind, files, features, members, calibration)."""
    kind, files = save_model_files(directory, name, model)
    entry = {"kind": kind, "files": [p.relative_to(directory).as_posix() for p in files]}
    if kind == "svm":
        entry["feature_names"] = model.feature_names_
        entry["feature_subset"] = getattr(model.features_, "subset", None)
        entry["best_params"] = model.best_params_
    if kind == "average":
        members = name.split("+")
        if len(members) < 2 or any(m not in models or models[m] is not mm
                                   for m, mm in zip(members, model.members_)):
            raise ArtifactError(f"{directory}: average {name!r} must be named A+B after its members, "
                                "each saved in the same folder")
        entry["members"] = members
    if calibration and name in calibration:
        entry["calibration"] = Temperature.from_dict(dict(calibration[name])).to_dict()
    return entry


def _novelty_entry(directory: Path, novelty: tuple[str, NoveltyScorer, dict], models: dict[str, Any]) -> dict:
    """Save the novelty scorer; its manifest entry (settings, threshold, info, model, file)."""
    nov_name, scorer, info = novelty
    if nov_name not in models:
        raise ArtifactError(f"{directory}: novelty scorer of {nov_name!r}, which is not among the models")
    path = scorer.save(directory / "novelty")
    return {**scorer.config(), **dict(info), "model": nov_name, "file": path.relative_to(directory).as_posix()}


# ---------------------------------------------------------------------------- loading
# ---------------------------------------------------------------------------- sensor members
#: sub-folder of a model folder that holds its sensor members, one model folder each
MEMBERS_DIR = "members"


def attach_members(directory: str | Path, names: Sequence[str]) -> dict:
    """List the sensor members ``directory/members/NAME`` in the folder's manifest; rewrite it.

    A sensor member (design §9) is a complete model folder of its own (written by
    the same training as the folder's model, on a subset of its sensor groups) inside
    ``members/``. The manifest's ``sensor_members`` gets one entry per member, in the order
    given: ``name``, ``path``, ``sensors``, ``window_spec``, ``channels``, ``feature_family``,
    ``default_model``, its CV ``balanced_accuracy`` and its manifest's ``manifest_sha256``; its
    files are hashed into this manifest like every other file, so one signature covers all.

    Raises ArtifactError (naming the member's manifest) when a member does not verify, or has
    other classes or another robot than the folder's model.
    """
    directory = Path(directory)
    doc = read_manifest(directory)
    entries = []
    for name in names:
        rel = f"{MEMBERS_DIR}/{name}"
        mdoc = verify_artifact(directory / rel)
        where = directory / rel / MANIFEST_NAME
        for key in ("classes", "class_names"):
            if mdoc.get(key) != doc.get(key):
                raise ArtifactError(f"{where}: member {key} {mdoc.get(key)} differ from the model's {doc.get(key)}")
        if mdoc["robot"].get("sha256") != doc["robot"].get("sha256"):
            raise ArtifactError(f"{where}: member trained for another robot spec than the model's")
        default = mdoc["default_model"]
        bacc = (mdoc.get("metrics_summary", {}).get(default, {}).get("balanced_accuracy") or {}).get("mean")
        entries.append({"name": str(name), "path": rel, "sensors": mdoc.get("sensors"),
                        "window_spec": mdoc["window_spec"], "channels": mdoc.get("channels"),
                        "feature_family": mdoc.get("feature_family"), "default_model": default,
                        "balanced_accuracy": bacc, "manifest_sha256": mdoc["manifest_sha256"]})
    doc["sensor_members"] = entries
    return write_manifest(directory, doc)


def load_members(directory: str | Path, doc: dict) -> list["Artifact"]:
    """The sensor members listed in a verified manifest ``doc``, each verified and loaded.

    Their files were checked against ``doc`` already (:func:`verify_artifact`); a member's own
    manifest must also be the one ``doc`` lists (``manifest_sha256``), else ArtifactError.
    """
    directory = Path(directory)
    out = []
    for entry in doc.get("sensor_members") or []:
        sub = directory / str(entry.get("path", ""))
        if Path(str(entry.get("path", ""))).parts[:1] != (MEMBERS_DIR,) or ".." in Path(str(entry["path"])).parts:
            raise ArtifactError(f"{directory / MANIFEST_NAME}: member path {entry.get('path')!r} is not under "
                                f"{MEMBERS_DIR}/")
        art = load_artifact(sub)
        if art.manifest.get("manifest_sha256") != entry.get("manifest_sha256"):
            raise ArtifactError(f"{sub / MANIFEST_NAME}: not the member manifest the model folder lists")
        out.append(art)
    return out


def _load_skops(path: Path) -> Any:
    try:
        untrusted = sio.get_untrusted_types(file=path)
    except Exception as exc:  # noqa: BLE001 - skops raises many types on corrupt files
        raise ArtifactError(f"{path}: not a readable skops file ({type(exc).__name__}: {exc})") from None
    unknown = sorted(set(untrusted) - ALLOWED_SKOPS_TYPES)
    if unknown:
        raise ArtifactError(f"{path}: refuses to load types outside the allow-list: {unknown}")
    try:
        return sio.load(path, trusted=list(untrusted))
    except Exception as exc:  # noqa: BLE001
        raise ArtifactError(f"{path}: skops could not load the model ({type(exc).__name__}: {exc})") from None


@dataclass
class Artifact:
    """A verified model folder.

    Attributes
    ----------
    path : Path. manifest : dict. model_name, kind : served model and its kind.
    model : fitted classifier on raw windows (``predict_proba(Windows)``).
    robot : RobotSpec. window_spec : WindowSpec.
    attachments : {file name: Path} of the verified attachments (e.g. the desired-slip table).
    class_ids : list of int. class_names : list of str. channels : list of str.
    preset : estimation preset. features : None (the models compute their own features).
    sensors : sensor groups the model needs (None: a folder written before they were recorded;
        the robot's groups then apply). feature_family : ``canonical``, ``side_channel`` or None.
    novelty : :class:`~terrainml.models.novelty.NoveltyScorer` of the loaded model's windows, or
        None (no scorer in the folder, or one fitted for another of its models).
    """

    path: Path
    manifest: dict
    model_name: str
    kind: str
    model: Any
    robot: RobotSpec
    window_spec: WindowSpec
    attachments: dict = field(default_factory=dict)
    class_ids: list = field(default_factory=list)
    class_names: list = field(default_factory=list)
    channels: list = field(default_factory=list)
    preset: str = "robust"
    features: Any = None
    sensors: list | None = None
    feature_family: str | None = None
    novelty: NoveltyScorer | None = None
    #: sensor members (:func:`load_members`), loaded by ``load_artifact(..., members=True)``
    members: list = field(default_factory=list)


def _load_novelty(directory: Path, doc: dict, name: str, model: Any) -> NoveltyScorer | None:
    """The novelty scorer of model ``name`` (files verified), checked against the model's features."""
    entry = doc.get("novelty")
    if entry is None or entry.get("model") != name:
        return None
    path = directory / entry["file"]
    try:
        scorer = NoveltyScorer.load(path, entry)
        n_model = len(model_feature_names(model))
    except NoveltyError as exc:
        raise ArtifactError(str(exc) if str(path) in str(exc) else f"{path}: {exc}") from None
    if n_model != int(entry.get("n_features", -1)):
        raise ArtifactError(f"{path}: novelty scorer has {entry.get('n_features')} features, the model "
                            f"{name!r} computes {n_model}")
    if sorted(scorer.classes_.tolist()) != sorted(np.asarray(model.classes_).astype(int).tolist()):
        raise ArtifactError(f"{path}: novelty classes {scorer.classes_.tolist()} differ from the model's")
    return scorer


def _load_model(directory: Path, doc: dict, name: str, depth: int = 0) -> tuple[str, Any]:
    """(kind, fitted model) of the manifest's model ``name`` (files already verified)."""
    mpath = directory / MANIFEST_NAME
    try:
        entry = doc["models"][name]
    except KeyError:
        raise ArtifactError(f"{mpath}: no model {name!r} (models: {list(doc.get('models', {}))})") from None
    kind = entry.get("kind")
    if kind in ("svm", "hgb"):
        path = directory / next(f for f in entry["files"] if f.endswith(".skops"))
        return kind, _calibrated(mpath, name, entry, _load_skops(path))
    if kind == "cnn":
        try:
            from terrainml.models.cnn import CNNClassifier  # noqa: PLC0415 - torch, optional
        except ImportError as exc:
            raise ArtifactError(f"{mpath}: model {name!r} needs the CNN ({exc})") from None
        sub = directory / Path(entry["files"][0]).parent
        try:
            return kind, _calibrated(mpath, name, entry, CNNClassifier.load(sub))
        except ValueError as exc:
            raise ArtifactError(str(exc)) from None
    if kind == "average" and depth == 0:
        members = [_load_model(directory, doc, m, depth + 1)[1] for m in entry.get("members", [])]
        try:
            return kind, _calibrated(mpath, name, entry, ProbabilityAverage.from_fitted(members))
        except ValueError as exc:
            raise ArtifactError(f"{mpath}: average {name!r}: {exc}") from None
    raise ArtifactError(f"{mpath}: unknown model kind {kind!r} for {name!r}")


def _calibrated(mpath: Path, name: str, entry: dict, model: Any) -> Any:
    """The model served through its manifest calibration, if the entry has one."""
    if "calibration" not in entry:
        return model
    try:
        return CalibratedModel(model, Temperature.from_dict(entry["calibration"]))
    except ValueError as exc:
        raise ArtifactError(f"{mpath}: model {name!r}: calibration: {exc}") from None


def load_artifact(directory: str | Path, model: str | None = None, *,
                  trusted_keys: Sequence[PublicKeyLike] | None = None, members: bool = False) -> Artifact:
    """Verify a model folder and load one model (default: the manifest's ``default_model``).

    ``members``: also load its sensor members (:func:`load_members`, each its own default model)
    into :attr:`Artifact.members`.

    ``trusted_keys`` (public keys: ``KEY.pub`` paths or loaded keys): the manifest must also be
    signed by one of them (:mod:`terrainml.models.signing`), checked first. None: not checked.

    Raises
    ------
    ArtifactError
        Naming the file that is missing, modified, of an unknown schema or unsafe to load.
    SignatureError
        Naming the folder, with ``trusted_keys``: unsigned, signed by another key, or manifest
        changed after signing.
    """
    directory = Path(directory)
    if trusted_keys is not None:
        verify_artifact_signature(directory, trusted_keys)
    doc = verify_artifact(directory)
    mpath = directory / MANIFEST_NAME
    try:
        name = model or doc["default_model"]
        entry = doc["models"][name]
        robot = RobotSpec.from_dict(doc["robot"]["spec"], source=f"{mpath}:robot")
        spec = WindowSpec.from_dict(doc["window_spec"])
    except KeyError as exc:
        raise ArtifactError(f"{mpath}: no entry {exc} (models: {list(doc.get('models', {}))})") from None
    except ValueError as exc:
        raise ArtifactError(f"{mpath}: {exc}") from None
    if robot.sha256() != doc["robot"].get("sha256"):
        raise ArtifactError(f"{mpath}: robot spec sha256 mismatch")
    del entry  # the model's entry is read by _load_model
    kind, clf = _load_model(directory, doc, name)
    # folders written before attachments existed name the desired-slip table on its own
    names = doc.get("attachments") or ([doc["desired_slip_table"]] if doc.get("desired_slip_table") else [])
    attachments = {str(n): directory / str(n) for n in names}
    classes = [int(c) for c in doc["classes"]]
    if sorted(np.asarray(clf.classes_).astype(int).tolist()) != sorted(classes):
        raise ArtifactError(f"{mpath}: model classes {list(clf.classes_)} differ from the manifest's {classes}")
    return Artifact(directory, doc, name, kind, clf, robot, spec, attachments, classes,
                    list(doc.get("class_names", [])), list(doc.get("channels", [])),
                    doc.get("preset", "robust"), sensors=doc.get("sensors"),
                    feature_family=doc.get("feature_family"),
                    novelty=_load_novelty(directory, doc, name, clf),
                    members=load_members(directory, doc) if members else [])
