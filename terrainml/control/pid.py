"""Per-wheel slip PID (design §12; thesis §8.3, eq. 8.1-8.3).

For every wheel i, at every control tick::

    e_i        = s_des_i - s_meas_i                                    (eq. 8.1)
    PID_out_i  = Kp e_i + I_i + D_i                                    (eq. 8.2, discretised)
    omega_cmd_i = omega_low_level_i + PID_out_i                        (eq. 8.3)

``s_des_i`` is the signed desired slip of eq. 8.7-8.9 (:func:`terrainml.lookup.wheel_targets.
desired_slip_per_wheel`), ``s_meas_i`` the measured SAE slip of design §7.1 (positive in forward
traction), ``omega_low_level_i`` the wheel-speed set-point of the low-level kinematic control
(rad/s) and ``omega_cmd_i`` what the wheel's velocity loop (the ODrive on the reference robot)
receives. Because the slip ``(omega R - v) / max(|omega R|, |v|)`` always grows with omega, a
positive error always asks for a faster (more positive) wheel speed in either driving direction,
so the same sign convention serves forward and backward traction and braking (thesis Table 8.1).

Discretisation and safeguards (beyond the thesis, which used a pure P controller):

* **enable rule** (thesis §8.3.2): a wheel is controlled only when ``|v_long_i| >=
  min_wheel_speed_mps`` and the body speed ``>= min_body_speed_mps`` (both 0.05 m/s). A disabled
  wheel gets error 0, ``PID_out = 0`` (``omega_cmd = omega_low_level``), and its integrator,
  derivative filter and rate limiter are reset. Non-finite inputs disable the wheel for that tick;
  the output is never NaN.
* **integral** ``I += Ki e dt`` (forward Euler), clamped to ``+-integral_limit_radps``; while the
  output is saturated (output limit, rate limit or the one-sided limit of ``mode="limit"``) the
  integrator does not grow further in the saturating direction (conditional integration,
  anti-windup).
* **derivative on the filtered measurement** ``D = -Kd d(s_f)/dt`` with ``s_f`` a first-order
  low-pass of ``s_meas`` (time constant ``derivative_tau_s``), so a step in the desired slip (a
  class or state change) gives no derivative kick and encoder noise is not differentiated raw.
* **output limit** ``|PID_out| <= output_limit_radps``; **rate limit** ``|d PID_out / dt| <=
  rate_limit_radps2`` (default: none).

Two optional structures, both off by default (the thesis's P controller):

* **feed-forward** (``wheel_radius_m`` set): the controller starts from the wheel speed that would
  give exactly the desired slip at the measured wheel-centre speed, the inverse of the slip
  definition::

      omega_ff R = v_long / (1 - |s_des|)   traction (s_des sgn(v_long) > 0)
      omega_ff R = v_long (1 - |s_des|)     braking  (s_des sgn(v_long) < 0)

  (to first order ``v_long (1 + s_des)``), and ``PID_out = (omega_ff - omega_low_level) + Kp e +
  I + D``: the PID only trims what the feed-forward misses (slip-measurement bias, lag), so it
  holds the target with modest gains instead of winding up over seconds.
* **mode** ``"track"`` (default, thesis eq. 8.3: both directions) or ``"limit"`` (a traction /
  anti-lock limiter): the correction may only move the wheel speed towards less slip magnitude
  (``sign(PID_out) = -sign(s_des)``), so the controller caps the slip at the target but never
  spins a wheel faster than the low-level command asks. With ``mode="limit"`` the body speed stays
  governed by the speed command; with ``"track"`` and feed-forward the slip is governed and the
  speed command is overridden (on soft soil holding a slip above the cruise slip accelerates the
  robot past its command; holding one below it stalls the robot).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from terrainml.control._wheels import per_wheel

__all__ = ["MODES", "PIDStep", "SlipPID", "SlipPIDConfig", "wheel_speed_for_slip"]

MODES = ("track", "limit")


def wheel_speed_for_slip(v_long_mps, slip, wheel_radius_m: float) -> np.ndarray:
    """Wheel speed (rad/s) that gives SAE slip ``slip`` at wheel-centre speed ``v_long_mps``.

    The inverse of ``s = (omega R - v) / max(|omega R|, |v|)`` (design §7.1): in traction
    (``slip`` with the sign of ``v``) ``omega R = v / (1 - |s|)``, in braking ``omega R = v (1 -
    |s|)``. ``|s|`` is clipped to 0.95 (a finite wheel speed). Shapes broadcast.
    """
    v = np.asarray(v_long_mps, dtype=float)
    s = np.clip(np.asarray(slip, dtype=float), -0.95, 0.95)
    traction = s * np.sign(v) >= 0.0
    va = np.where(traction, v / (1.0 - np.abs(s)), v * (1.0 - np.abs(s)))
    return va / float(wheel_radius_m)


@dataclass(frozen=True)
class SlipPIDConfig:
    """Gains and limits of :class:`SlipPID` (one set shared by all wheels).

    Parameters
    ----------
    kp : rad/s per unit slip, proportional gain (thesis Table 8.1: 1.0).
    ki : rad/s per (unit slip x s), integral gain (thesis: 0).
    kd : rad/s x s per unit slip, derivative gain on the filtered measurement (thesis: 0).
    output_limit_radps : |PID_out| limit, rad/s (*assumption*: 5 rad/s, about 0.8 m/s at the
        reference wheel).
    integral_limit_radps : |I| clamp, rad/s (*assumption*: 2 rad/s).
    derivative_tau_s : s, time constant of the measurement low-pass feeding the derivative
        (*assumption*: 0.05 s, 5 base ticks).
    min_wheel_speed_mps : m/s, per-wheel enable threshold on |v_long_i| (thesis: 0.05).
    min_body_speed_mps : m/s, body-speed enable threshold (thesis: 0.05).
    rate_limit_radps2 : rad/s^2, slew limit on PID_out (inf: none, the default).
    wheel_radius_m : m, enables the feed-forward of the module docstring (None: off).
    mode : ``"track"`` (thesis eq. 8.3, default) or ``"limit"`` (one-sided slip limiter).
    """

    kp: float = 1.0
    ki: float = 0.0
    kd: float = 0.0
    output_limit_radps: float = 5.0
    integral_limit_radps: float = 2.0
    derivative_tau_s: float = 0.05
    min_wheel_speed_mps: float = 0.05
    min_body_speed_mps: float = 0.05
    rate_limit_radps2: float = math.inf
    wheel_radius_m: float | None = None
    mode: str = "track"

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "kd", "derivative_tau_s", "min_wheel_speed_mps",
                     "min_body_speed_mps"):
            v = getattr(self, name)
            if not math.isfinite(v) or v < 0.0:
                raise ValueError(f"SlipPIDConfig.{name} must be finite and >= 0, got {v!r}")
        for name in ("output_limit_radps", "integral_limit_radps", "rate_limit_radps2"):
            v = getattr(self, name)
            if not (v > 0.0):  # also rejects NaN; inf is allowed (no limit)
                raise ValueError(f"SlipPIDConfig.{name} must be > 0, got {v!r}")
        if self.wheel_radius_m is not None and not (math.isfinite(self.wheel_radius_m)
                                                    and self.wheel_radius_m > 0.0):
            raise ValueError(f"SlipPIDConfig.wheel_radius_m must be > 0 or None, "
                             f"got {self.wheel_radius_m!r}")
        if self.mode not in MODES:
            raise ValueError(f"SlipPIDConfig.mode must be one of {', '.join(MODES)}, "
                             f"got {self.mode!r}")


@dataclass(frozen=True)
class PIDStep:
    """One control tick of :class:`SlipPID`; every array has shape (N,), one entry per wheel.

    Attributes
    ----------
    omega_cmd_radps : final wheel-speed command ``omega_low_level + PID_out`` (eq. 8.3), rad/s.
    pid_out_radps : the PID correction, rad/s (0 on disabled wheels).
    error : slip error ``s_des - s_meas`` (eq. 8.1), 0 on disabled wheels.
    enabled : bool, whether the wheel was controlled this tick.
    """

    omega_cmd_radps: np.ndarray
    pid_out_radps: np.ndarray
    error: np.ndarray
    enabled: np.ndarray


class SlipPID:
    """Per-wheel slip PID for N wheels (design §12), vectorised over wheels.

    Parameters
    ----------
    n_wheels : number of wheels N.
    config : gains and limits; default the thesis's pure P controller (Kp = 1).

    Examples
    --------
    Thesis Table 8.1 case 1A (forward traction, too much slip; r = 1 m):

    >>> pid = SlipPID(1)
    >>> out = pid.step([0.1], [0.1429], v_long_mps=[0.6], body_speed_mps=0.6,
    ...                omega_low_level_radps=[0.7], dt_s=0.01)
    >>> round(float(out.omega_cmd_radps[0]), 3)
    0.657
    """

    def __init__(self, n_wheels: int, config: SlipPIDConfig | None = None) -> None:
        if int(n_wheels) < 1:
            raise ValueError(f"n_wheels must be >= 1, got {n_wheels!r}")
        self.n_wheels = int(n_wheels)
        self.config = config if config is not None else SlipPIDConfig()
        self.integral_radps = np.zeros(self.n_wheels)
        self._s_filt = np.zeros(self.n_wheels)
        self._has_filt = np.zeros(self.n_wheels, dtype=bool)
        self._out_prev = np.zeros(self.n_wheels)

    def reset(self, wheels: np.ndarray | None = None) -> None:
        """Clear integrator, derivative filter and rate limiter (all wheels, or an index)."""
        idx = slice(None) if wheels is None else wheels
        self.integral_radps[idx] = 0.0
        self._s_filt[idx] = 0.0
        self._has_filt[idx] = False
        self._out_prev[idx] = 0.0

    def _vec(self, x, name: str) -> np.ndarray:
        return per_wheel(x, self.n_wheels, name)

    def _bounds(self, s_des: np.ndarray, dt: float, dt_ok: bool,
                one_sided: bool) -> tuple[np.ndarray, np.ndarray]:
        """Per-wheel [lo, hi] of PID_out: output limit, rate limit and (``one_sided``) the
        limiter's side."""
        cfg = self.config
        lo = np.full(self.n_wheels, -cfg.output_limit_radps)
        hi = np.full(self.n_wheels, cfg.output_limit_radps)
        if one_sided:  # only towards less slip magnitude: sign(out) = -sign(s_des)
            hi = np.where(s_des >= 0.0, 0.0, hi)
            lo = np.where(s_des <= 0.0, 0.0, lo)
        if math.isfinite(cfg.rate_limit_radps2) and dt_ok:
            step = cfg.rate_limit_radps2 * dt
            lo = np.maximum(lo, np.minimum(self._out_prev - step, hi))
            hi = np.minimum(hi, np.maximum(self._out_prev + step, lo))
        return lo, hi

    def _derivative(self, enabled: np.ndarray, s_meas_safe: np.ndarray, dt: float, dt_ok: bool) -> np.ndarray:
        """D term on the low-passed measured slip (no setpoint kick), shape (N,), rad/s."""
        cfg = self.config
        d_term = np.zeros(self.n_wheels)
        first = enabled & ~self._has_filt
        self._s_filt[first] = s_meas_safe[first]
        self._has_filt[first] = True
        cont = enabled & ~first
        if dt_ok and np.any(cont):
            a = 1.0 - math.exp(-dt / cfg.derivative_tau_s) if cfg.derivative_tau_s > 0 else 1.0
            prev = self._s_filt[cont].copy()
            self._s_filt[cont] = prev + a * (s_meas_safe[cont] - prev)
            d_term[cont] = -cfg.kd * (self._s_filt[cont] - prev) / dt
        return d_term

    def step(self, slip_desired, slip_measured, v_long_mps, body_speed_mps: float,
             omega_low_level_radps, dt_s: float) -> PIDStep:
        """Advance one control tick.

        Parameters
        ----------
        slip_desired : array_like, shape (N,), signed desired slip s_des_i (eq. 8.7-8.9).
        slip_measured : array_like, shape (N,), measured slip s_meas_i (design §7.1).
        v_long_mps : array_like, shape (N,), wheel-centre longitudinal speed, m/s.
        body_speed_mps : float, body speed |v| = hypot(vx, vy), m/s.
        omega_low_level_radps : array_like, shape (N,), low-level wheel-speed set-point, rad/s.
        dt_s : float, s, time since the previous tick (integral, derivative and rate limit use
            it; a non-positive or non-finite dt freezes them for this tick).

        Returns
        -------
        PIDStep with arrays of shape (N,).
        """
        cfg = self.config
        s_des = self._vec(slip_desired, "slip_desired")
        s_meas = self._vec(slip_measured, "slip_measured")
        v_long = self._vec(v_long_mps, "v_long_mps")
        omega_ll = self._vec(omega_low_level_radps, "omega_low_level_radps")
        body = float(body_speed_mps)
        dt = float(dt_s)
        dt_ok = math.isfinite(dt) and dt > 0.0

        enabled = (np.isfinite(s_des) & np.isfinite(s_meas) & np.isfinite(v_long)
                   & (np.abs(v_long) >= cfg.min_wheel_speed_mps))
        if cfg.wheel_radius_m is not None:
            enabled &= np.isfinite(omega_ll)  # the feed-forward is relative to omega_ll
        if not (math.isfinite(body) and body >= cfg.min_body_speed_mps):
            enabled[:] = False
        if np.any(~enabled):
            self.reset(~enabled)

        error = np.where(enabled, s_des - s_meas, 0.0)
        s_meas_safe = np.where(enabled, s_meas, 0.0)
        s_des_safe = np.where(enabled, s_des, 0.0)

        d_term = self._derivative(enabled, s_meas_safe, dt, dt_ok)

        ff = np.zeros(self.n_wheels)
        if cfg.wheel_radius_m is not None:
            v_safe = np.where(enabled, v_long, 0.0)
            ff = np.where(enabled, wheel_speed_for_slip(v_safe, s_des_safe, cfg.wheel_radius_m)
                          - np.where(enabled, omega_ll, 0.0), 0.0)

        limit = cfg.mode == "limit"
        lo, hi = self._bounds(s_des_safe, dt, dt_ok, one_sided=limit)
        p_term = cfg.kp * error
        if dt_ok and cfg.ki > 0.0:
            trial = np.clip(self.integral_radps + cfg.ki * error * dt,
                            -cfg.integral_limit_radps, cfg.integral_limit_radps)
            unsat = ff + p_term + trial + d_term
            # conditional integration: do not wind up further into a saturated output (output
            # and rate limits; the limiter's side is handled by the clip below)
            w_lo, w_hi = (self._bounds(s_des_safe, dt, dt_ok, one_sided=False) if limit
                          else (lo, hi))
            winding = (((unsat > w_hi) & (error > 0.0)) | ((unsat < w_lo) & (error < 0.0)))
            self.integral_radps = np.where(enabled & ~winding, trial, self.integral_radps)
            if limit:  # the integrator lives on the allowed side only
                self.integral_radps = np.where(s_des_safe > 0.0, np.minimum(self.integral_radps, 0.0),
                                               np.where(s_des_safe < 0.0,
                                                        np.maximum(self.integral_radps, 0.0), 0.0))
        self.integral_radps[~enabled] = 0.0

        out = np.clip(ff + p_term + self.integral_radps + d_term, lo, hi)
        out = np.where(enabled, out, 0.0)
        self._out_prev = out.copy()
        omega_cmd = np.where(np.isfinite(omega_ll), omega_ll + out, 0.0)
        return PIDStep(omega_cmd_radps=omega_cmd, pid_out_radps=out, error=error,
                       enabled=enabled)
