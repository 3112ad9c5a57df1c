"""The mission suite: position-based missions that ask for traction (design §6, §12; docs/missions.md).

A *mission* is a route (:mod:`terrainml.experiments.mission_routes`) over a terrain map of patches
with a grade, a towed cart or a soil-engaging tool. A *suite* is families x terrains x seeds; each
mission's parameters are drawn from its seed, so a suite is a fixed list that any controller is
judged on. Two families:

``greenhouse``  a row of stop-and-go legs of 1-2 m at 0.5 m/s with 3 s stops, ramped or step
                starts, a grade of 0-3 deg (half the seeds level), a cart whose payload grows from
                0 to 40 kg in equal steps at the stops (harvest), and 0-2 soft patches of a softer
                class on the row's floor (``terrain`` is the floor).
``field``       two passes of 6-10 m at 0.8 m/s with a 3 s stop between, up a 2-8 deg grade,
                pulling a tool with a draft of 0.1-0.25 W (W the robot's weight), over 1-2 soft
                patches of 1-3 m of ``terrain`` on firmer ground (compacted dirt).

Seeds. :data:`EVAL_SEEDS` are the evaluation seeds, fixed here before any controller is tuned and
never used for tuning; :data:`TUNING_SEEDS` are for tuning. A mission's parameters and its
simulator seed derive from ``(seed, family, terrain)`` only, so every policy of a mission drives
on the same ground, and a parallel run equals a sequential one.

``demand_ratio`` = (draft + grade force) / (mu_net,peak W): the towed cart's rolling resistance
(:data:`CART_CRR_BY_CLASS` of the weakest soil) and grade force at its full payload plus the tool
draft, plus the robot's own grade force m g sin(theta), over the steady net traction peak
(:func:`terrainml.sim.mission_physics.traction_peak`, at the mean static wheel load) of the weakest
soil on the route times the robot's weight. ``demand_ratio`` uses the terrain draw of the run
(simulator truth: the median over the route's cells of a class), ``demand_ratio_nominal`` the
class nominal. Above 1 no controller can hold speed with the load up the grade.

Running a mission: :func:`run_mission` builds the simulator, attaches the policy's controller
(:mod:`terrainml.experiments.mission_policies`) through
:func:`terrainml.experiments.closed_loop.closed_loop_hook`, steps until the route is done or
2x its nominal time has passed, and computes the metrics of
:mod:`terrainml.experiments.mission_metrics`.
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
from joblib import Parallel, delayed

from terrainml.classes import TERRAIN_CLASSES, class_id
from terrainml.experiments.closed_loop import closed_loop_hook
from terrainml.experiments.mission_metrics import TIME_FACTOR, MissionLog, mission_metrics
from terrainml.experiments.mission_policies import POLICIES, PolicyContext, make_controller
from terrainml.experiments.mission_routes import Route, RouteFollower, Waypoint
from terrainml.lookup import terramechanics as tm
from terrainml.robot import RobotSpec, reference_robot
from terrainml.sim import mission_physics as mp
from terrainml.sim import physics as ph
from terrainml.sim.scenarios import Scenario
from terrainml.sim.simulator import SimResult, Simulator
from terrainml.sim.terrain import TerrainLayout

__all__ = ["EVAL_SEEDS", "FAMILIES", "SEED_SETS", "TUNING_SEEDS", "Mission", "MissionSpec",
           "OPEN_SET_CLASSES", "build_mission", "demand_ratio", "mission_log", "open_set_suite",
           "route_peaks", "run_mission", "run_suite", "suite", "suite_counts"]

# ------------------------------------------------------------------ the suite (pre-registered)
#: Evaluation seeds, fixed before any controller is tuned; never used for tuning.
EVAL_SEEDS: tuple[int, ...] = tuple(range(1000, 1012))
#: Tuning seeds, disjoint from the evaluation seeds.
TUNING_SEEDS: tuple[int, ...] = tuple(range(5000, 5012))
SEED_SETS = {"eval": EVAL_SEEDS, "tuning": TUNING_SEEDS}

GREENHOUSE_TERRAINS = ("compacted_dirt", "tilled_loam", "dry_sand", "wet_mud")
FIELD_TERRAINS = ("short_grass", "tilled_loam", "dry_sand", "wet_mud")
FAMILIES = {"greenhouse": GREENHOUSE_TERRAINS, "field": FIELD_TERRAINS}
#: the softer class of a greenhouse floor's soft patches (mud has none softer: its patches are mud)
GREENHOUSE_SOFTER = {"compacted_dirt": "tilled_loam", "tilled_loam": "dry_sand",
                     "dry_sand": "wet_mud", "wet_mud": "wet_mud"}
FIELD_BASE = "compacted_dirt"

CELL_M = 0.25                 # terrain map resolution along the route, m
MAP_START_X_M = -1.0          # the map starts 1 m behind the start position
START_DELAY_S = 0.5
STOP_S = 3.0
GREENHOUSE_SPEED_MPS = 0.5
FIELD_SPEED_MPS = 0.8
CART_MASS_KG = 20.0           # empty greenhouse cart (assumption)
PAYLOAD_MAX_KG = 40.0
#: cart rolling-resistance coefficient on each class (assumption: small pneumatic cart wheels;
#: Marks' handbook order of magnitude, more on loose and wet soil)
CART_CRR_BY_CLASS = {"pavement": 0.015, "compacted_dirt": 0.04, "short_grass": 0.06,
                     "gravel_on_firm_soil": 0.08, "tall_damp_grass": 0.08, "tilled_loam": 0.10,
                     "dry_sand": 0.15, "wet_mud": 0.12}
PHYSICS_SPEED_LIMIT_MPS = 10.0  # a body speed above this is a diverged integration, not a robot


@dataclass(frozen=True)
class MissionSpec:
    """One entry of a suite: everything else is drawn from these three."""

    family: str
    terrain: str
    seed: int


@dataclass
class Mission:
    """A built mission (see the module docstring). Lengths m, angles deg, masses kg.

    ``cells`` are the class names of the map's cells along x (``CELL_M`` each, from
    ``MAP_START_X_M``); ``grade_deg`` is the slope of every cell (uphill along +x);
    ``payload_kg`` is the cart payload on each leg (None: no cart); ``tool_draft_w`` the tool's
    draft in robot weights (0: no tool).
    """

    spec: MissionSpec
    route: Route
    cells: tuple[str, ...]
    patches: tuple[tuple[float, float, str], ...]     # (x_start_m, x_end_m, class)
    grade_deg: float
    payload_kg: tuple[float, ...] | None
    cart_mass_kg: float
    tool_draft_w: float
    params: dict = field(default_factory=dict)

    @property
    def layout(self) -> TerrainLayout:
        return TerrainLayout.course(self.cells, CELL_M, start_x_m=MAP_START_X_M)

    @property
    def soils(self) -> tuple[str, ...]:
        return tuple(sorted(set(self.cells), key=class_id))


def _seed_seq(spec: MissionSpec, stream: int) -> np.random.SeedSequence:
    """Stream 0 draws the mission's parameters, stream 1 seeds the simulator."""
    fam = list(FAMILIES).index(spec.family)
    return np.random.SeedSequence([int(spec.seed), fam, class_id(spec.terrain), stream])


