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

import errno
import hashlib
import json
import math
import os
import stat
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import skops.io as sio

from terrainml import __version__
from terrainml.atomic import write_text
from terrainml.features.windows import WindowSpec
from terrainml.hashing import sha256_file
from terrainml.models.calibration import CalibratedModel, Temperature
from terrainml.models.ensemble import ProbabilityAverage
from terrainml.models.novelty import NoveltyError, NoveltyScorer, model_feature_names
from terrainml.models.signing import (MANIFEST_NAME, SIGNATURE_NAME, PublicKeyLike, SignatureError,
                                      verify_artifact_signature)
from terrainml.robot import RobotSpec

__all__ = ["ArtifactError", "Artifact", "save_artifact", "load_artifact", "verify_artifact",
           "attach_members", "load_members", "MEMBERS_DIR",
           "read_manifest", "write_manifest", "ALLOWED_SKOPS_TYPES", "MANIFEST_NAME", "SCHEMA",
           "SCHEMA_VERSION", "SIGNATURE_NAME", "SignatureError", "json_safe"]

SCHEMA = "terrainml.model"
SCHEMA_VERSION = 1
SKOPS_NAME = "model.skops"

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


class ArtifactError(ValueError):
    """A model folder cannot be trusted or used (the message names the file)."""


def json_safe(obj: Any) -> Any:
    """Recursively convert numpy scalars/arrays to Python and non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _canonical(doc: dict) -> str:
    return json.dumps(doc, indent=2, sort_keys=True, allow_nan=False, ensure_ascii=True) + "\n"


def _self_hash(doc: dict) -> str:
    body = {k: v for k, v in doc.items() if k != "manifest_sha256"}
    return hashlib.sha256(_canonical(body).encode()).hexdigest()


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


def save_artifact(directory: str | Path, models: dict[str, Any], *, classes: Sequence[int],
                  class_names: Sequence[str], channels: Sequence[str], window_spec: WindowSpec,
                  robot: RobotSpec, training_fingerprint: str, metrics_summary: dict | None = None,
                  default_model: str | None = None, preset: str = "robust",
                  attachments: Mapping[str, str] | None = None, extra: dict | None = None,
                  sensors: Sequence[str] | None = None, feature_family: str | None = None,
                  calibration: Mapping[str, dict] | None = None,
                  novelty: tuple[str, NoveltyScorer, dict] | None = None) -> dict:
    """Write models and attachments, then the manifest over all files.

    Parameters
    ----------
    directory : output folder (created).
    models : {name: fitted model} (``SVMClassifier``, ``CNNClassifier``, ``BoostedTrees`` or a
        ``ProbabilityAverage`` whose members are also in ``models`` under the names of its
        ``A+B`` name), e.g. {"svm": m, "hgb": t, "svm+hgb": avg}.
    classes : class ids (labels of the models), physical order.
    class_names : names of the classes.
    channels : raw-window channel names. window_spec : WindowSpec used to cut them.
    robot : RobotSpec the data came from. training_fingerprint : sha256 of the training windows.
    metrics_summary : {model: {metric: {mean, std}}}, stored as is.
    default_model : model served by default (first of ``models`` when None).
    preset : estimation preset used to build the data.
    attachments : {file name: text} written into ``directory`` and listed in the manifest under
        ``attachments`` (e.g. ``{"desired_slip_table.json": table.to_json()}``); verified on load
        like every file, read by whoever knows their format (:attr:`Artifact.attachments`).
    extra : more JSON-able fields stored under ``extra``.
    sensors : sensor groups the models need (``wheels``, ``currents``, ``imu``, ``cam``); the
        predictor checks health only on those (None: all the robot has).
    feature_family : ``canonical`` or ``side_channel`` (design §8).
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
        "classes": [int(c) for c in classes], "class_names": [str(c) for c in class_names],
        "channels": [str(c) for c in channels], "window_spec": window_spec.to_dict(),
        "robot": {"name": robot.name, "sha256": robot.sha256(), "spec": robot.to_dict()},
        "training_fingerprint": str(training_fingerprint), "preset": str(preset),
        "models": entries, "default_model": default_model or next(iter(models)),
        "attachments": sorted(attachments or {}),
        "metrics_summary": metrics_summary or {}, "extra": extra or {},
        "sensors": None if sensors is None else [str(g) for g in sensors],
        "feature_family": feature_family,
    }
    if nov_entry is not None:  # absent (not null) without a scorer: older folders read the same
        doc["novelty"] = nov_entry
    return write_manifest(directory, doc)


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


