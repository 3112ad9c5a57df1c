"""Fixed exponential slippage approximation: the baseline of the IRLS paper (its ref. [1]).

The IRLS paper compares against "a prediction technique based on an exponential function
approximation" with "precomputed constants" from its ref. [1] (Focchi et al., pseudo-kinematic
control of tracked vehicles), which models slippage as exponential functions of the turning radius
(as Moosavian and Kalantari did with path curvature). The paper does not print the form, so this
module uses, with ``R = v / omega`` the commanded turning radius (m)::

    alpha         = sign(omega) * a_alpha * exp(b_alpha * |R|)
    beta_outer    = a_out * exp(b_out * |R|)        (outer track: right in a left turn)
    beta_inner    = a_in  * exp(b_in  * |R|)

``b < 0``: slippage vanishes on a straight line (|R| -> inf). The six constants are identified once
(:meth:`ExponentialSlipModel.identify`, scipy ``curve_fit``) on open-loop turns on one default
terrain, then never adapted, which is the point of the baseline.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import curve_fit

_MIN_YAW_RATE = 1e-6


@dataclass(frozen=True)
class ExponentialSlipModel:
    """Six fixed constants; see the module docstring for the form. Units: m/s (beta), rad (alpha), 1/m (b)."""

    a_alpha_rad: float = 0.0
    b_alpha_per_m: float = -1.0
    a_out_mps: float = 0.0
    b_out_per_m: float = -1.0
    a_in_mps: float = 0.0
    b_in_per_m: float = -1.0

    def predict(self, v_mps, yaw_rate_radps):
        """Predicted (beta_left_mps, beta_right_mps, alpha_rad) for commanded (v, omega).

        Parameters
        ----------
        v_mps, yaw_rate_radps : arrays, shape (n,)

        Returns
        -------
        three arrays, shape (n,)
        """
        v = np.asarray(v_mps, dtype=float)
        w = np.asarray(yaw_rate_radps, dtype=float)
        turning = np.abs(w) > _MIN_YAW_RATE
        radius = np.where(turning, np.abs(v) / np.where(turning, np.abs(w), 1.0), np.inf)
        with np.errstate(over="ignore", invalid="ignore"):
            f_alpha = np.where(turning, self.a_alpha_rad * np.exp(self.b_alpha_per_m * radius), 0.0)
            f_out = np.where(turning, self.a_out_mps * np.exp(self.b_out_per_m * radius), 0.0)
            f_in = np.where(turning, self.a_in_mps * np.exp(self.b_in_per_m * radius), 0.0)
        left_turn = w > 0
        beta_l = np.where(left_turn, f_in, f_out)
        beta_r = np.where(left_turn, f_out, f_in)
        alpha = np.sign(w) * f_alpha
        return beta_l, beta_r, alpha

    @classmethod
    def identify(cls, v_mps, yaw_rate_radps, beta_left_mps, beta_right_mps, alpha_rad) -> "ExponentialSlipModel":
        """Fit the six constants to slippage measured on turns (scipy ``curve_fit``).

        Parameters
        ----------
        v_mps, yaw_rate_radps : arrays, shape (n,)  commanded twist of each sample (|omega| > 0).
        beta_left_mps, beta_right_mps, alpha_rad : arrays, shape (n,)  measured slippage.
        """
        v = np.asarray(v_mps, float)
        w = np.asarray(yaw_rate_radps, float)
        keep = np.abs(w) > _MIN_YAW_RATE
        radius = np.abs(v[keep]) / np.abs(w[keep])
        left_turn = w[keep] > 0
        bl, br = np.asarray(beta_left_mps, float)[keep], np.asarray(beta_right_mps, float)[keep]
        outer = np.where(left_turn, br, bl)
        inner = np.where(left_turn, bl, br)
        alpha_mag = np.sign(w[keep]) * np.asarray(alpha_rad, float)[keep]

        def fit(y):
            def f(r, a, b):
                return a * np.exp(b * r)
            i0 = int(np.argmin(radius))
            p, _ = curve_fit(f, radius, y, p0=(float(y[i0]) or 1e-3, -0.5), maxfev=20000)
            return float(p[0]), float(p[1])

        a_al, b_al = fit(alpha_mag)
        a_o, b_o = fit(outer)
        a_i, b_i = fit(inner)
        return cls(a_al, b_al, a_o, b_o, a_i, b_i)

    def to_dict(self) -> dict:
        return asdict(self)