def _rng(spec: MissionSpec, stream: int) -> np.random.Generator:
    return np.random.default_rng(_seed_seq(spec, stream))


def _cells(base: str, patches, x_end_m: float) -> tuple[str, ...]:
    n = int(math.ceil((x_end_m - MAP_START_X_M) / CELL_M))
    centres = MAP_START_X_M + (np.arange(n) + 0.5) * CELL_M
    cells = [base] * n
    for x0, x1, cls in patches:
        for k in np.flatnonzero((centres >= x0) & (centres < x1)):
            cells[int(k)] = cls
    return tuple(cells)


def _place_patches(rng, n: int, lo_m: float, hi_m: float, x_min: float, x_max: float, cls: str):
    """``n`` non-overlapping patches of length U(lo, hi) with starts in [x_min, x_max)."""
    out: list[tuple[float, float, str]] = []
    for _ in range(n):
        for _try in range(20):
            length = float(rng.uniform(lo_m, hi_m))
            x0 = float(rng.uniform(x_min, max(x_min, x_max - length)))
            if all(x0 + length <= a or x0 >= b for a, b, _ in out):
                out.append((round(x0, 3), round(x0 + length, 3), cls))
                break
    return tuple(sorted(out))


def _index(spec: MissionSpec) -> int:
    seeds = EVAL_SEEDS if spec.seed in EVAL_SEEDS else TUNING_SEEDS if spec.seed in TUNING_SEEDS else None
    return seeds.index(spec.seed) if seeds is not None else int(spec.seed)


