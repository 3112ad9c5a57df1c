"""Dynamic state per wheel: idle | steady | traction | braking (design §7.2; thesis eq. 8.6).

::

    a_wheel_i = a_body + (-r^2) [x_i, y_i]            (acceleration of the wheel centre; the
                                                        yaw-acceleration term is not in the state)
    a_long_i  = a_wheel_i . [cos delta_i, sin delta_i]
    Power_i   = a_long_i * v_long_i                    (m^2/s^3)

``a_body = (ax, ay)`` is the EKF's inertial acceleration of the body origin in body axes
(it already holds the centripetal term of the body's path), so on a steady arc the wheel-centre
acceleration is perpendicular to the wheel's velocity and Power is ~0 (steady).

The acceleration feeding Power is the *manoeuvre* acceleration: the EKF (or true) acceleration
through two cascaded first-order low-passes of ``MANOEUVRE_TAU_S`` = 0.3 s each (critically
damped, -3 dB near 0.34 Hz, variable-dt safe). *Departure/addition to design §7.2*: on rough
or soft ground the body shakes at 3-8 Hz with 0.05-0.4 m/s^2 rms (terrain roughness modulating
wheel loads and thrust); theta = 0.02 m^2/s^3 sits far below that, so an unfiltered Power
flips sign every few ticks and, with the dwell debounce, the state freezes in whatever state it
held last (a robot cruising on tilled soil read as "traction" for a whole run). The dynamic
state is about the manoeuvre (speeding up, slowing down, holding speed), not about vibration,
so the vibration band is filtered out first. A 1 m/s^2 start is still flagged as traction
within ~0.3 s.

Classification with hysteresis and minimum dwell (beyond the thesis):
enter traction when Power > theta, leave it when Power < theta / 2; braking symmetric;
idle when |v_long| < 0.05 m/s; a new state is taken only after it has persisted ``dwell_s``
(0.2 s, a debounce), so no state is shorter than the dwell. This is the same definition as the
simulator's truth (``terrainml.sim.truth.wheel_states`` calls this module).
"""

from __future__ import annotations

import math

import numpy as np

# state codes 0..3 (order of schema.WHEEL_STATES) and the per-tick rules, compiled (one
# implementation, shared with the online estimator's tick)
from terrainml.estimation._wheel_kernel import (BRAKING, IDLE, STEADY, TRACTION, manoeuvre_gain,  # noqa: F401
                                                manoeuvre_step, state_machine_step)

THETA_M2PS3 = 0.02
DWELL_S = 0.2
IDLE_SPEED_MPS = 0.05
MANOEUVRE_TAU_S = 0.3  # each of the two cascaded first-order low-passes on the acceleration


class ManoeuvreFilter:
    """Two cascaded first-order low-passes: vibration out, manoeuvre acceleration kept.

    ``y1 += g (a - y1); y2 += g (y1 - y2)`` with ``g = 1 - exp(-dt / tau)`` per tick, on any
    number of channels at once. The first sample initialises both stages (no start-up ramp).

    Parameters
    ----------
    tau_s : time constant of each stage (s); 0 passes the input through.
    """

    def __init__(self, tau_s: float = MANOEUVRE_TAU_S) -> None:
        self.tau_s = float(tau_s)
        self._y1: np.ndarray | None = None
        self._y2: np.ndarray | None = None
        self._p1 = np.zeros(2)  # state of the two-float path (step_pair)
        self._p2 = np.zeros(2)
        self._pa = np.zeros(2)
        self._pair_started = False
        self._t_prev = math.nan

    def step(self, t_s: float, accel) -> np.ndarray:
        """Filter one sample (any shape); returns the filtered value (copy)."""
        a = np.asarray(accel, dtype=float)
        if self._y1 is None or self.tau_s <= 0.0:
            self._y1, self._y2 = a.copy(), a.copy()
        else:
            dt = t_s - self._t_prev
            g = 1.0 - math.exp(-dt / self.tau_s) if dt > 0.0 else 0.0
            ok = np.isfinite(a)  # a non-finite sample holds the filter
            self._y1 = np.where(ok, self._y1 + g * (a - self._y1), self._y1)
            self._y2 = self._y2 + g * (self._y1 - self._y2)
        self._t_prev = t_s
        return self._y2.copy()

    def step_pair(self, t_s: float, a0: float, a1: float) -> tuple[float, float]:
        """:meth:`step` for two plain floats (the online (ax, ay) path): the same arithmetic in
        the same order (:func:`manoeuvre_step`, which the online estimator's compiled tick runs).
        An instance is used through one of the two methods, not both."""
        self._pa[0], self._pa[1] = a0, a1
        if not self._pair_started or self.tau_s <= 0.0:
            self._p1[:] = self._pa
            self._p2[:] = self._pa
            self._pair_started = True
        else:
            manoeuvre_step(self._p1, self._p2, self._pa, manoeuvre_gain(t_s - self._t_prev, self.tau_s))
        self._t_prev = t_s
        return float(self._p2[0]), float(self._p2[1])


