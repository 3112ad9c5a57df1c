"""Driving scenarios: body-twist commands over time plus the terrain layout (design §6).

A :class:`Scenario` gives the commanded twist (vx, vy in body axes, yaw rate) as a function of time
and, for path following, of the true pose. Open-loop scenarios are precomputed at 100 Hz with a
1 m/s^2 acceleration limit (thesis §7.2.3 test protocol); ``patch_map`` follows a circle on the
9 x 9 m map with a simple pose-feedback law.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from terrainml.classes import N_CLASSES, class_id
from terrainml.sim.terrain import TerrainLayout

SCENARIOS = ("straight", "omni", "arc", "reversal", "stop_and_go", "mixed", "patch_map",
             "course_stop_and_go")
# scenarios drawn for labelled single-terrain runs (sim generate --runs-per-class)
LABELLED_SCENARIOS = ("straight", "omni", "arc", "reversal", "stop_and_go")
CMD_RATE_HZ = 100.0


@dataclass
class Scenario:
    """What to drive and where. ``command(t_s, x_m, y_m, yaw_rad) -> (vx, vy, yaw_rate)``."""

    name: str
    duration_s: float
    layout: TerrainLayout
    command: Callable[[float, float, float, float], tuple[float, float, float]]
    info: dict = field(default_factory=dict)


def _rate_limited(targets: np.ndarray, accel: np.ndarray, dt: float) -> np.ndarray:
    """Rate-limit each column of ``targets`` (n, 3) with per-column limits ``accel`` (3,)."""
    out = np.empty_like(targets)
    cur = np.zeros(targets.shape[1])
    step = accel * dt
    for k in range(len(targets)):
        cur = cur + np.clip(targets[k] - cur, -step, step)
        out[k] = cur
    return out


def _table_command(cmd: np.ndarray) -> Callable:
    n = len(cmd)

    def command(t_s: float, x_m: float = 0.0, y_m: float = 0.0, yaw_rad: float = 0.0):
        k = min(max(int(t_s * CMD_RATE_HZ + 1e-9), 0), n - 1)
        return float(cmd[k, 0]), float(cmd[k, 1]), float(cmd[k, 2])

    command.table = cmd  # type: ignore[attr-defined]
    return command


def _profile(segments: list[tuple[float, float, float, float]], duration_s: float,
             accel_mps2: float = 1.0, yaw_accel: float = 1.0) -> np.ndarray:
    """Segments (t_start, vx, vy, r) -> rate-limited (n, 3) command table at 100 Hz."""
    n = int(round(duration_s * CMD_RATE_HZ)) + 1
    t = np.arange(n) / CMD_RATE_HZ
    tgt = np.zeros((n, 3))
    for t0, vx, vy, r in segments:
        tgt[t >= t0] = (vx, vy, r)
    return _rate_limited(tgt, np.array([accel_mps2, accel_mps2, yaw_accel]), 1.0 / CMD_RATE_HZ)


def straight(terrain, speed_mps: float = 1.0, duration_s: float = 30.0, *, brake: bool = True,
             brake_decel_mps2: float = 1.0, start_s: float = 0.5) -> Scenario:
    """1 m/s^2 start to ``speed_mps``, hold, and (``brake``) stop before the end."""
    segs = [(start_s, speed_mps, 0.0, 0.0)]
    if brake:
        t_brake = max(start_s + 2.0, duration_s - abs(speed_mps) / 1.0 - 1.5)
        segs.append((t_brake, 0.0, 0.0, 0.0))
    cmd = _profile(segs, duration_s, accel_mps2=1.0)
    if brake and brake_decel_mps2 != 1.0:
        cmd = _profile(segs, duration_s, accel_mps2=1.0)
        t = np.arange(len(cmd)) / CMD_RATE_HZ
        k0 = np.searchsorted(t, segs[-1][0])
        v0 = cmd[k0, 0]
        cmd[k0:, 0] = np.maximum(v0 - brake_decel_mps2 * (t[k0:] - t[k0]), 0.0) * np.sign(speed_mps)
    return Scenario("straight", duration_s, TerrainLayout.uniform(terrain), _table_command(cmd),
                    {"speed_mps": speed_mps, "brake": brake})


def omni(terrain, speed_mps: float, duration_s: float, rng: np.random.Generator) -> Scenario:
    """Translations in random directions (heading fixed), with stops between them."""
    segs, t = [], 0.5
    while t < duration_s - 4.0:
        theta = rng.uniform(-np.pi, np.pi)
        hold = rng.uniform(6.0, 12.0)
        segs.append((t, speed_mps * np.cos(theta), speed_mps * np.sin(theta), 0.0))
        segs.append((t + hold, 0.0, 0.0, 0.0))
        t += hold + speed_mps + rng.uniform(1.0, 2.0)
    cmd = _profile(segs, duration_s)
    return Scenario("omni", duration_s, TerrainLayout.uniform(terrain), _table_command(cmd))


def arc(terrain, speed_mps: float, duration_s: float, rng: np.random.Generator) -> Scenario:
    """Arcs of radius 2-5 m, alternating left and right."""
    segs, t, side = [(0.5, speed_mps, 0.0, 0.0)], 3.0, rng.choice([-1.0, 1.0])
    while t < duration_s - 3.0:
        radius = rng.uniform(2.0, 5.0)
        hold = rng.uniform(6.0, 12.0)
        segs.append((t, speed_mps, 0.0, side * speed_mps / radius))
        t += hold
        side = -side
    segs.append((duration_s - speed_mps - 1.5, 0.0, 0.0, 0.0))
    cmd = _profile(segs, duration_s, yaw_accel=0.5)
    return Scenario("arc", duration_s, TerrainLayout.uniform(terrain), _table_command(cmd))


def reversal(terrain, speed_mps: float, duration_s: float, rng: np.random.Generator) -> Scenario:
    """Forward and backward legs of 5-10 s."""
    segs, t, sign = [], 0.5, 1.0
    while t < duration_s - 3.0:
        hold = rng.uniform(5.0, 10.0)
        segs.append((t, sign * speed_mps, 0.0, 0.0))
        t += hold
        sign = -sign
    segs.append((duration_s - speed_mps - 1.5, 0.0, 0.0, 0.0))
    cmd = _profile(segs, duration_s)
    return Scenario("reversal", duration_s, TerrainLayout.uniform(terrain), _table_command(cmd))


def stop_and_go(terrain, speed_mps: float, duration_s: float, rng: np.random.Generator) -> Scenario:
    """Drive 3-6 s, stop 1-2 s, repeat."""
    segs, t = [], 0.5
    while t < duration_s - 3.0:
        go = rng.uniform(3.0, 6.0)
        segs.append((t, speed_mps, 0.0, 0.0))
        segs.append((t + go, 0.0, 0.0, 0.0))
        t += go + speed_mps + rng.uniform(1.0, 2.0)
    cmd = _profile(segs, duration_s)
    return Scenario("stop_and_go", duration_s, TerrainLayout.uniform(terrain), _table_command(cmd))


def mixed(speed_mps: float, duration_s: float, rng: np.random.Generator, terrains=None,
          segment_m: float | None = None) -> Scenario:
    """Straight course over segments of different terrain (transitions for stream tests)."""
    if terrains is None:
        n_seg = 5
        terrains = [int(rng.integers(N_CLASSES))]
        while len(terrains) < n_seg:
            c = int(rng.integers(N_CLASSES))
            if c != terrains[-1]:
                terrains.append(c)
    terrains = [class_id(t) for t in terrains]
    if segment_m is None:
        segment_m = max(2.0, 0.7 * speed_mps * duration_s / len(terrains))
    layout = TerrainLayout.course(terrains, segment_m, start_x_m=-1.0)
    cmd = _profile([(0.5, speed_mps, 0.0, 0.0), (duration_s - speed_mps - 1.5, 0.0, 0.0, 0.0)], duration_s)
    return Scenario("mixed", duration_s, layout, _table_command(cmd),
                    {"terrains": terrains, "segment_m": segment_m})


def patch_map(speed_mps: float, duration_s: float, rng: np.random.Generator, grid=None,
              radius_m: float = 3.0) -> Scenario:
    """9 x 9 m map of 3 x 3 m patches; the robot laps a circle of ``radius_m`` about the map centre.

    The robot starts at world (0, 0) heading +x on the circle's lowest point; the circle's centre is
    (0, radius_m), the map spans x in [-4.5, 4.5], y in [radius_m - 4.5, radius_m + 4.5].
    """
    if grid is None:
        grid = rng.integers(0, N_CLASSES, size=(3, 3)).tolist()
    layout = TerrainLayout.patches(grid, 3.0, (-4.5, radius_m - 4.5))
    cx, cy = 0.0, radius_m

    def command(t_s: float, x_m: float = 0.0, y_m: float = 0.0, yaw_rad: float = 0.0):
        v = min(speed_mps, max(t_s - 0.5, 0.0) * 1.0)
        dx, dy = x_m - cx, y_m - cy
        dist = np.hypot(dx, dy)
        e_r = dist - radius_m                          # > 0 outside
        tangent = np.arctan2(dy, dx) + np.pi / 2       # counter-clockwise
        e_h = np.pi - np.mod(np.pi - (tangent - yaw_rad), 2 * np.pi)
        r = v / radius_m + 1.5 * e_h + 1.0 * e_r * (v > 0)
        return float(v), 0.0, float(r) if v > 0 else 0.0

    return Scenario("patch_map", duration_s, layout, command, {"grid": grid, "radius_m": radius_m})


# --------------------------------------------------------------------------- course, stop-and-go
# Mixed-terrain courses driven stop-and-go (design §6): today's ``mixed`` course
# (straight segments of different terrain, TerrainLayout.course) driven the way a field robot
# works: legs of 1-4 m, stops of 1-3 s, each start either ramped (1 m/s^2, thesis §7.2.3) or a
# step (5 m/s^2 commanded: the wheels' own limit does the rest). Legs are sized by distance, the
# segment length is chosen so the course crosses every terrain of the list, and every draw comes
# from the scenario's random generator, so a seed gives the same course every time.

LEG_M = (1.0, 4.0)      # leg length range, m
STOP_S = (1.0, 3.0)     # stop duration range, s
RAMP_MPS2 = 1.0         # ramped start and every stop: 1 m/s^2
STEP_MPS2 = 5.0         # step start: as fast as the command allows (the wheels limit the rest)
START_S = 0.5           # the first leg starts here (the estimator settles at rest)


def _draw_terrains(rng: np.random.Generator, n: int) -> list[int]:
    """n classes, no two consecutive alike."""
    out = [int(rng.integers(N_CLASSES))]
    while len(out) < n:
        c = int(rng.integers(N_CLASSES))
        if c != out[-1]:
            out.append(c)
    return out


def _command_table(speed_mps: float, duration_s: float,
                   rng: np.random.Generator) -> tuple[np.ndarray, int]:
    """(n, 3) command table at 100 Hz for legs and stops; the number of legs."""
    n = int(round(duration_s * CMD_RATE_HZ)) + 1
    dt = 1.0 / CMD_RATE_HZ
    target = np.zeros(n)
    accel = np.full(n, RAMP_MPS2)
    t, legs = START_S, 0
    v = abs(float(speed_mps))
    while t < duration_s - 2.0:
        go_s = rng.uniform(*LEG_M) / v
        step = bool(rng.random() < 0.5)
        k0, k1 = int(round(t * CMD_RATE_HZ)), int(round((t + go_s) * CMD_RATE_HZ))
        target[k0:k1] = float(speed_mps)
        accel[k0:k0 + int(round(v / RAMP_MPS2 * CMD_RATE_HZ)) + 1] = STEP_MPS2 if step else RAMP_MPS2
        legs += 1
        t += go_s + v / RAMP_MPS2 + rng.uniform(*STOP_S)  # decelerate, then stand still
    cmd = np.zeros((n, 3))
    cur = 0.0
    for k in range(n):
        cur += float(np.clip(target[k] - cur, -accel[k] * dt, accel[k] * dt))
        cmd[k, 0] = cur
    return cmd, legs


def course_stop_and_go(speed_mps: float, duration_s: float, rng: np.random.Generator,
                       terrains=None, segment_m: float | None = None) -> Scenario:
    """A mixed-terrain course driven stop-and-go.

    Parameters
    ----------
    speed_mps : commanded leg speed, m/s.
    duration_s : run length, s.
    rng : the scenario's random generator (terrains, legs, stops, start kinds).
    terrains : class ids or names along the course (default 5 drawn, no two consecutive alike).
    segment_m : length of each terrain segment, m (default: the commanded distance split so that
        every terrain is crossed, at least 2 m).

    Returns
    -------
    Scenario ``course_stop_and_go`` with ``info``: ``terrains``, ``segment_m``, ``legs``,
    ``distance_m`` (commanded).
    """
    terrains = _draw_terrains(rng, 5) if terrains is None else [class_id(c) for c in terrains]
    cmd, legs = _command_table(speed_mps, duration_s, rng)
    distance_m = float(np.sum(np.abs(cmd[:, 0])) / CMD_RATE_HZ)
    if segment_m is None:
        # wheels slip and soils slow the robot: leave ~20% margin so the last terrain is reached
        segment_m = max(2.0, 0.8 * distance_m / len(terrains))
    layout = TerrainLayout.course(terrains, segment_m, start_x_m=-1.0)
    return Scenario("course_stop_and_go", duration_s, layout, _table_command(cmd),
                    {"terrains": terrains, "segment_m": segment_m, "legs": legs,
                     "distance_m": distance_m})


def make_scenario(name: str, terrain=0, *, speed_mps: float = 1.0, duration_s: float = 60.0,
                  rng: np.random.Generator | None = None, **kw) -> Scenario:
    """Build a scenario by name (one of :data:`SCENARIOS`)."""
    rng = rng if rng is not None else np.random.default_rng(0)
    if name == "straight":
        return straight(terrain, speed_mps, duration_s, **kw)
    if name == "omni":
        return omni(terrain, speed_mps, duration_s, rng)
    if name == "arc":
        return arc(terrain, speed_mps, duration_s, rng)
    if name == "reversal":
        return reversal(terrain, speed_mps, duration_s, rng)
    if name == "stop_and_go":
        return stop_and_go(terrain, speed_mps, duration_s, rng)
    if name == "mixed":
        return mixed(speed_mps, duration_s, rng, **kw)
    if name == "course_stop_and_go":
        return course_stop_and_go(speed_mps, duration_s, rng, **kw)
    if name == "patch_map":
        return patch_map(speed_mps, duration_s, rng, **kw)
    raise ValueError(f"unknown scenario {name!r}; expected one of: {', '.join(SCENARIOS)}")