def write_manifest(directory: str | Path, doc: dict | None = None) -> dict:
    """(Re)write ``manifest.json`` hashing every file in ``directory`` (recursively).

    ``doc`` None re-reads the existing manifest (without verifying files) and refreshes the
    file list, e.g. after reports were added. The signature (``manifest.sig``, if any) is not
    hashed: it signs the manifest, and a rewritten manifest no longer matches it (sign again).
    """
    directory = Path(directory)
    if doc is None:
        doc = json.loads((directory / MANIFEST_NAME).read_text())
    doc = {k: v for k, v in doc.items() if k not in ("files", "manifest_sha256")}
    files = {}
    for p in sorted(directory.rglob("*")):
        rel = p.relative_to(directory).as_posix()
        # the folder's own manifest and signature only: a sensor member's manifest is a file
        # of this folder like any other (hashed, so signing this manifest covers the members)
        if p.is_file() and rel not in (MANIFEST_NAME, SIGNATURE_NAME):
            files[rel] = {"sha256": sha256_file(p), "bytes": p.stat().st_size}
    doc["files"] = files
    doc = json_safe(doc)
    doc["manifest_sha256"] = _self_hash(doc)
    write_text(directory / MANIFEST_NAME, _canonical(doc))   # last, whole or not at all
    return doc


# ---------------------------------------------------------------------------- loading
_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"),
          (stat.S_ISDIR, "a folder"))


def file_problem(path: Path) -> str | None:
    """Why ``path`` is not a readable regular file (None when it is), its real cause.

    "missing" only when nothing is there (a dangling symlink says where it points); a symlink
    loop, a device (``/dev/zero``), a FIFO, a socket or a folder are named as such, so a model
    file replaced by one is refused before it is opened (reading a FIFO blocks, a device never
    ends). A symlink to a regular file is followed.
    """
    try:
        st = path.stat()
    except FileNotFoundError:
        if path.is_symlink():
            return f"a symlink to {os.readlink(path)!r}, which does not exist"
        return "missing"
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a symlink loop"
        return f"cannot be read ({exc.strerror or exc})"
    if stat.S_ISREG(st.st_mode):
        return None
    what = next((name for test, name in _KINDS if test(st.st_mode)), "not a regular file")
    via = f" (a symlink to {os.readlink(path)!r})" if path.is_symlink() else ""
    return f"{what}{via}, not a regular file"


def read_manifest(directory: str | Path) -> dict:
    """Read and verify ``manifest.json`` itself (canonical form, self-hash, schema)."""
    directory = Path(directory)
    path = directory / MANIFEST_NAME
    if not directory.is_dir():
        raise ArtifactError(f"{directory}: no such model folder (train one with `terrainml train`)")
    problem = file_problem(path)
    if problem == "missing":
        raise ArtifactError(f"{path}: manifest missing; not a terrainml model folder")
    if problem is not None:
        raise ArtifactError(f"{path}: manifest is {problem}")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
        doc = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ArtifactError(f"{path}: corrupt manifest (not valid JSON: {exc})") from None
    if not isinstance(doc, dict):
        raise ArtifactError(f"{path}: corrupt manifest (not a JSON object)")
    if doc.get("schema") != SCHEMA:
        raise ArtifactError(f"{path}: not a terrainml model manifest (schema {doc.get('schema')!r})")
    if doc.get("schema_version") != SCHEMA_VERSION:
        raise ArtifactError(f"{path}: manifest schema version {doc.get('schema_version')!r}; this "
                            f"terrainml reads version {SCHEMA_VERSION}")
    if doc.get("manifest_sha256") != _self_hash(doc):
        raise ArtifactError(f"{path}: manifest sha256 mismatch: the manifest was modified after "
                            "it was written")
    if text != _canonical(doc):
        raise ArtifactError(f"{path}: manifest is not in its canonical form: it was modified "
                            "after it was written")
    return doc


def verify_artifact(directory: str | Path) -> dict:
    """Verify the manifest and the sha256 of every file it lists; return the manifest."""
    directory = Path(directory)
    doc = read_manifest(directory)
    files = doc.get("files")
    if not isinstance(files, dict) or not files:
        raise ArtifactError(f"{directory / MANIFEST_NAME}: manifest lists no files")
    for rel, info in files.items():
        p = directory / rel
        problem = file_problem(p)
        if problem is not None:
            raise ArtifactError(f"{p}: file listed in the manifest is {problem}")
        if p.stat().st_size != info.get("bytes"):
            raise ArtifactError(f"{p}: size {p.stat().st_size} B differs from the manifest's "
                                f"{info.get('bytes')} B: the file was modified")
        if sha256_file(p) != info.get("sha256"):
            raise ArtifactError(f"{p}: sha256 mismatch: the file was modified after training")
    for name, entry in doc.get("models", {}).items():
        for rel in entry.get("files", []):
            if rel not in files:
                raise ArtifactError(f"{directory / rel}: model file of {name!r} not hashed in the manifest")
    for rel in doc.get("attachments") or []:
        if rel not in files:
            raise ArtifactError(f"{directory / rel}: attachment not hashed in the manifest")
    nov = doc.get("novelty")
    if nov is not None and (not isinstance(nov, dict) or nov.get("file") not in files):
        raise ArtifactError(f"{directory / MANIFEST_NAME}: novelty entry names no file hashed in the manifest")
    return doc


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