def _greenhouse(spec: MissionSpec) -> Mission:
    rng = _rng(spec, 0)
    k = _index(spec)
    # stratified over the seeds: ramp/step x level/sloped, so every block of 4 seeds has all four
    start = ("ramp", "step")[k % 2]
    grade = 0.0 if (k // 2) % 2 == 0 else float(rng.uniform(1.0, 3.0))
    n_legs = int(rng.integers(6, 9))
    legs = rng.uniform(1.0, 2.0, n_legs)
    x = np.concatenate([[0.0], np.cumsum(legs)])
    wps = tuple(Waypoint(float(xi), 0.0, STOP_S if i < n_legs else 0.0) for i, xi in enumerate(x))
    route = Route(wps, GREENHOUSE_SPEED_MPS, start=start, accel_mps2=0.5, decel_mps2=0.5,
                  start_delay_s=START_DELAY_S)
    payload = tuple(PAYLOAD_MAX_KG * i / (n_legs - 1) for i in range(n_legs))
    soft = GREENHOUSE_SOFTER[spec.terrain]
    patches = _place_patches(rng, int(rng.integers(0, 3)), 0.5, 1.5, 0.0, float(x[-1]), soft)
    cells = _cells(spec.terrain, patches, float(x[-1]) + 2.0)
    return Mission(spec, route, cells, patches, grade, payload, CART_MASS_KG, 0.0,
                   {"start": start, "grade_deg": grade, "n_legs": n_legs, "route_m": float(x[-1]),
                    "payload_max_kg": PAYLOAD_MAX_KG, "cart_mass_kg": CART_MASS_KG,
                    "soft_class": soft, "n_patches": len(patches)})


def _field(spec: MissionSpec) -> Mission:
    rng = _rng(spec, 0)
    k = _index(spec)
    start = ("ramp", "step")[k % 2]
    grade = float(rng.uniform(2.0, 8.0))
    draft = float(rng.uniform(0.10, 0.25))
    legs = rng.uniform(6.0, 10.0, 2)
    x = np.concatenate([[0.0], np.cumsum(legs)])
    wps = (Waypoint(0.0), Waypoint(float(x[1]), 0.0, STOP_S), Waypoint(float(x[2]), 0.0, 0.0))
    route = Route(wps, FIELD_SPEED_MPS, start=start, accel_mps2=1.0, decel_mps2=1.0,
                  start_delay_s=START_DELAY_S)
    # the first patch always lies on the route's first half, so the stop may fall on soft ground
    n_p = int(rng.integers(1, 3))
    patches = _place_patches(rng, n_p, 1.0, 3.0, 1.0, float(x[-1]) - 1.0, spec.terrain)
    cells = _cells(FIELD_BASE, patches, float(x[-1]) + 2.0)
    return Mission(spec, route, cells, patches, grade, None, 0.0, draft,
                   {"start": start, "grade_deg": grade, "tool_draft_w": draft,
                    "route_m": float(x[-1]), "base_class": FIELD_BASE, "n_patches": len(patches)})


_BUILDERS: dict[str, Callable[[MissionSpec], Mission]] = {"greenhouse": _greenhouse, "field": _field}


def build_mission(spec: MissionSpec) -> Mission:
    """The mission of ``spec`` (deterministic in ``spec``)."""
    if spec.family not in FAMILIES:
        raise ValueError(f"unknown family {spec.family!r}; expected one of {', '.join(FAMILIES)}")
    if spec.terrain not in TERRAIN_CLASSES:
        raise ValueError(f"unknown terrain {spec.terrain!r}")
    return _BUILDERS[spec.family](spec)


def suite(name: str, seeds: str = "eval", limit: int | None = None) -> list[MissionSpec]:
    """The missions of suite ``name`` (a family, or ``all``) on seed set ``seeds`` (eval|tuning).

    Ordered seed-major (each seed runs every terrain), so ``limit`` keeps the terrains balanced.
    """
    names = list(FAMILIES) if name == "all" else [name]
    if any(n not in FAMILIES for n in names):
        raise ValueError(f"unknown suite {name!r}; expected one of {', '.join(FAMILIES)}, all")
    if seeds not in SEED_SETS:
        raise ValueError(f"seeds must be one of {', '.join(SEED_SETS)}, got {seeds!r}")
    specs = [MissionSpec(f, t, s) for f in names for s in SEED_SETS[seeds] for t in FAMILIES[f]]
    return specs if limit is None else specs[:max(int(limit), 0)]


#: classes the open-set suite holds out of the served model's training, one at a time
OPEN_SET_CLASSES: tuple[str, ...] = ("dry_sand", "wet_mud", "tilled_loam")


def open_set_suite(held_out: str, seeds: str = "eval", limit: int | None = None) -> list[MissionSpec]:
    """The open-set suite of ``held_out``: the missions of both families (:func:`suite` ``"all"``)
    whose ground has that class, as the base or a patch, for a model trained without it.

    The missions are the suite's own (same seeds, same draws), so a policy's open-set rows pair
    with its closed-world rows. ``limit`` keeps the first N.
    """
    if held_out not in TERRAIN_CLASSES:
        raise ValueError(f"unknown class {held_out!r}; expected one of {', '.join(TERRAIN_CLASSES)}")
    specs = [s for s in suite("all", seeds) if held_out in build_mission(s).cells]
    return specs if limit is None else specs[:max(int(limit), 0)]


def suite_counts(seeds: str = "eval") -> dict[str, dict[str, Any]]:
    """Per suite: terrains, seed set and the number of missions."""
    return {f: {"terrains": list(t), "seeds": seeds, "n_seeds": len(SEED_SETS[seeds]),
                "first_seed": SEED_SETS[seeds][0], "missions": len(suite(f, seeds))}
            for f, t in FAMILIES.items()}


# ------------------------------------------------------------------ demand ratio
def peak_mu_net(params, robot: RobotSpec) -> float:
    """Steady net traction peak mu_net of a soil at the mean static wheel load (dig-in included,
    :func:`terrainml.sim.mission_physics.traction_peak`)."""
    return mp.traction_peak(params, float(np.mean(robot.static_wheel_loads_n())), robot)[1]


def route_peaks(mission: Mission, robot: RobotSpec, cell_params=None) -> dict[str, float]:
    """Net traction peak per soil on the route: the class nominal (``cell_params`` None) or the
    median over the route's cells of that class of their drawn peaks (one draw per map cell)."""
    if cell_params is None:
        return {c: peak_mu_net(tm.nominal_params(c), robot) for c in mission.soils}
    x_end = mission.route.length_m
    out: dict[str, list[float]] = {}
    for i, (c, p) in enumerate(zip(mission.cells, cell_params)):
        x0 = MAP_START_X_M + i * CELL_M
        if x0 + CELL_M > 0.0 and x0 < x_end:
            out.setdefault(c, []).append(peak_mu_net(p, robot))
    return {c: float(np.median(v)) for c, v in out.items()}


def demand_ratio(mission: Mission, robot: RobotSpec, peaks: dict[str, float]) -> float:
    """(draft + grade force) / (mu_net,peak W) with the weakest soil on the route (module docstring).

    ``peaks``: net traction peak per soil (:func:`route_peaks`)."""
    th = math.radians(mission.grade_deg)
    w = robot.mass_kg * ph.G
    weakest = min(peaks, key=peaks.get)
    draft = mission.tool_draft_w * w
    if mission.payload_kg is not None:
        cart_kg = mission.cart_mass_kg + max(mission.payload_kg)
        draft += cart_kg * ph.G * (CART_CRR_BY_CLASS[weakest] * math.cos(th) + math.sin(th))
    grade = w * math.sin(th)
    peak = peaks[weakest]
    return float((draft + grade) / (max(peak, 1e-9) * w))


# ------------------------------------------------------------------ physics adapter
# The mission physics (grade, towed cart, tool draft, sinkage state, battery; terrainml.sim.
# mission_physics) is read through these few functions. Where the simulator in use lacks a law the
# mission needs, the row lists it under ``physics_missing`` and the metric falls back (mechanical
# energy for battery energy, instantaneous slip-sinkage) or is NaN (drawbar power): a row is
# honest about what was not modelled.
def _hitch_xyz_m(robot: RobotSpec) -> tuple[float, float, float]:
    """Hitch 0.3 m behind the rearmost wheel, on the centre of mass's y, 0.3 m high (assumption)."""
    return (min(w.x_m for w in robot.wheels) - 0.3, float(robot.com_y_m), 0.3)


def _layout(mission: Mission) -> tuple[TerrainLayout, list[str]]:
    lay = mission.layout
    if not mission.grade_deg:
        return lay, []
    if not hasattr(lay, "with_grade"):
        return lay, ["grade"]
    return lay.with_grade(slope_x_rad=math.radians(mission.grade_deg), slope_y_rad=0.0), []


def _physics_kwargs(mission: Mission, robot: RobotSpec) -> tuple[dict, list[str]]:
    """Simulator keyword arguments for the cart and the tool (where the Simulator takes them)."""
    accepted = set(inspect.signature(Simulator.__init__).parameters)
    kw: dict[str, Any] = {}
    missing: list[str] = []
    if mission.payload_kg is not None:
        if "towed" in accepted:
            kw["towed"] = mp.TowedLoad(mass_kg=mission.cart_mass_kg, crr=dict(CART_CRR_BY_CLASS),
                                       hitch_xyz_m=_hitch_xyz_m(robot), payload_kg=mission.payload_kg[0])
        else:
            missing.append("cart")
    if mission.tool_draft_w:
        if "tool_draft_n" in accepted:
            kw["tool_draft_n"] = mission.tool_draft_w * robot.mass_kg * ph.G
        else:
            missing.append("tool_draft")
    return kw, missing


def _clearance_m(robot: RobotSpec) -> float:
    c = getattr(robot, "ground_clearance_or_default_m", None)
    return float(c) if c is not None else mp.DEFAULT_GROUND_CLEARANCE_M


def _body_col(res: SimResult, name: str, rows: np.ndarray) -> np.ndarray | None:
    return res.log[rows, ph.LOG_COLS.index(name)] if name in ph.LOG_COLS else None


def mission_log(res: SimResult, follower: RouteFollower, mission: Mission) -> MissionLog:
    """The :class:`MissionLog` of a finished run at 100 Hz (the state after each control tick)."""
    rb = res.robot
    rows = np.minimum(2 * np.arange(len(res.cmd)) + 2, len(res.log) - 1)
    # a physics state that diverged (non-finite, or a body speed no robot has) ends the log
    speed_all = np.hypot(res.log[rows, ph.L_VX], res.log[rows, ph.L_VY])
    bad = np.flatnonzero(~np.isfinite(res.log[rows]).all(axis=1) | ~(speed_all < PHYSICS_SPEED_LIMIT_MPS))
    n_t = int(bad[0]) if bad.size else len(rows)
    rows = rows[:n_t]
    lg = res.log[rows]
    rw = float(rb.wheel_radius_m)
    omega = res.wblock("omega")[rows]
    tau = res.wblock("tau")[rows]
    v_long = res.wblock("v_long")[rows]
    slip = res.true_slip()[rows]
    cells = res.wblock("cell")[rows].astype(int)
    load = res.wblock("load")[rows]
    if "sinkage" in ph.WLOG:
        sink = res.wblock("sinkage")[rows]
    else:  # instantaneous slip-sinkage of the cell under each wheel (no sinkage state)
        sink = np.zeros_like(slip)
        for c in np.unique(cells):
            m = cells == c
            sink[m] = tm.sinkage_m(res.terrain.params[int(c)], load[m], slip[m], rb)
    rut = res.wblock("rut")[rows] if "rut" in ph.WLOG else np.full_like(slip, np.nan)
    thrust = res.wblock("thrust")[rows] if "thrust" in ph.WLOG else tau / rw
    speed = np.hypot(lg[:, ph.L_VX], lg[:, ph.L_VY])
    p_batt = _body_col(res, "p_batt", rows)
    dp = _body_col(res, "drawbar", rows)
    hitch = _body_col(res, "hitch", rows)
    has_load = mission.payload_kg is not None or mission.tool_draft_w > 0
    return MissionLog(
        t_s=lg[:, ph.L_T], x_m=lg[:, ph.L_X], y_m=lg[:, ph.L_Y], speed_mps=speed,
        cmd_speed_mps=np.hypot(res.cmd[:n_t, 0], res.cmd[:n_t, 1]), slip=slip, sinkage_m=sink, rut_m=rut,
        p_battery_w=p_batt if p_batt is not None else np.sum(tau * omega, axis=1),
        p_drawbar_w=dp * speed if dp is not None else np.full(n_t, np.nan),
        p_slip_w=thrust * (omega * rw - v_long),
        loaded=(hitch > 0) if hitch is not None else np.full(n_t, has_load),
        t_start_s=mission.route.start_delay_s, t_done_s=follower.t_done_s,
        nominal_time_s=mission.route.nominal_time_s(), clearance_m=_clearance_m(rb),
        extra={"cells": cells, "energy_source": "battery" if p_batt is not None else "mechanical"})


# ------------------------------------------------------------------ running
def _physics_sane(body: np.ndarray) -> bool:
    u, w = body[ph.B_U], body[ph.B_W]
    return bool(math.isfinite(body[ph.B_X]) and math.isfinite(u) and math.isfinite(w)
                and math.hypot(u, w) < PHYSICS_SPEED_LIMIT_MPS)


def run_mission(spec: MissionSpec, policy: str, *, model: str | Path | None = None,
                robot: RobotSpec | None = None, trace_every: int = 0
                ) -> dict[str, Any] | tuple[dict[str, Any], MissionLog]:
    """Drive one mission under ``policy``; return its report row (and, with ``trace_every`` > 0,
    the :class:`MissionLog` decimated to every ``trace_every``-th 100 Hz tick).

    The simulator seed and the terrain draw depend only on ``spec``.
    """
    rb = robot if robot is not None else reference_robot()
    mission = build_mission(spec)
    follower = RouteFollower(mission.route)
    duration = mission.route.start_delay_s + TIME_FACTOR * mission.route.nominal_time_s() + 1.0
    layout, missing = _layout(mission)
    scn = Scenario(f"mission_{spec.family}", duration, layout, follower,
                   {"family": spec.family, "terrain": spec.terrain, "seed": spec.seed})
    phys_kw, missing_kw = _physics_kwargs(mission, rb)
    missing += missing_kw
    sim = Simulator(scn, rb, _seed_seq(spec, 1), **phys_kw)
    ctrl = make_controller(policy, PolicyContext(rb, sim, mission, model))
    hook = None if ctrl is None else closed_loop_hook(sim, ctrl)
    leg = 0
    blew_up = False
    while not sim.done and not follower.done:
        if mission.payload_kg is not None and follower.leg != leg and "cart" not in missing:
            leg = follower.leg          # the payload grows at each stop (harvest)
            sim.set_payload_kg(mission.payload_kg[min(leg, len(mission.payload_kg) - 1)])
        sim.step(hook)
        if not _physics_sane(sim.body):
            blew_up = True              # a diverged physics state: the mission ends, failed
            break
    res = sim.result()
    log = mission_log(res, follower, mission)
    row: dict[str, Any] = {
        "family": spec.family, "terrain": spec.terrain, "seed": int(spec.seed), "policy": policy,
        **mission_metrics(log),
        "demand_ratio": demand_ratio(mission, rb, route_peaks(mission, rb, res.terrain.params)),
        "demand_ratio_nominal": demand_ratio(mission, rb, route_peaks(mission, rb)),
        "route_m": mission.route.length_m, "patches": [list(p) for p in mission.patches],
        "waypoints_x_m": [w.x_m for w in mission.route.waypoints],
        "base": mission.cells[0],
        "parameters": mission.params, "energy_source": log.extra["energy_source"],
        "physics_missing": missing, "physics_error": blew_up,
        "fallback_share": (ctrl.n_fallback / ctrl.n_ticks
                           if getattr(ctrl, "n_ticks", 0) else 0.0),
    }
    if trace_every > 0:
        return row, log.decimate(int(trace_every))
    return row


def _run_one(spec: MissionSpec, policy: str, model, robot, trace_every: int):
    return run_mission(spec, policy, model=model, robot=robot, trace_every=trace_every)


def run_suite(specs: list[MissionSpec], policy: str, *, model: str | Path | None = None,
              robot: RobotSpec | None = None, n_jobs: int = 1, trace_every: int = 0,
              progress: Callable[[int, int], None] | None = None
              ) -> tuple[list[dict[str, Any]], list[MissionLog]]:
    """Run every mission of ``specs`` under ``policy`` (joblib over missions, input order kept).

    Each mission's seed comes from its spec, so the rows do not depend on ``n_jobs``. Returns the
    rows and, with ``trace_every`` > 0, the decimated :class:`MissionLog` of each mission (else an
    empty list). ``progress(done, total)`` is called after each mission.
    """
    rb = robot if robot is not None else reference_robot()
    if policy not in POLICIES:
        raise ValueError(f"unknown policy {policy!r}; expected one of {', '.join(POLICIES)}")
    calls = (delayed(_run_one)(s, policy, model, rb, trace_every) for s in specs)
    rows, traces = [], []
    for k, out in enumerate(Parallel(n_jobs=n_jobs, return_as="generator")(calls), start=1):
        row, trace = out if trace_every > 0 else (out, None)
        rows.append(row)
        if trace is not None:
            traces.append(trace)
        if progress is not None:
            progress(k, len(specs))
    return rows, traces
