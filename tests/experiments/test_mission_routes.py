"""Route follower: reaches each waypoint, stops there for the stop time, ramps or steps; nominal
time by hand. The robot here is an ideal kinematic one (it moves exactly as commanded)."""

from __future__ import annotations

import math

import pytest

from terrainml.experiments.mission_routes import Route, RouteFollower, Waypoint, leg_time_s


def _drive(route: Route, t_max: float = 60.0, dt: float = 0.01, slow: float = 1.0):
    """Integrate an ideal robot (speed = ``slow`` x command); return times, positions, commands."""
    f = RouteFollower(route)
    x = y = yaw = 0.0
    ts, xs, vs = [], [], []
    t = 0.0
    while t < t_max and not f.done:
        vx, vy, r = f(t, x, y, yaw)
        assert f(t, x, y, yaw) == (vx, vy, r)         # a second call in the same tick: cached
        x += slow * (vx * math.cos(yaw) - vy * math.sin(yaw)) * dt
        y += slow * (vx * math.sin(yaw) + vy * math.cos(yaw)) * dt
        yaw += r * dt
        ts.append(t)
        xs.append(x)
        vs.append(vx)
        t = round(t + dt, 10)
    return f, ts, xs, vs


def test_leg_time_by_hand():
    # 2 m at 0.5 m/s, a = b = 0.5: 1 s up (0.25 m), 1 s down (0.25 m), 1.5 m cruise in 3 s -> 5 s
    assert leg_time_s(2.0, 0.5, 0.5, 0.5) == pytest.approx(5.0)
    # step start: no ramp, 1.75 m cruise (3.5 s) + 1 s braking -> 4.5 s
    assert leg_time_s(2.0, 0.5, math.inf, 0.5) == pytest.approx(4.5)
    # too short to reach cruise: 0.2 m with a = b = 0.5 peaks at sqrt(0.2 * 0.5) = 0.316 m/s
    assert leg_time_s(0.2, 0.5, 0.5, 0.5) == pytest.approx(2 * math.sqrt(0.1) / 0.5)


def test_nominal_time_sums_legs_and_stops():
    r = Route((Waypoint(0), Waypoint(2.0, 0, 3.0), Waypoint(4.0, 0, 0.0)), 0.5)
    assert r.nominal_time_s() == pytest.approx(5.0 + 3.0 + 5.0)
    assert r.length_m == pytest.approx(4.0)


def test_reaches_waypoints_and_stops_for_the_stop_time():
    r = Route((Waypoint(0), Waypoint(1.5, 0, 3.0), Waypoint(3.0, 0, 3.0), Waypoint(4.0, 0, 0.0)), 0.5,
              start="ramp", accel_mps2=0.5, decel_mps2=0.5)
    f, ts, xs, vs = _drive(r)
    assert f.done and len(f.arrivals_s) == 3
    # each arrival within the tolerance of its waypoint
    for t_arr, wp in zip(f.arrivals_s, r.waypoints[1:]):
        k = ts.index(t_arr)
        assert abs(xs[k - 1] - wp.x_m) <= f.tol_m + 1e-6
    # the command is 0 for the stop time after the first two arrivals, then it moves again
    for t_arr in f.arrivals_s[:2]:
        k0 = ts.index(t_arr)
        stopped = [v for t, v in zip(ts, vs) if t_arr <= t < t_arr + 3.0 - 1e-9]
        assert stopped and max(abs(v) for v in stopped) == 0.0
        assert ts[k0 + len(stopped)] == pytest.approx(t_arr + 3.0)
    # ideal robot: done at the nominal time, less up to sqrt(2 tol / a) = 0.35 s per leg (the
    # follower stops braking 3 cm early), plus the creep at 0.05 m/s
    t_route = f.t_done_s - r.start_delay_s
    assert r.nominal_time_s() - 3 * 0.35 - 0.05 <= t_route <= r.nominal_time_s() + 0.1


def test_ramp_versus_step_start():
    wps = (Waypoint(0), Waypoint(2.0))
    _, ts, _, v_ramp = _drive(Route(wps, 0.5, start="ramp", accel_mps2=0.5))
    _, _, _, v_step = _drive(Route(wps, 0.5, start="step"))
    k = ts.index(0.6)                   # 0.1 s after the 0.5 s start delay
    assert v_ramp[k] == pytest.approx(0.5 * 0.1, abs=0.006)
    assert v_step[ts.index(0.5)] == pytest.approx(0.5)


def test_time_is_free_a_slow_robot_takes_longer_not_shorter():
    r = Route((Waypoint(0), Waypoint(3.0)), 0.5)
    f_fast, _, x_fast, _ = _drive(r)
    f_slow, _, x_slow, _ = _drive(r, slow=0.5)
    assert f_fast.done and f_slow.done
    assert x_slow[-1] == pytest.approx(x_fast[-1], abs=0.01)
    assert f_slow.t_done_s > 1.5 * f_fast.t_done_s


def test_cross_track_and_heading_corrected():
    r = Route((Waypoint(0), Waypoint(3.0)), 0.5)
    f = RouteFollower(r)
    vx, vy, yr = f(1.0, 0.5, 0.2, 0.1)     # left of the line, nose left
    assert vy < 0 and yr < 0


def test_bad_routes_refused():
    with pytest.raises(ValueError):
        Route((Waypoint(0),), 0.5)
    with pytest.raises(ValueError):
        Route((Waypoint(0), Waypoint(1)), 0.5, start="jump")