def manoeuvre_accel(t_s, accel, tau_s: float = MANOEUVRE_TAU_S) -> np.ndarray:
    """Offline :class:`ManoeuvreFilter` over rows: ``accel`` (n_ticks, ...) sampled at ``t_s`` (n_ticks,)."""
    accel = np.asarray(accel, dtype=float)
    f = ManoeuvreFilter(tau_s)
    out = np.empty_like(accel)
    for k, t in enumerate(np.asarray(t_s, dtype=float)):
        out[k] = f.step(float(t), accel[k])
    return out


def wheel_power(ax_mps2, ay_mps2, yaw_rate_radps, steer_rad, v_long_mps, wheel_x_m, wheel_y_m):
    """Power_i = a_long_i v_long_i (m^2/s^3); broadcasts like :func:`slip.wheel_v_long`."""
    r2 = np.asarray(yaw_rate_radps)[..., None] ** 2
    a_x = np.asarray(ax_mps2)[..., None] - r2 * np.asarray(wheel_x_m)
    a_y = np.asarray(ay_mps2)[..., None] - r2 * np.asarray(wheel_y_m)
    d = np.asarray(steer_rad, dtype=float)
    a_long = a_x * np.cos(d) + a_y * np.sin(d)
    return a_long * np.asarray(v_long_mps)


class WheelStateMachine:
    """Per-tick classifier with hysteresis and minimum dwell for N wheels.

    Dwell as a debounce: a new raw state must persist for ``dwell_s`` before it is taken (the
    definition the simulator's truth calls, ``terrainml.sim.truth.wheel_states``), so no state
    is shorter than the dwell and a one-tick blip never shows. Hysteresis is relative to the
    committed state. The first tick takes its raw state at once.

    Parameters
    ----------
    n_wheels : int
    theta : Power threshold (m^2/s^3).
    dwell_s : minimum persistence of a new state before it is taken (s).
    """

    def __init__(self, n_wheels: int, theta: float = THETA_M2PS3, dwell_s: float = DWELL_S,
                 idle_speed: float = IDLE_SPEED_MPS) -> None:
        self.theta = float(theta)
        self.dwell_s = float(dwell_s)
        self.idle_speed = float(idle_speed)
        self.state = np.full(n_wheels, IDLE, dtype=np.int8)
        self.cand = np.full(n_wheels, IDLE, dtype=np.int8)
        self.cand_since = np.full(n_wheels, -math.inf)
        self.started = False

    def step(self, t_s: float, power, v_long) -> np.ndarray:
        """Advance one tick; returns the state codes (N,) (copy). Rules: :func:`state_machine_step`."""
        state_machine_step(float(t_s), np.asarray(power, dtype=float), np.asarray(v_long, dtype=float),
                           self.theta, self.dwell_s, self.idle_speed, self.started, self.state, self.cand,
                           self.cand_since)
        self.started = True
        return self.state.copy()


def classify_states(t_s, power, v_long, theta: float = THETA_M2PS3, dwell_s: float = DWELL_S,
                    idle_speed: float = IDLE_SPEED_MPS) -> np.ndarray:
    """Offline version: state codes (n_ticks, N) from Power and v_long arrays (n_ticks, N).

    Runs the same :class:`WheelStateMachine` tick by tick (the dwell makes it sequential), so
    offline and online states are identical.
    """
    power = np.atleast_2d(np.asarray(power, dtype=float))
    v_long = np.atleast_2d(np.asarray(v_long, dtype=float))
    sm = WheelStateMachine(power.shape[1], theta, dwell_s, idle_speed)
    out = np.empty(power.shape, dtype=np.int8)
    for k, t in enumerate(np.asarray(t_s, dtype=float)):
        out[k] = sm.step(t, power[k], v_long[k])
    return out
