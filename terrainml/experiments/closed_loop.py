"""Closed-loop traction-control experiment in the simulator (design §12, beyond the thesis).

The harness builds a straight-run scenario on one terrain, runs the :class:`Simulator` with a
:class:`terrainml.control.traction.SlipController` in its control hook and reports energy per
metre, mean speed, mean tractive efficiency and stuck events. The controller is the robot-side
code (it only sees measured samples); this module is the only place that knows both.

Each control tick (100 Hz) the hook's sample is the simulator's measured sample plus the
low-level wheel-speed set-points ``wheel{i}_cmd_omega_radps`` (design §5 optional column; what a
robot's traction controller reads from its own kinematic layer) and the commanded twist
``cmd_vx_mps``, ``cmd_vy_mps``, ``cmd_yaw_rate_radps``. They are computed exactly as
:meth:`Simulator.step` computes them for the same tick (scenario command + inverse kinematics
from the previous steering set-points).

Report keys: ``energy_j_per_m`` (mechanical energy delivered at the wheels, the integral of
``tau omega`` summed over wheels with regeneration counted negative, J, over the distance the
robot's origin travelled, m), ``mean_speed_mps`` (distance / duration), ``mean_tractive_efficiency``
(time mean over driving ticks of ``eta = (DP/H)(1 - s)`` per wheel with H > 0, from the
terramechanics model of the cell under each wheel at its true load and slip), ``stuck_events``
(the simulator's count: commanded >= 0.2 m/s but true speed < 20% of it for 1 s), plus
``cruise_true_slip`` (mean true slip over wheels while the command is at cruise and the robot
moves) and ``fallback_fraction`` (predictor ticks served from the fallback row).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from terrainml.classes import class_id
from terrainml.control.pid import SlipPIDConfig
from terrainml.control.slip_limiter import SlipLimiterConfig
from terrainml.control.traction import POLICIES, ControlSettings, SlipController
from terrainml.lookup import terramechanics as tm
from terrainml.robot import RobotSpec, reference_robot
from terrainml.schema import wheel_col
from terrainml.sim import physics as ph
from terrainml.sim.control import inverse_kinematics
from terrainml.sim.scenarios import Scenario, make_scenario
from terrainml.sim.simulator import SimResult, Simulator
from terrainml.sim.terrain import TerrainLayout

__all__ = ["POLICIES", "SCENARIOS", "ClosedLoopControl", "closed_loop_hook", "cruise_true_slip", "run_closed_loop",
           "simulate_closed_loop", "step_stop_and_go", "tractive_efficiency"]


def closed_loop_hook(sim: Simulator, controller: Callable[[dict], Any]) -> Callable[[dict], Any]:
    """Wrap ``controller`` so that its sample also carries the tick's low-level set-points."""
    rb = sim.robot
    n = rb.n_wheels
    keys = [wheel_col("cmd_omega", i) for i in range(1, n + 1)]

    def hook(sample: dict) -> Any:
        b = sim.body
        vx, vy, r = sim.scenario.command(sim.t_s, b[ph.B_X], b[ph.B_Y], b[ph.B_PSI])
        omega, _ = inverse_kinematics(vx, vy, r, sim.wx, sim.wy, rb.wheel_radius_m,
                                      sim.delta_cmd, sim.steerable)
        s = dict(sample)
        s.update(zip(keys, (float(w) for w in omega)))
        s.update(cmd_vx_mps=float(vx), cmd_vy_mps=float(vy), cmd_yaw_rate_radps=float(r))
        return controller(s)

    return hook


def tractive_efficiency(res: SimResult) -> float:
    """Time mean of eta = (DP/H)(1 - s) over wheels in traction (H > 0, moving >= 0.2 m/s)."""
    rb = res.robot
    rows = np.arange(0, len(res.log), 10)  # 20 Hz is plenty for a mean
    slip = res.true_slip()[rows]
    load = res.wblock("load")[rows]
    cell = res.wblock("cell")[rows].astype(int)
    v = res.wblock("v_long")[rows]
    etas = []
    for c in np.unique(cell):
        p = res.terrain.params[int(c)]
        for i in range(rb.n_wheels):
            m = (cell[:, i] == c) & (v[:, i] >= 0.2) & (slip[:, i] > 0) & (load[:, i] > 0)
            for s_k, w_k in zip(slip[m, i], load[m, i]):
                h = float(tm.gross_thrust_n(p, float(w_k), float(s_k), rb))
                if h <= 0:
                    continue
                r = float(tm.motion_resistance_n(p, float(w_k), float(s_k), rb))
                etas.append(max(0.0, (h - r) / h) * (1.0 - s_k))
    return float(np.mean(etas)) if etas else 0.0


def cruise_true_slip(res: SimResult) -> float:
    """Mean true slip over wheels while the command is at its maximum and the robot moves."""
    cmd = np.hypot(res.cmd[:, 0], res.cmd[:, 1])
    if cmd.size == 0 or cmd.max() <= 0:
        return 0.0
    ticks = np.flatnonzero(cmd >= 0.999 * cmd.max())
    rows = np.minimum(2 * ticks + 2, len(res.log) - 1)
    moving = np.hypot(res.log[rows, ph.L_VX], res.log[rows, ph.L_VY]) > 0.05
    rows = rows[moving]
    return float(res.true_slip()[rows].mean()) if rows.size else float("nan")


