"""Position-based routes for the mission suite: waypoints with stops and a route follower (design §6, §12).

A :class:`Route` is a polyline of :class:`Waypoint` (world frame, m) with a stop duration at each
waypoint, a cruise speed and a start type. A :class:`RouteFollower` turns it into the body-twist
command of :class:`terrainml.sim.scenarios.Scenario` from the robot's *true pose*
(``command(t_s, x_m, y_m, yaw_rad) -> (vx, vy, yaw_rate)``), so time is free: a robot that slips
more takes longer to reach the next waypoint; it never skips distance.

Follower law, per leg from waypoint i to i + 1 (unit direction u, left normal n):

* progress p = (P - W_i) . u, remaining d = |W_{i+1} - W_i| - p, cross-track e = (P - W_i) . n;
* speed target v* = min(v_cruise, max(sqrt(2 a_dec max(d - tol, 0)), v_creep)) (a braking profile
  that ends at the waypoint; ``v_creep`` 0.05 m/s keeps the robot creeping on until it arrives);
* ``start="ramp"``: the speed command rises at most ``accel_mps2`` per second;
  ``start="step"``: it jumps to v* (a hard start from rest);
* world velocity v u - k_e e n, rotated into the body frame; yaw rate -k_psi (psi - heading(u));
* arrival when d <= ``tol_m`` (or the waypoint is passed): the command is 0 for the waypoint's
  ``stop_s``, then the next leg starts from rest. The route is done on arrival at the last
  waypoint after its stop. The tolerance (3 cm) ends each leg up to about
  sqrt(2 tol / a_dec) = 0.35 s before the nominal profile of :meth:`Route.nominal_time_s`.

The follower keeps state (leg, phase, speed command) and is called more than once per control tick
(the simulator and the closed-loop hook both ask for the tick's command), so a repeated call at the
same ``t_s`` returns the cached command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["START_TYPES", "Route", "RouteFollower", "Waypoint", "leg_time_s"]

START_TYPES = ("ramp", "step")


@dataclass(frozen=True)
class Waypoint:
    """A point of a route (world frame, m) and how long to stop there on arrival (s)."""

    x_m: float
    y_m: float = 0.0
    stop_s: float = 0.0


@dataclass(frozen=True)
class Route:
    """Waypoints (the first is the start position), cruise speed and start type.

    Parameters
    ----------
    waypoints : at least two; ``waypoints[0].stop_s`` is ignored (the route starts there).
    speed_mps : cruise speed command, m/s (> 0).
    start : ``"ramp"`` (speed command rate-limited by ``accel_mps2``) or ``"step"``.
    accel_mps2 : ramped-start acceleration, m/s^2.
    decel_mps2 : braking-profile deceleration towards each waypoint, m/s^2.
    start_delay_s : time at rest before the first leg, s.
    """

    waypoints: tuple[Waypoint, ...]
    speed_mps: float
    start: str = "ramp"
    accel_mps2: float = 0.5
    decel_mps2: float = 0.5
    start_delay_s: float = 0.5

    def __post_init__(self) -> None:
        if len(self.waypoints) < 2:
            raise ValueError("a route needs at least two waypoints")
        if self.start not in START_TYPES:
            raise ValueError(f"start must be one of {', '.join(START_TYPES)}, got {self.start!r}")
        if not (self.speed_mps > 0 and self.accel_mps2 > 0 and self.decel_mps2 > 0):
            raise ValueError("speed_mps, accel_mps2 and decel_mps2 must be > 0")

    @property
    def leg_lengths_m(self) -> np.ndarray:
        xy = np.array([(w.x_m, w.y_m) for w in self.waypoints])
        return np.hypot(*np.diff(xy, axis=0).T)

    @property
    def length_m(self) -> float:
        return float(self.leg_lengths_m.sum())

    @property
    def stops_s(self) -> np.ndarray:
        """Stop duration at the end of each leg, s (n_legs,)."""
        return np.array([w.stop_s for w in self.waypoints[1:]], dtype=float)

    def nominal_time_s(self) -> float:
        """Route time of a robot that follows the command exactly (no slip, no lag), s.

        Sum over legs of :func:`leg_time_s` plus the stops; the start delay is not included
        (mission times are counted from the end of the start delay).
        """
        acc = math.inf if self.start == "step" else self.accel_mps2
        legs = sum(leg_time_s(d, self.speed_mps, acc, self.decel_mps2) for d in self.leg_lengths_m)
        return float(legs + self.stops_s.sum())


def leg_time_s(length_m: float, speed_mps: float, accel_mps2: float, decel_mps2: float) -> float:
    """Time of a trapezoidal (or triangular) speed profile over ``length_m`` from rest to rest, s.

    ``accel_mps2 = inf`` is a step start. Accelerating to v takes v/a and v^2/(2a) metres, braking
    v/b and v^2/(2b) metres; the rest is cruised at v. A leg too short to reach v peaks at
    v_p = sqrt(2 d a b / (a + b)).
    """
    a, b, v, d = float(accel_mps2), float(decel_mps2), float(speed_mps), float(length_m)
    d_acc = 0.0 if math.isinf(a) else v * v / (2 * a)
    d_dec = v * v / (2 * b)
    if d_acc + d_dec <= d:
        t_acc = 0.0 if math.isinf(a) else v / a
        return t_acc + v / b + (d - d_acc - d_dec) / v
    vp = math.sqrt(2 * d * b) if math.isinf(a) else math.sqrt(2 * d * a * b / (a + b))
    return (0.0 if math.isinf(a) else vp / a) + vp / b


class RouteFollower:
    """Body-twist command from the true pose for a :class:`Route` (the law in the module docstring).

    Call as ``follower(t_s, x_m, y_m, yaw_rad) -> (vx_mps, vy_mps, yaw_rate_radps)`` (the
    :class:`~terrainml.sim.scenarios.Scenario` ``command`` signature). After the route,
    :attr:`done` is True and :attr:`t_done_s` holds the time of completion. :attr:`arrivals_s`
    lists the arrival time at each waypoint; :attr:`leg` is the current leg index.
    """

    V_CREEP_MPS = 0.05     # keeps a slow robot moving until it arrives
    K_CROSS = 1.0          # 1/s: cross-track feedback
    K_YAW = 2.0            # 1/s: heading feedback

    def __init__(self, route: Route, tol_m: float = 0.03):
        self.route = route
        self.tol_m = float(tol_m)
        xy = np.array([(w.x_m, w.y_m) for w in route.waypoints], dtype=float)
        self._xy = xy
        self._len = route.leg_lengths_m
        self.leg = 0
        self.phase = "wait"                  # wait | drive | stop | done
        self._stop_until = 0.0
        self._v_cmd = 0.0
        self._t_last: float | None = None
        self._out = (0.0, 0.0, 0.0)
        self.arrivals_s: list[float] = []
        self.t_done_s: float | None = None

    @property
    def done(self) -> bool:
        return self.phase == "done"

    @property
    def speed_command_mps(self) -> float:
        return self._v_cmd

    def progress_m(self, x_m: float, y_m: float) -> float:
        """Distance along the route of the projection of (x, y) onto the current leg, m."""
        i = min(self.leg, len(self._len) - 1)
        u = (self._xy[i + 1] - self._xy[i]) / self._len[i]
        p = float(np.dot((x_m, y_m) - self._xy[i], u))
        return float(self._len[:i].sum() + min(max(p, 0.0), self._len[i]))

    def __call__(self, t_s: float, x_m: float = 0.0, y_m: float = 0.0, yaw_rad: float = 0.0):
        t_s = float(t_s)
        if self._t_last is not None and t_s == self._t_last:
            return self._out                   # second call within the same control tick
        dt = 0.0 if self._t_last is None else max(t_s - self._t_last, 0.0)
        self._t_last = t_s
        self._out = self._command(t_s, dt, float(x_m), float(y_m), float(yaw_rad))
        return self._out

    def _command(self, t: float, dt: float, x: float, y: float, yaw: float):
        rt = self.route
        if self.phase == "wait":
            if t < rt.start_delay_s:
                return 0.0, 0.0, 0.0
            self.phase = "drive"
        if self.phase == "stop":
            if t < self._stop_until:
                return 0.0, 0.0, 0.0
            self.leg += 1
            if self.leg >= len(self._len):
                self.phase = "done"
                self.t_done_s = t
            else:
                self.phase = "drive"
        if self.phase == "done":
            return 0.0, 0.0, 0.0
        i = self.leg
        u = (self._xy[i + 1] - self._xy[i]) / self._len[i]
        nrm = np.array([-u[1], u[0]])
        rel = np.array([x, y]) - self._xy[i]
        d = self._len[i] - float(rel @ u)
        if d <= self.tol_m:                    # arrived (or passed the waypoint)
            self.arrivals_s.append(t)
            self._v_cmd = 0.0
            self.phase = "stop"
            self._stop_until = t + rt.waypoints[i + 1].stop_s
            return self._command(t, 0.0, x, y, yaw) if rt.waypoints[i + 1].stop_s <= 0 else (0.0, 0.0, 0.0)
        v_star = min(rt.speed_mps, max(math.sqrt(2 * rt.decel_mps2 * max(d - self.tol_m, 0.0)), self.V_CREEP_MPS))
        if rt.start == "ramp":
            v_star = min(v_star, self._v_cmd + rt.accel_mps2 * dt)
        self._v_cmd = v_star
        e = float(rel @ nrm)
        vw = v_star * u - self.K_CROSS * e * nrm
        c, s = math.cos(yaw), math.sin(yaw)
        vx = c * vw[0] + s * vw[1]
        vy = -s * vw[0] + c * vw[1]
        heading = math.atan2(u[1], u[0])
        err = math.remainder(yaw - heading, 2 * math.pi)
        return float(vx), float(vy), float(-self.K_YAW * err)
