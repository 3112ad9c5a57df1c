"""Calibrated class probabilities: temperature scaling fitted on out-of-fold probabilities.

Under run-grouped cross-validation the probabilities of the window classifiers are
over-confident on a new run (expected calibration error 0.16-0.24 on real robots), and the
fusion and the fallback of the online predictor read them as they are. :class:`Temperature`
is one positive scalar T fitted by maximum likelihood on probabilities that the model gave to
windows it was *not* trained on (the out-of-fold predictions of grouped folds: never a test
run), and applied as

    p_cal = softmax(log(p) / T)

(Guo et al., *On Calibration of Modern Neural Networks*, ICML 2017). T > 1 softens
over-confident probabilities, T < 1 sharpens under-confident ones. The argmax is unchanged, so
the served class and every classification metric stay what they were; only the confidence the
fusion, the uncertain-class fallback and the safe-cap rule read changes.

:class:`CalibratedModel` wraps a fitted classifier (SVM, trees, their average, the CNN) with
its temperature; a model folder stores the temperature in the manifest entry of the model
(:mod:`terrainml.models.artifacts`), so no new file format is needed.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.special import log_softmax

__all__ = ["Temperature", "CalibratedModel", "LOG_T_BOUNDS", "METHOD"]

#: search interval of log(T): T in [0.5, 10]. Sharpening is bounded at 2x: on out-of-fold
#: windows that are all right the likelihood keeps rising as T -> 0, and a model that is
#: certain of everything would never fall back as uncertain online
LOG_T_BOUNDS = (float(np.log(0.5)), float(np.log(10.0)))
#: the method name stored in manifests
METHOD = "temperature"
_P_FLOOR = 1e-12


def _log_p(proba: np.ndarray) -> np.ndarray:
    return np.log(np.clip(np.asarray(proba, dtype=float), _P_FLOOR, 1.0))


class Temperature:
    """Temperature scaling of class probabilities.

    Parameters
    ----------
    temperature : float > 0, the fitted T (1.0: the identity).
    """

    def __init__(self, temperature: float = 1.0):
        t = float(temperature)
        if not np.isfinite(t) or t <= 0:
            raise ValueError(f"temperature must be a finite positive number, got {temperature!r}")
        self.temperature = t

    @classmethod
    def fit(cls, proba: np.ndarray, y: Sequence, classes: Sequence) -> "Temperature":
        """T minimising the mean negative log-likelihood of ``y`` under the scaled ``proba``.

        Parameters
        ----------
        proba : ndarray (n, K), out-of-fold probabilities, columns in ``classes`` order.
        y : array (n,), true labels (each one of ``classes``; others are ignored).
        classes : sequence (K,).

        Returns
        -------
        Temperature (T = 1 when there are no usable rows).
        """
        proba = np.asarray(proba, dtype=float)
        col = {c: k for k, c in enumerate(np.asarray(classes).tolist())}
        y = np.asarray(y).tolist()
        rows = np.array([i for i, v in enumerate(y) if v in col], dtype=np.int64)
        if len(rows) == 0 or proba.ndim != 2:
            return cls(1.0)
        target = np.array([col[y[i]] for i in rows], dtype=np.int64)
        logp = _log_p(proba[rows])

        def nll(log_t: float) -> float:
            z = log_softmax(logp / np.exp(log_t), axis=1)
            return float(-z[np.arange(len(rows)), target].mean())

        res = minimize_scalar(nll, bounds=LOG_T_BOUNDS, method="bounded", options={"xatol": 1e-4})
        return cls(float(np.exp(res.x)))

    def transform(self, proba: np.ndarray) -> np.ndarray:
        """Calibrated probabilities (n, K) (or (K,) for one row); rows sum to 1."""
        p = np.asarray(proba, dtype=float)
        if self.temperature == 1.0:
            return p
        return np.exp(log_softmax(_log_p(p) / self.temperature, axis=-1))

    def to_dict(self) -> dict[str, Any]:
        """The manifest entry: ``{"method": "temperature", "temperature": T}``."""
        return {"method": METHOD, "temperature": float(self.temperature)}

    @classmethod
    def from_dict(cls, d: dict) -> "Temperature":
        """Inverse of :meth:`to_dict`; ValueError names an unknown method or a bad T."""
        if not isinstance(d, dict) or d.get("method") != METHOD:
            raise ValueError(f"unknown calibration {d!r}; expected method {METHOD!r}")
        return cls(d.get("temperature", float("nan")))


class CalibratedModel:
    """A fitted classifier whose ``predict_proba`` goes through a :class:`Temperature`.

    Parameters
    ----------
    model : fitted classifier with ``predict_proba`` and ``classes_``.
    calibrator : Temperature.

    Attributes
    ----------
    classes_ : the model's classes. model, calibrator : as given.
    """

    def __init__(self, model: Any, calibrator: Temperature):
        self.model = model
        self.calibrator = calibrator
        self.classes_ = np.asarray(model.classes_)

    def predict_proba(self, X) -> np.ndarray:
        """Calibrated probabilities (n, K), columns in ``classes_`` order."""
        return self.calibrator.transform(self.model.predict_proba(X))

    def predict(self, X) -> np.ndarray:
        return self.classes_[np.argmax(self.predict_proba(X), axis=1)]

    def __getattr__(self, name: str) -> Any:
        # the wrapped model's other attributes (best_params_, feature_names_, ...) stay readable
        if name in ("model", "calibrator", "classes_"):
            raise AttributeError(name)
        return getattr(self.model, name)
