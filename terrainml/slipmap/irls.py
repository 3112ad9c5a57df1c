"""Robust polynomial regression by IRLS (IRLS paper §II-B, design §13).

:class:`IRLSRegressor` is a scikit-learn-style estimator: inputs are scaled by a fixed
``input_scale`` (so that robots fitting separately share one feature space), expanded by
:class:`sklearn.preprocessing.PolynomialFeatures` (third order by default, paper §III-A) and fitted
by statsmodels' :class:`~statsmodels.robust.robust_linear_model.RLM` (iteratively re-weighted least
squares with a Huber or Tukey-bisquare norm). No hand-rolled solver.

After RLM converges, the final IRLS weights ``w`` define the *local sufficient statistics*
``A = X^T W X`` and ``b = X^T W y`` (design §13). ``coef_`` is the weighted least-squares solution
under those final weights (one WLS step after RLM's last iteration, a change of the order of RLM's
tolerance), so a single robot's estimate is exactly the solve of its own statistics, and the merge
``(sum A_k) theta = sum b_k`` of several robots equals the centralised weighted fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.preprocessing import PolynomialFeatures
from sklearn.utils.validation import check_is_fitted
from statsmodels.robust import norms
from statsmodels.robust.robust_linear_model import RLM

NORMS = ("huber", "bisquare")
_DEFAULT_TUNING = {"huber": 1.345, "bisquare": 4.685}


def make_norm(norm: str, tuning: float | None = None):
    """The statsmodels robust norm for ``norm`` ("huber" or "bisquare")."""
    if norm not in NORMS:
        raise ValueError(f"norm must be one of {NORMS}, got {norm!r}")
    t = _DEFAULT_TUNING[norm] if tuning is None else float(tuning)
    if not (np.isfinite(t) and t > 0):
        raise ValueError(f"tuning must be a positive number, got {tuning!r}")
    return norms.HuberT(t=t) if norm == "huber" else norms.TukeyBiweight(c=t)


def polynomial_features(x: np.ndarray, degree: int, input_scale: float) -> np.ndarray:
    """Polynomial features (bias included) of ``x / input_scale``.

    Parameters
    ----------
    x : array, shape (n_samples, n_inputs)
    degree : polynomial degree (3 in the paper).
    input_scale : divisor applied to ``x`` first (same unit as ``x``); keeps features O(1).

    Returns
    -------
    array, shape (n_samples, n_features); columns in sklearn ``PolynomialFeatures`` order.
    """
    x = np.asarray(x, dtype=float)
    pf = PolynomialFeatures(degree=degree, include_bias=True)
    return pf.fit_transform(x / input_scale)


def solve_normal_equations(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``a theta = b`` (symmetric PSD ``a``); minimum-norm least squares when singular."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    theta, *_ = np.linalg.lstsq(a, b, rcond=None)
    return theta


@dataclass
class SufficientStats:
    """Local sufficient statistics of one weighted least-squares problem.

    Attributes
    ----------
    a : array, shape (p, p)   ``X^T W X``
    b : array, shape (p,)     ``X^T W y``
    n : number of samples
    sum_w : sum of the weights
    """

    a: np.ndarray
    b: np.ndarray
    n: int
    sum_w: float

    def __add__(self, other: "SufficientStats") -> "SufficientStats":
        if self.a.shape != other.a.shape:
            raise ValueError(f"cannot merge statistics of shapes {self.a.shape} and {other.a.shape}")
        return SufficientStats(self.a + other.a, self.b + other.b, self.n + other.n,
                               self.sum_w + other.sum_w)

    def solve(self) -> np.ndarray:
        """The weighted least-squares coefficients ``theta`` of ``a theta = b``."""
        return solve_normal_equations(self.a, self.b)


class IRLSRegressor(RegressorMixin, BaseEstimator):
    """Robust polynomial regression fitted by IRLS (statsmodels RLM).

    Parameters
    ----------
    degree : int, default 3
        Polynomial degree of the features (paper: third order).
    norm : {"huber", "bisquare"}, default "huber"
        Robust norm (statsmodels ``HuberT`` or ``TukeyBiweight``).
    tuning : float or None
        Norm tuning constant in units of the residual scale (default 1.345 Huber, 4.685 bisquare).
    input_scale : float, default 1.0
        Inputs are divided by this before the polynomial expansion (same unit as ``X``, e.g.
        rad/s). Robots whose statistics are merged must use the same value.
    max_iter : int, default 50
        IRLS iterations at most.
    tol : float, default 1e-8
        RLM convergence tolerance.

    Attributes
    ----------
    coef_ : array, shape (n_features,)
        Coefficients of the polynomial features (bias first), WLS under the final weights.
    weights_ : array, shape (n_samples,)
        Final IRLS weights in [0, 1].
    scale_ : float
        Robust residual scale (MAD) of the last iteration, unit of ``y``.
    n_iter_ : int
    n_features_in_ : int
    """

    def __init__(self, degree: int = 3, norm: str = "huber", tuning: float | None = None,
                 input_scale: float = 1.0, max_iter: int = 50, tol: float = 1e-8):
        self.degree = degree
        self.norm = norm
        self.tuning = tuning
        self.input_scale = input_scale
        self.max_iter = max_iter
        self.tol = tol

    # ------------------------------------------------------------------ checks
    def _check_params(self) -> None:
        if isinstance(self.degree, bool) or not isinstance(self.degree, (int, np.integer)) or self.degree < 1:
            raise ValueError(f"degree must be an integer >= 1, got {self.degree!r}")
        make_norm(self.norm, self.tuning)
        if not (np.isfinite(self.input_scale) and self.input_scale > 0):
            raise ValueError(f"input_scale must be a positive number, got {self.input_scale!r}")
        if not isinstance(self.max_iter, (int, np.integer)) or self.max_iter < 1:
            raise ValueError(f"max_iter must be an integer >= 1, got {self.max_iter!r}")
        if not (np.isfinite(self.tol) and self.tol > 0):
            raise ValueError(f"tol must be a positive number, got {self.tol!r}")

    @staticmethod
    def _check_xy(x, y=None):
        x = np.asarray(x, dtype=float)
        if x.ndim == 1:
            x = x[:, None]
        if x.ndim != 2:
            raise ValueError(f"X must be 2-D (n_samples, n_inputs), got shape {x.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError("X contains non-finite values")
        if y is None:
            return x
        y = np.asarray(y, dtype=float).ravel()
        if y.shape[0] != x.shape[0]:
            raise ValueError(f"X has {x.shape[0]} samples but y has {y.shape[0]}")
        if not np.all(np.isfinite(y)):
            raise ValueError("y contains non-finite values")
        return x, y

    # ------------------------------------------------------------------ api
    def features(self, x) -> np.ndarray:
        """Polynomial features of ``X``, shape (n_samples, n_features)."""
        x = self._check_xy(x)
        return polynomial_features(x, int(self.degree), float(self.input_scale))

    def fit(self, X, y) -> "IRLSRegressor":
        """Fit by IRLS.

        Parameters
        ----------
        X : array, shape (n_samples, n_inputs)
            Inputs (e.g. left/right wheel speeds, rad/s).
        y : array, shape (n_samples,)
            Target (e.g. longitudinal slippage, m/s, or slip angle, rad).
        """
        self._check_params()
        x, y = self._check_xy(X, y)
        feats = polynomial_features(x, int(self.degree), float(self.input_scale))
        if x.shape[0] < feats.shape[1] + 1:
            raise ValueError(f"need more than {feats.shape[1]} samples for degree {self.degree} "
                             f"with {x.shape[1]} inputs, got {x.shape[0]}")
        res = RLM(y, feats, M=make_norm(self.norm, self.tuning)).fit(
            maxiter=int(self.max_iter), tol=float(self.tol))
        w = np.asarray(res.weights, dtype=float)
        if not np.all(np.isfinite(w)) or w.sum() <= 0:  # degenerate (e.g. zero residual scale)
            w = np.ones_like(y)
        self.weights_ = w
        self.scale_ = float(res.scale)
        self.n_iter_ = int(res.fit_history["iteration"])
        self.n_features_in_ = x.shape[1]
        self._stats = _stats(feats, y, w)
        self.coef_ = self._stats.solve()
        return self

    def predict(self, X) -> np.ndarray:
        """Predicted target, shape (n_samples,)."""
        check_is_fitted(self, "coef_")
        x = self._check_xy(X)
        if x.shape[1] != self.n_features_in_:
            raise ValueError(f"X has {x.shape[1]} inputs, fitted with {self.n_features_in_}")
        return polynomial_features(x, int(self.degree), float(self.input_scale)) @ self.coef_

    def sufficient_stats(self) -> SufficientStats:
        """``A = X^T W X``, ``b = X^T W y`` with the final IRLS weights (design §13)."""
        check_is_fitted(self, "coef_")
        s = self._stats
        return SufficientStats(s.a.copy(), s.b.copy(), s.n, s.sum_w)


def _stats(feats: np.ndarray, y: np.ndarray, w: np.ndarray) -> SufficientStats:
    xw = feats * w[:, None]
    a = xw.T @ feats
    a = 0.5 * (a + a.T)  # exactly symmetric, so the upper-triangle message round-trips bit for bit
    return SufficientStats(a=a, b=xw.T @ y, n=int(len(y)), sum_w=float(w.sum()))
