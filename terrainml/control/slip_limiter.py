"""Per-wheel slip limiter that works from rest to cruise (design §12).

The thesis PID (:mod:`terrainml.control.pid`) is enabled only when the body and the wheel move
(>= 0.05 m/s) and resets when disabled, so it lets go exactly at a stall, and its feed-forward
caps the wheel at ``v_est / (1 - s_T)`` from a lagging speed estimate, which stalls the robot at
low speed. This limiter replaces both rules for traction control; the thesis PID stays for the
thesis configuration (Table 8.1).

Per wheel i and control tick (all speeds along the wheel's heading, signed by the driving
direction ``d = sgn(omega_cmd)`` so that forward and backward read the same)::

    u      = d omega_meas R                       wheel surface speed (m/s)
    u_cmd  = d omega_cmd R                        commanded surface speed (inverse kinematics)
    v      = d v_wheel,  v+ = max(v, 0)           estimated wheel-centre speed over ground (m/s)

    shear-displacement slip, integrated as the soil's shear displacement j = s L (design §6.2,
    Janosi-Hanamoto in displacement form; it holds still at standstill). It follows the measured
    motion whatever the command (a stop relaxes it as the wheel halts before the body) and lives
    in the frame of the last non-zero command's direction (a reversal flips its sign):

    ds/dt  = (u - v) / L - s max(|u|, |v|) / L                                            (1)

    ceiling on the surface speed (e = s_T - s, the error on the shear slip):

    u_hold = v+ / (1 - s_T)                       steady speed at the target slip         (2)
    I     += Ki e dt   only while the ceiling binds and e < 0; drains otherwise; in [-I_max, 0]
    u_ceil = u_hold + Kp e + I    (Kp: kp_build while e > 0, kp otherwise)                (3)
    u_ceil >= min(v+ + du_creep, u_cmd)  while e > 0;   u_ceil >= 0 otherwise             (4)

    output (before rate limits):  u_out = min(u_cmd, u_ceil)                              (5)

At a stall (v = 0) the wheel creeps (``Kp e``, at least ``du_creep``) until the soil's shear
displacement reaches the target slip, then holds: traction sits at the peak and the dig-in
sinkage, whose rate grows with the wheel's surface speed, stops growing. The limiter never lets go
there. The feed-forward (2) is only the holding speed: the build-up term works on the shear slip,
which integrates the slip velocity, so a small lagging v cannot stall the wheel.
:func:`regularised_slip` is the SAE slip with a speed floor, for reading a slip at rest.

Braking (target ``s_B < 0``) is the mirror image: a floor ``u >= v - max(|s_B| v, du_creep)``
(never below 0 in the driving direction), so a braking wheel does not lock.

Release is smooth: the command offset ``u_out - u_cmd`` moves towards its new value at most
``release_rate_mps2`` per second when the limit lets go (and ``clamp_rate_mps2`` when it tightens),
and the integrator drains at ``Ki``-rate once the slip is below target: there is no reset. A
wheel with a non-finite input, or a zero command, gets the command unchanged and its state
decays smoothly (the offset relaxes at the release rate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from terrainml.control._wheels import per_wheel

__all__ = ["LimiterStep", "SlipLimiter", "SlipLimiterConfig", "regularised_slip"]


def regularised_slip(u_mps, v_mps, v_floor_mps: float) -> np.ndarray:
    """SAE slip ``(u - v) / max(|u|, |v|, v_floor)`` (design §7.1) with a speed floor.

    Parameters
    ----------
    u_mps : array_like, wheel surface speed omega R, m/s.
    v_mps : array_like, wheel-centre speed over ground along the wheel, m/s.
    v_floor_mps : float, m/s, denominator floor: below it the slip is the slip velocity over the
        floor, so a wheel at rest reads 0 and a creeping wheel at a stall reads ``u / v_floor``
        (clipped to [-1, 1]).

    Returns
    -------
    ndarray, slip in [-1, 1]; shapes broadcast.
    """
    u = np.asarray(u_mps, dtype=float)
    v = np.asarray(v_mps, dtype=float)
    den = np.maximum(np.maximum(np.abs(u), np.abs(v)), float(v_floor_mps))
    return np.clip((u - v) / den, -1.0, 1.0)


@dataclass(frozen=True)
class SlipLimiterConfig:
    """Gains and limits of :class:`SlipLimiter` (one set shared by all wheels).

    Parameters
    ----------
    wheel_radius_m : m, wheel radius R.
    creep_mps : m/s, ``du_creep`` of (4): while the shear slip is below target the wheel may always
        turn this much faster than the body (at a stall: the creep speed). *Assumption*: 0.08 m/s, about 0.5 rad/s
        at the reference wheel: slow enough that the dig-in sinkage grows over tens of seconds,
        fast enough that the shear displacement reaches the traction peak within about 1 s.
    v_floor_mps : m/s, speed floor of :func:`regularised_slip` (*assumption*: 0.1 m/s).
    contact_length_m : m, contact length L of the shear slip (1) (*assumption*: 0.14 m, the
        reference wheel on dry sand at its static load; it sets how fast s_shear follows).
    kp_mps : m/s per unit slip, how much faster than the holding speed ``v / (1 - s_T)`` the
        ceiling lets a wheel turn per unit of shear-slip error (*assumption*: 0.5 m/s: 0.2 m/s of
        surface speed at a stall with the shear slip 0.4 below target).
    ki : m/s per (unit slip x s), integral trim of the ceiling (*assumption*: 1.0).
    integral_limit_mps : m/s, the trim can lower the ceiling by at most this much.
    clamp_rate_mps2 : m/s^2, fastest tightening of the command offset (a surface-speed slew;
        *assumption*: 10 m/s^2, the wheel drive follows within ~50 ms).
    release_rate_mps2 : m/s^2, fastest release of the command offset (*assumption*: 1.0 m/s^2,
        the robot's own acceleration limit: a released wheel spins up no faster than a ramp).
    kp_build_mps : m/s per unit slip or None, the gain of (3) while the shear slip is *below*
        target (build-up, e > 0); None: ``kp_mps``. The wheel drive is a PI speed loop whose
        torque needs a speed error: a ceiling only a few cm/s above a body at rest leaves a wheel
        sitting in its own rut with the integrator's torque alone, and every start from rest is
        late (mission suite, tuning seeds: +4 to +13 % route time at kp 0.5 on level ground).
    rest_relax_s : s or None, time constant with which the shear slip decays towards 0 while the
        wheel and the body are both at rest (``max(|u|, |v|) < rest_speed_mps``); None: it holds, as
        the soil's displacement does. Why: at rest (1) cannot move, so a shear slip estimated above
        the cap (a speed estimate biased low, a roll-back on a grade) keeps the ceiling at 0 and
        the wheel at rest for good (mission suite, field tuning seed tilled_loam 5004: 13 s).
        Once it decays below the cap the creep floor of (4) lets the wheel take up the soil again.
    rest_speed_mps : m/s, below this wheel and body speed ``rest_relax_s`` applies (0.02).
    """

    wheel_radius_m: float
    creep_mps: float = 0.08
    v_floor_mps: float = 0.1
    contact_length_m: float = 0.14
    kp_mps: float = 0.5
    ki: float = 1.0
    integral_limit_mps: float = 0.3
    clamp_rate_mps2: float = 10.0
    release_rate_mps2: float = 1.0
    kp_build_mps: float | None = None
    rest_relax_s: float | None = None
    rest_speed_mps: float = 0.02

    def __post_init__(self) -> None:
        for name in ("wheel_radius_m", "creep_mps", "v_floor_mps", "contact_length_m", "kp_mps",
                     "integral_limit_mps", "clamp_rate_mps2", "release_rate_mps2"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"SlipLimiterConfig.{name} must be finite and > 0, got {v!r}")
        if self.kp_build_mps is not None and not (math.isfinite(self.kp_build_mps)
                                                  and self.kp_build_mps > 0.0):
            raise ValueError("SlipLimiterConfig.kp_build_mps must be None or finite and > 0, "
                             f"got {self.kp_build_mps!r}")
        v = self.rest_relax_s
        if v is not None and not (math.isfinite(v) and v > 0.0):
            raise ValueError(f"SlipLimiterConfig.rest_relax_s must be None or finite and > 0, got {v!r}")
        if not (math.isfinite(self.rest_speed_mps) and self.rest_speed_mps >= 0.0):
            raise ValueError("SlipLimiterConfig.rest_speed_mps must be finite and >= 0, got "
                             f"{self.rest_speed_mps!r}")
        if not (math.isfinite(self.ki) and self.ki >= 0.0):
            raise ValueError(f"SlipLimiterConfig.ki must be finite and >= 0, got {self.ki!r}")


@dataclass(frozen=True)
class LimiterStep:
    """One tick of :class:`SlipLimiter`; every array has shape (N,).

    Attributes
    ----------
    omega_out_radps : limited wheel-speed command, rad/s.
    offset_radps : ``omega_out - omega_cmd``, rad/s (what the simulator's hook adds).
    slip_shear : shear-displacement slip (1) per wheel (signed like the driving direction).
    limiting : bool, whether the limit binds this tick (before rate limits).
    """

    omega_out_radps: np.ndarray
    offset_radps: np.ndarray
    slip_shear: np.ndarray
    limiting: np.ndarray


class SlipLimiter:
    """Per-wheel slip limiter, vectorised over N wheels (module docstring, eq. 1-5).

    Parameters
    ----------
    n_wheels : number of wheels N.
    config : :class:`SlipLimiterConfig`.

    Examples
    --------
    A stalled body (v = 0) with a wheel spinning at 3 rad/s (R = 0.165 m) against a 0.4 cap: the
    shear slip passes the cap, so the ceiling drops to 0 and the command is pulled down from
    3 rad/s (held, not released).

    >>> lim = SlipLimiter(1, SlipLimiterConfig(wheel_radius_m=0.165))
    >>> for _ in range(100):
    ...     out = lim.step([3.0], [3.0], [0.0], [0.4], dt_s=0.01)
    >>> bool(out.limiting[0]), round(float(out.omega_out_radps[0]), 3)
    (True, 0.0)
    """

    def __init__(self, n_wheels: int, config: SlipLimiterConfig) -> None:
        if int(n_wheels) < 1:
            raise ValueError(f"n_wheels must be >= 1, got {n_wheels!r}")
        self.n_wheels = int(n_wheels)
        self.config = config
        n = self.n_wheels
        self.integral_mps = np.zeros(n)       # ceiling trim, <= 0 (m/s of surface speed)
        self.offset_mps = np.zeros(n)         # u_out - u_cmd after the rate limits (signed by d)
        self.slip_shear = np.zeros(n)         # shear-displacement slip (1)
        self.direction = np.ones(n)           # driving direction of the last non-zero command

    def reset(self) -> None:
        """Clear the state of every wheel (a new run; never called while driving)."""
        self.integral_mps[:] = 0.0
        self.offset_mps[:] = 0.0
        self.slip_shear[:] = 0.0
        self.direction[:] = 1.0

    def _vec(self, x, name: str) -> np.ndarray:
        return per_wheel(x, self.n_wheels, name)

    def step(self, omega_meas_radps, omega_cmd_radps, v_wheel_mps, slip_target,
             dt_s: float) -> LimiterStep:
        """Advance one control tick.

        Parameters
        ----------
        omega_meas_radps : array_like, shape (N,), measured wheel speeds, rad/s.
        omega_cmd_radps : array_like, shape (N,), commanded wheel speeds from the robot's inverse
            kinematics, rad/s.
        v_wheel_mps : array_like, shape (N,), estimated wheel-centre velocity along each wheel's
            heading, m/s (signed in the wheel frame, like omega R).
        slip_target : array_like, shape (N,), served target per wheel, unsigned-direction: > 0 a
            traction cap s_T, < 0 a braking floor s_B (the class's target, or the safe cap on
            fallback). Which one applies is chosen by the wheel itself: the traction cap while
            the command asks the wheel to turn at least as fast as the ground moves under it,
            the braking floor otherwise; pass ``(s_T, s_B)`` pairs through
            :meth:`step_pair` to give both.
        dt_s : float, s, time since the previous tick (a non-positive or non-finite dt freezes
            the integrator, the shear lag and the rate limits for this tick).

        Returns
        -------
        LimiterStep with arrays of shape (N,).
        """
        s = self._vec(slip_target, "slip_target")
        return self.step_pair(omega_meas_radps, omega_cmd_radps, v_wheel_mps,
                              np.where(s > 0, s, np.nan), np.where(s < 0, s, np.nan), dt_s)

    def step_pair(self, omega_meas_radps, omega_cmd_radps, v_wheel_mps, traction_cap,
                  braking_floor, dt_s: float) -> LimiterStep:
        """:meth:`step` with both targets per wheel: ``traction_cap`` (> 0, NaN: no cap) and
        ``braking_floor`` (< 0, NaN: no floor), shape (N,) each."""
        cfg = self.config
        rw = cfg.wheel_radius_m
        om = self._vec(omega_meas_radps, "omega_meas_radps")
        oc = self._vec(omega_cmd_radps, "omega_cmd_radps")
        vw = self._vec(v_wheel_mps, "v_wheel_mps")
        s_t = np.abs(self._vec(traction_cap, "traction_cap"))
        s_b = np.abs(self._vec(braking_floor, "braking_floor"))
        dt = float(dt_s)
        dt_ok = math.isfinite(dt) and dt > 0.0

        ok = np.isfinite(om) & np.isfinite(oc) & np.isfinite(vw) & (oc != 0.0)
        # driving direction of the command; at a zero command, that of the last non-zero one.
        # The shear slip is kept in the driving direction's frame, so a reversal flips its sign:
        # the soil's displacement is where the wheel left it, not at the cap of the new direction
        d = np.where(np.isfinite(oc) & (oc != 0.0), np.sign(oc), self.direction)
        self.slip_shear = np.where(d != self.direction, -self.slip_shear, self.slip_shear)
        self.direction = d
        u_cmd = np.where(np.isfinite(oc), d * oc * rw, 0.0)
        v = np.where(ok, d * vw, 0.0)
        v_fwd = np.maximum(v, 0.0)

        # (1): the shear-displacement slip, integrated exactly as the soil's shear displacement
        # j = s L: ds/dt = (u - v) / L - s max(|u|, |v|) / L (holds still at standstill). It
        # follows the measured motion whatever the command: at a stop the wheel halts before the
        # body and the soil's displacement relaxes, so a restart must not begin from the cap.
        meas = np.isfinite(om) & np.isfinite(vw)
        if dt_ok:
            um = np.where(meas, d * om * rw, 0.0)
            vm = np.where(meas, d * vw, 0.0)
            mx = np.maximum(np.abs(um), np.abs(vm))
            a = -np.expm1(-mx * dt / cfg.contact_length_m)
            s_inst = np.where(mx > 1e-9, (um - vm) / np.maximum(mx, 1e-9), self.slip_shear)
            self.slip_shear = np.where(meas, self.slip_shear + a * (s_inst - self.slip_shear),
                                       self.slip_shear)
            if cfg.rest_relax_s is not None:
                # wheel and body at rest: (1) holds, so an estimate left above the cap (a biased
                # speed estimate, a roll-back) would hold the wheel at rest for good; let it go
                rest = meas & (mx < cfg.rest_speed_mps)
                self.slip_shear = np.where(rest, self.slip_shear * math.exp(-dt / cfg.rest_relax_s),
                                           self.slip_shear)

        # traction side: the command is at or above the ground speed
        traction = ok & (u_cmd >= v) & np.isfinite(s_t) & (s_t > 0.0)
        s_tc = np.clip(np.where(traction, s_t, 0.0), 0.0, 0.95)
        e = np.where(traction, s_tc - self.slip_shear, 0.0)
        u_hold = v_fwd / (1.0 - s_tc)                  # (1): steady speed at the target slip
        # (4): build up at most kp (s_T - s) faster than u_hold; the creep floor applies only
        # while the shear slip is below target (a stalled wheel creeps up to the peak, then holds)
        kp_build = cfg.kp_mps if cfg.kp_build_mps is None else cfg.kp_build_mps
        u_ceil = u_hold + np.where(e > 0.0, kp_build, cfg.kp_mps) * e + self.integral_mps
        u_ceil = np.where(e > 0.0, np.maximum(u_ceil, np.minimum(u_hold + cfg.creep_mps, u_cmd)),
                          np.maximum(u_ceil, 0.0))
        lim_t = traction & (u_cmd > u_ceil)

        # braking side: the command is below the ground speed; floor, never below 0
        braking = ok & (u_cmd < v) & np.isfinite(s_b) & (s_b > 0.0)
        s_bc = np.clip(np.where(braking, s_b, 0.0), 0.0, 0.95)
        u_floor = np.maximum(v_fwd - np.maximum(s_bc * v_fwd, cfg.creep_mps), 0.0)
        lim_b = braking & (u_cmd < u_floor)

        # integral trim (anti-windup: grows only while the ceiling binds; drains otherwise)
        if dt_ok and cfg.ki > 0.0:
            grow = lim_t & (e < 0.0)
            trial = self.integral_mps + cfg.ki * e * dt
            drained = np.minimum(self.integral_mps + cfg.ki * np.abs(e) * dt, 0.0)
            self.integral_mps = np.clip(np.where(grow, trial, np.where(lim_t, self.integral_mps,
                                                                          drained)),
                                        -cfg.integral_limit_mps, 0.0)

        target_off = np.where(lim_t, u_ceil - u_cmd, np.where(lim_b, u_floor - u_cmd, 0.0))
        # rate limits on the offset: tighten at clamp_rate, let go at release_rate (no reset)
        if dt_ok:
            prev = self.offset_mps
            tighten = np.abs(target_off) > np.abs(prev)
            step = np.where(tighten, cfg.clamp_rate_mps2, cfg.release_rate_mps2) * dt
            new = prev + np.clip(target_off - prev, -step, step)
        else:
            new = self.offset_mps
        # an offset may never reverse the wheel against its command nor exceed the command's
        # own side (a limiter: traction offsets <= 0, braking offsets >= 0)
        new = np.where(ok, np.maximum(new, -np.abs(u_cmd)), new)
        new = np.where(np.isfinite(new), new, 0.0)
        self.offset_mps = new
        off_radps = np.where(ok, d * new / rw, 0.0)
        oc_safe = np.where(np.isfinite(oc), oc, 0.0)
        return LimiterStep(omega_out_radps=oc_safe + off_radps, offset_radps=off_radps,
                           slip_shear=d * self.slip_shear, limiting=lim_t | lim_b)