def step_stop_and_go(terrain: str | int, speed_mps: float = 1.0, duration_s: float = 30.0,
                     go_s: float = 4.0, stop_s: float = 2.0) -> Scenario:
    """Harsh-start scenario: the speed command *steps* (no acceleration limit) to ``speed_mps``
    for ``go_s``, then to 0 for ``stop_s``, repeated; one terrain. Unlike the 1 m/s^2 ramps of
    :mod:`terrainml.sim.scenarios`, a step asks for more traction than soft soil has, so the
    wheels spin up past the traction peak at every start."""
    period = go_s + stop_s

    def command(t_s: float, x_m: float = 0.0, y_m: float = 0.0, yaw_rad: float = 0.0):
        on = t_s >= 0.5 and ((t_s - 0.5) % period) < go_s and t_s < duration_s - 1.0
        return (float(speed_mps) if on else 0.0), 0.0, 0.0

    return Scenario("step_stop_and_go", float(duration_s), TerrainLayout.uniform(class_id(terrain)),
                    command, {"speed_mps": speed_mps, "go_s": go_s, "stop_s": stop_s})


SCENARIOS = ("straight", "step_stop_and_go")


@dataclass(frozen=True)
class ClosedLoopControl:
    """The slip controller of a closed-loop run, as :class:`~terrainml.control.traction.SlipController`
    takes it.

    Attributes
    ----------
    model : model directory of the terrain-aware policy (None: the oracle class).
    law : ``"limiter"`` or ``"pid"`` (None: the limiter unless ``pid`` is given).
    pid : SlipPIDConfig of the slip PID (None: :func:`~terrainml.control.traction.tuned_config`).
    limiter : SlipLimiterConfig (None: :func:`~terrainml.control.traction.limiter_config`).
    steady_target : ``"peak"`` or the table's steady target, as the controller takes it.
    """

    model: str | Path | None = None
    law: str | None = None
    pid: SlipPIDConfig | None = None
    limiter: SlipLimiterConfig | None = None
    steady_target: str = "peak"


def run_closed_loop(terrain: str | int, policy: str, *, control: ClosedLoopControl | None = None,
                    duration_s: float = 60.0, seed: int = 0, speed_mps: float = 1.0,
                    robot: RobotSpec | None = None, scenario: str = "straight",
                    progress: Callable[[float], None] | None = None) -> dict[str, Any]:
    """Simulate one run on ``terrain`` under ``policy``; return the report dict
    (:func:`simulate_closed_loop` without the simulation result)."""
    return simulate_closed_loop(terrain, policy, control=control, duration_s=duration_s, seed=seed,
                                speed_mps=speed_mps, robot=robot, scenario=scenario, progress=progress)[0]


def simulate_closed_loop(terrain: str | int, policy: str, *, control: ClosedLoopControl | None = None,
                         duration_s: float = 60.0, seed: int = 0, speed_mps: float = 1.0,
                         robot: RobotSpec | None = None, scenario: str = "straight",
                         progress: Callable[[float], None] | None = None) -> tuple[dict[str, Any], SimResult]:
    """Simulate one run on ``terrain`` under ``policy``; return the report dict and the :class:`SimResult`.

    ``scenario``: ``"straight"`` (the default: 1 m/s^2 start, cruise, brake; design §6) or
    ``"step_stop_and_go"`` (:func:`step_stop_and_go`). ``control``: the slip controller
    (:class:`ClosedLoopControl`; by default the slip limiter, or the slip PID when it names one).
    The scenario and the terrain draw depend only on ``seed`` (derived exactly as
    :func:`terrainml.sim.generate.simulate` derives them), so the policies of one seed drive on the
    same ground. ``duration_s`` in s, ``speed_mps`` the cruise command in m/s.
    """
    control = control or ClosedLoopControl()
    if scenario not in SCENARIOS:
        raise ValueError(f"scenario must be one of {', '.join(SCENARIOS)}, got {scenario!r}")
    rb = robot if robot is not None else reference_robot()
    cid = class_id(terrain)
    ss_scn, ss_sim = np.random.SeedSequence(int(seed)).spawn(2)
    if scenario == "straight":
        scn = make_scenario("straight", cid, speed_mps=speed_mps, duration_s=duration_s,
                            rng=np.random.default_rng(ss_scn))
    else:
        scn = step_stop_and_go(cid, speed_mps, duration_s)
    sim = Simulator(scn, rb, ss_sim)
    ctrl = SlipController(rb, policy, ControlSettings(law=control.law, pid=control.pid, limiter=control.limiter,
                                                      steady_target=control.steady_target),
                          model=control.model, true_class=cid)
    hook = None if policy == "none" else closed_loop_hook(sim, ctrl)
    res = sim.run(controller=hook, progress=progress)
    dist = max(float(res.distance_m), 1e-9)
    report = {
        "terrain": int(cid), "policy": policy, "scenario": scenario, "seed": int(seed),
        "duration_s": float(duration_s),
        "speed_cmd_mps": float(speed_mps), "classifier": ctrl.classifier,
        "energy_j": float(res.energy_j), "distance_m": float(res.distance_m),
        "energy_j_per_m": float(res.energy_j) / dist,
        "mean_speed_mps": float(res.distance_m) / float(duration_s),
        "mean_tractive_efficiency": tractive_efficiency(res),
        "stuck_events": int(res.stuck_events),
        "cruise_true_slip": cruise_true_slip(res),
        "fallback_fraction": ctrl.n_fallback / ctrl.n_ticks if ctrl.n_ticks else 0.0,
    }
    return report, res
