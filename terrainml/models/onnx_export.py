"""ONNX export of a fitted :class:`~terrainml.models.cnn.CNNClassifier`, and inference without torch.

The exported graph is the whole inference path of ``CNNClassifier.predict_proba``: raw windows
``windows`` of shape ``(n, C, T)`` float32 (physical units, NaN allowed) -> per-channel
standardisation -> network -> softmax -> ``probabilities`` ``(n, K)``. The batch axis is
dynamic; ``T`` is fixed to the training window length. Classes, channel names and the
standardisation statistics are stored in the model's ``metadata_props`` (JSON strings), so the
``.onnx`` file alone is enough to deploy (onnxruntime, C++/C#/Java/JS runtimes...).

Example
-------
>>> path = export_onnx(clf, "runs/cnn/cnn.onnx")          # doctest: +SKIP
>>> OnnxCNN(path).predict_proba(windows)                   # doctest: +SKIP
"""

from __future__ import annotations

import io
import json
import warnings
from pathlib import Path

import numpy as np
from sklearn.utils.validation import check_is_fitted

__all__ = ["export_onnx", "OnnxCNN", "ONNX_NAME", "INPUT_NAME", "OUTPUT_NAME"]

ONNX_NAME = "cnn.onnx"
INPUT_NAME = "windows"
OUTPUT_NAME = "probabilities"
DEFAULT_OPSET = 17


def export_onnx(clf, path, opset: int = DEFAULT_OPSET) -> Path:
    """Export a fitted CNN (standardisation + network + softmax) to an ONNX file.

    Parameters
    ----------
    clf : CNNClassifier
        Fitted classifier.
    path : str or Path
        Output ``.onnx`` file (a directory gets ``cnn.onnx`` inside it).
    opset : int, default 17
        ONNX opset.

    Returns
    -------
    Path
        The file written.

    Notes
    -----
    Uses torch's TorchScript-based exporter (``dynamo=False``: the dynamo exporter needs the
    ``onnxscript`` package, which terrainml does not depend on); the deprecation warning it
    emits is silenced here. The graph is checked with ``onnx.checker`` after export.
    """
    import onnx  # noqa: PLC0415 - optional (cnn extra)
    import torch  # noqa: PLC0415 - optional (cnn extra)

    from terrainml.models.cnn_files import cnn_config  # noqa: PLC0415 - torch, optional (cnn extra)

    check_is_fitted(clf, "model_")
    path = Path(path)
    if path.is_dir() or path.suffix == "":
        path = path / ONNX_NAME
    path.parent.mkdir(parents=True, exist_ok=True)
    model = clf.model_.eval()
    example = torch.zeros(2, clf.n_channels_in_, clf.n_timesteps_in_, dtype=torch.float32)
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(model, (example,), buf, dynamo=False, opset_version=int(opset),
                          input_names=[INPUT_NAME], output_names=[OUTPUT_NAME],
                          dynamic_axes={INPUT_NAME: {0: "n_windows"}, OUTPUT_NAME: {0: "n_windows"}},
                          do_constant_folding=True)
    proto = onnx.load_from_string(buf.getvalue())
    config = cnn_config(clf)
    meta = {
        "terrainml_format": "terrainml.cnn.onnx",
        "classes": json.dumps(config["classes"]),
        "classes_kind": config["classes_kind"],
        "channel_names": json.dumps(config["channel_names"]),
        "n_timesteps": str(int(clf.n_timesteps_in_)),
        "normalisation": json.dumps(config["normalisation"]),
    }
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    proto.producer_name = "terrainml"
    onnx.checker.check_model(proto)
    onnx.save(proto, str(path))
    return path


class OnnxCNN:
    """onnxruntime inference of an exported CNN: same API as ``CNNClassifier`` for prediction.

    Parameters
    ----------
    path : str or Path
        ``.onnx`` file written by :func:`export_onnx`.
    n_threads : int or None, default None
        onnxruntime intra-op threads (None: onnxruntime's default).

    Attributes
    ----------
    classes_ : ndarray of shape (K,)
    channel_names_ : list of str
    n_channels_in_, n_timesteps_in_ : int
    """

    def __init__(self, path, n_threads: int | None = None):
        import onnxruntime as ort  # noqa: PLC0415 - optional (cnn extra)

        self.path = Path(path)
        if not self.path.is_file():
            raise ValueError(f"ONNX model file missing: {self.path}")
        opts = ort.SessionOptions()
        if n_threads is not None:
            opts.intra_op_num_threads = int(n_threads)
            opts.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(str(self.path), sess_options=opts,
                                                providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own error types
            raise ValueError(f"{self.path}: not a loadable ONNX model ({exc})") from None
        meta = self.session.get_modelmeta().custom_metadata_map
        if meta.get("terrainml_format") != "terrainml.cnn.onnx":
            raise ValueError(f"{self.path}: not a terrainml CNN ONNX model")
        kind = {"int": np.int64, "bool": np.bool_, "float": np.float64, "str": np.str_}[meta["classes_kind"]]
        self.classes_ = np.asarray(json.loads(meta["classes"]), dtype=kind)
        self.channel_names_ = list(json.loads(meta["channel_names"]))
        self.n_channels_in_ = len(self.channel_names_)
        self.n_timesteps_in_ = int(meta["n_timesteps"])

    def predict_proba(self, X) -> np.ndarray:
        """Class probabilities, shape (n_windows, n_classes), float64, columns as ``classes_``.

        Parameters
        ----------
        X : array-like of shape (n_windows, n_channels, n_timesteps)
            Raw windows; ``n_timesteps`` must equal the training window length.
        """
        X = np.ascontiguousarray(X, dtype=np.float32)
        if X.ndim != 3 or X.shape[1:] != (self.n_channels_in_, self.n_timesteps_in_):
            raise ValueError(f"{self.path.name}: windows must have shape (n, {self.n_channels_in_}, "
                             f"{self.n_timesteps_in_}), got {X.shape}")
        (proba,) = self.session.run([OUTPUT_NAME], {INPUT_NAME: X})
        return proba.astype(np.float64)

    def predict(self, X) -> np.ndarray:
        """Most probable class per window, shape (n_windows,)."""
        return self.classes_[np.argmax(self.predict_proba(X), axis=1)]
