"""Persistence of the CNN terrain classifier (:class:`~terrainml.models.cnn.CNNClassifier`): two
files in the model's folder of a model folder (:mod:`terrainml.models.artifacts`).

``cnn_weights.safetensors`` holds the network's weights (safetensors: no pickle),
``cnn_config.json`` the architecture, the normalisation statistics, the classes, the channel
names, the flat hyper-parameters and the training record. :func:`load_cnn` rebuilds the network
from the JSON and loads the weights into it; ``torch.load`` is never used.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file, save_file
from sklearn.utils.validation import check_is_fitted

from terrainml.atomic import write_text
from terrainml.models.cnn import CNNClassifier, _as_int_tuple
from terrainml.models.cnn_net import ConvNet1d, InferenceNet, Standardize

__all__ = ["save_cnn", "load_cnn", "cnn_config", "WEIGHTS_NAME", "CONFIG_NAME", "CONFIG_FORMAT", "CONFIG_VERSION"]

WEIGHTS_NAME = "cnn_weights.safetensors"
CONFIG_NAME = "cnn_config.json"
CONFIG_FORMAT = "terrainml.cnn"
CONFIG_VERSION = 1


def cnn_config(clf: CNNClassifier) -> dict:
    """The ``cnn_config.json`` document of a fitted classifier: architecture, normalisation
    statistics, classes, channel names, flat hyper-parameters, training record."""
    classes = clf.classes_
    if np.issubdtype(classes.dtype, np.integer):
        cls_list, cls_kind = [int(c) for c in classes], "int"
    elif np.issubdtype(classes.dtype, np.bool_):
        cls_list, cls_kind = [bool(c) for c in classes], "bool"
    elif np.issubdtype(classes.dtype, np.floating):
        cls_list, cls_kind = [float(c) for c in classes], "float"
    else:
        cls_list, cls_kind = [str(c) for c in classes], "str"
    cfg = clf.config_
    params = {**asdict(cfg), "channel_names": clf.channel_names, "random_state": clf.random_state,
              "n_threads": clf.n_threads, "verbose": clf.verbose}
    params["conv_channels"] = list(_as_int_tuple(cfg.conv_channels, "conv_channels"))
    params["kernel_sizes"] = list(_as_int_tuple(cfg.kernel_sizes, "kernel_sizes"))
    params["channel_names"] = None if clf.channel_names is None else [str(c) for c in clf.channel_names]
    if not isinstance(params["random_state"], (int, type(None))):
        params["random_state"] = None  # a Generator is not JSON; the weights are what count
    return {
        "format": CONFIG_FORMAT,
        "version": CONFIG_VERSION,
        "architecture": {
            "n_channels": int(clf.n_channels_in_),
            "n_net_channels": int(clf.n_net_channels_),
            "n_timesteps": int(clf.n_timesteps_in_),
            "n_classes": len(classes),
            "conv_channels": params["conv_channels"],
            "kernel_sizes": params["kernel_sizes"],
            "dropout": float(cfg.dropout),
            "window_stats": bool(cfg.window_stats),
        },
        "classes": cls_list,
        "classes_kind": cls_kind,
        "channel_names": list(clf.channel_names_),
        "normalisation": {"mean": [float(v) for v in clf.mean_],
                          "scale": [float(v) for v in clf.scale_]},
        "params": params,
        "training": {"n_epochs": int(clf.n_epochs_), "best_epoch": int(clf.best_epoch_),
                     "fit_time_s": float(clf.fit_time_s_),
                     "history": [{k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                                  for k, v in rec.items()} for rec in clf.history_]},
        "torch_version": torch.__version__,
    }


def save_cnn(clf: CNNClassifier, directory) -> list[Path]:
    """Write ``cnn_weights.safetensors`` and ``cnn_config.json`` into ``directory``.

    Returns
    -------
    list of Path
        The two files written (for the artifact manifest).
    """
    check_is_fitted(clf, "model_")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    weights = directory / WEIGHTS_NAME
    config = directory / CONFIG_NAME
    state = {k: v.detach().cpu().contiguous() for k, v in clf.model_.net.state_dict().items()}
    save_file(state, str(weights), metadata={"format": CONFIG_FORMAT, "version": str(CONFIG_VERSION)})
    write_text(config, json.dumps(cnn_config(clf), indent=2, allow_nan=False) + "\n")
    return [weights, config]


def load_cnn(directory) -> CNNClassifier:
    """Rebuild a fitted classifier from :meth:`save` output (no pickle, no ``torch.load``).

    Raises
    ------
    ValueError
        When a file is missing, the config is not a terrainml CNN config of a known version,
        or the weights do not match the architecture (the message names the file).
    """
    directory = Path(directory)
    config_path, weights_path = directory / CONFIG_NAME, directory / WEIGHTS_NAME
    for p in (config_path, weights_path):
        if not p.is_file():
            raise ValueError(f"CNN model file missing: {p}")
    try:
        cfg = json.loads(config_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{config_path}: not valid JSON ({exc})") from None
    if not isinstance(cfg, dict) or cfg.get("format") != CONFIG_FORMAT:
        raise ValueError(f"{config_path}: not a terrainml CNN config (format {CONFIG_FORMAT!r})")
    if cfg.get("version") != CONFIG_VERSION:
        raise ValueError(f"{config_path}: unsupported CNN config version {cfg.get('version')!r}")
    try:
        arch = cfg["architecture"]
        params = dict(cfg["params"])
        params["conv_channels"] = tuple(params["conv_channels"])
        params["kernel_sizes"] = tuple(params["kernel_sizes"])
        if params.get("channel_names") is not None:
            params["channel_names"] = tuple(params["channel_names"])
        clf = CNNClassifier.from_params(**params)
        kind = {"int": np.int64, "bool": np.bool_, "float": np.float64, "str": np.str_}[cfg["classes_kind"]]
        clf.classes_ = np.asarray(cfg["classes"], dtype=kind)
        clf.n_channels_in_ = int(arch["n_channels"])
        clf.n_timesteps_in_ = int(arch["n_timesteps"])
        clf.channel_names_ = [str(c) for c in cfg["channel_names"]]
        clf.mean_ = np.asarray(cfg["normalisation"]["mean"], dtype=np.float32)
        clf.scale_ = np.asarray(cfg["normalisation"]["scale"], dtype=np.float32)
        training = cfg.get("training", {})
        clf.n_epochs_ = int(training.get("n_epochs", 0))
        clf.best_epoch_ = int(training.get("best_epoch", 0))
        clf.fit_time_s_ = float(training.get("fit_time_s", float("nan")))
        clf.history_ = list(training.get("history", []))
        C, K = clf.n_channels_in_, len(clf.classes_)
        clf.n_net_channels_ = int(arch.get("n_net_channels", C))
        C_net = clf.n_net_channels_
        if len(clf.channel_names_) != C:
            raise ValueError("channel_names length differs from n_channels")
        if len(clf.mean_) != C_net or len(clf.scale_) != C_net:
            raise ValueError("normalisation length differs from n_net_channels")
        if clf._preprocess_module()(torch.zeros(1, C, 8)).shape[1] != C_net:
            raise ValueError("n_net_channels does not match the preprocessing of these channels")
        if K != int(arch["n_classes"]):
            raise ValueError("classes length differs from n_classes")
        net = ConvNet1d(C_net, K, tuple(arch["conv_channels"]), tuple(arch["kernel_sizes"]),
                        float(arch["dropout"]), bool(arch.get("window_stats", False)))
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{config_path}: invalid CNN config ({exc})") from None
    try:
        state = load_file(str(weights_path))
        net.load_state_dict(state, strict=True)
    except Exception as exc:  # safetensors raises its own error types
        raise ValueError(f"{weights_path}: weights do not load into the configured "
                         f"network ({type(exc).__name__}: {exc})") from None
    net.eval()
    clf.model_ = InferenceNet(Standardize(clf.mean_, clf.scale_), net, clf._preprocess_module()).eval()
    for p in clf.model_.parameters():
        p.requires_grad_(False)
    return clf
