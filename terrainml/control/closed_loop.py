"""Closed-loop traction control in the simulator (SYSTEM §12, beyond the thesis).

Each control tick (100 Hz) the simulator hands the measured sample (what the robot's sensors
give) to a controller, which returns per-wheel offsets added to the low-level wheel-speed
set-points (``omega_cmd = omega_low_level + PID_out``, eq. 8.3). Policies:

``none``           no traction control (offsets 0)
``fixed``          slip PID towards a fixed target: ``sgn(v_long) 0.1`` in traction and steady,
                   ``sgn(v_long) (-0.1)`` in braking (the "0.1 everywhere" baseline)
``terrain-aware``  slip PID towards the served desired slip: with ``model`` the online predictor
                   (:class:`terrainml.stream.predictor.Predictor`: EKF, windows, classifier,
                   lookup policy and fallback); without a model the true class under the robot
                   with the lookup table (an oracle classifier, reported as such)

Measured slip, wheel states and v_long always come from the online estimator (never from
simulator truth). The PID is :class:`terrainml.control.pid.SlipPID` (thesis gains by default;
``kp``/``ki`` configurable).

Report keys: ``energy_j_per_m`` (electrical-mechanical energy at the wheels, J, over distance
travelled, m), ``mean_speed_mps`` (distance / duration), ``mean_tractive_efficiency`` (time mean
over driving ticks of ``eta = (DP/H)(1 - s)`` per wheel with H > 0, from the terramechanics model
of the cell under each wheel at its true load and slip), ``stuck_events`` (the simulator's count:
commanded >= 0.2 m/s but true speed < 20% of it for 1 s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from terrainml.classes import class_id
from terrainml.control.pid import SlipPID, SlipPIDConfig
from terrainml.robot import RobotSpec, load_robot

POLICIES = ("none", "fixed", "terrain-aware")
FIXED_TARGET = 0.1


@dataclass
class _FixedTable:
    """``target(c, state)``: 0.1 in traction and steady, -0.1 in braking, for every class."""

    value: float = FIXED_TARGET

    def target(self, class_id: int, state: str) -> float:
        return -self.value if state == "braking" else self.value


class SlipController:
    """Simulator controller: measured sample -> per-wheel wheel-speed offsets (rad/s)."""

    def __init__(self, robot: RobotSpec, policy: str, *, model: str | Path | None = None,
                 true_class: int | None = None, pid: SlipPIDConfig | None = None,
                 preset: str = "robust", class_lookup: Any = None):
        if policy not in POLICIES:
            raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}")
        self.robot = robot
        self.policy = policy
        self.pid = SlipPID(robot.n_wheels, pid or SlipPIDConfig())
        self.predictor = None
        self.estimator = None
        self.class_lookup = class_lookup  # callable t_s -> true class (oracle), optional
        self.true_class = true_class
        if policy == "terrain-aware" and model is not None:
            from terrainml.stream.predictor import Predictor

            self.predictor = Predictor.from_model_dir(model, robot=robot, preset=preset)
        elif policy != "none":
            from terrainml.estimation.online import OnlineEstimator

            self.estimator = OnlineEstimator(robot, preset, has_imu_yaw=False)
        if policy == "fixed":
            self.table: Any = _FixedTable()
        elif self.predictor is None and policy == "terrain-aware":
            from terrainml.lookup.table import DesiredSlipTable

            self.table = DesiredSlipTable.build(robot)
        self._t_prev: float | None = None
        self.n_fallback = 0
        self.n_ticks = 0

    @staticmethod
    def _prepare(sample: dict) -> dict:
        s = dict(sample)
        conf = s.get("cam_confidence")
        if conf is not None and "cam_valid" not in s:
            s["cam_valid"] = bool(np.isfinite(conf) and conf >= 2)  # as ingest does
        return s

    def __call__(self, sample: dict) -> np.ndarray | None:
        if self.policy == "none":
            return None
        from terrainml.lookup.policy import desired_slip_per_wheel

        s = self._prepare(sample)
        t = float(s["t_s"])
        dt = 0.01 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        n = self.robot.n_wheels
        self.n_ticks += 1
        if self.predictor is not None:
            msg = self.predictor.step(s)
            if msg is None:
                return None
            est = self.predictor.estimator
            s_des = np.asarray(msg.slip_desired, dtype=float)
            s_meas = np.array([float(v) for v in est.slip])  # NaN when unavailable: PID disables
            self.n_fallback += int(msg.fallback)
            v_long = np.asarray(est.v_long, dtype=float)
            x = est.ekf.x
            ok = msg.estimator_ok
        else:
            row = self.estimator.step(s)  # type: ignore[union-attr]
            states = [row[f"state{i}"] for i in range(1, n + 1)]
            v_long = np.array([row[f"v_long{i}_mps"] for i in range(1, n + 1)], dtype=float)
            cid = self.true_class
            if self.class_lookup is not None:
                cid = int(self.class_lookup(t))
            s_des = np.asarray(desired_slip_per_wheel(cid or 0, states, v_long, self.table))
            s_meas = np.array([row[f"slip{i}"] for i in range(1, n + 1)], dtype=float)
            x = self.estimator.ekf.x  # type: ignore[union-attr]
            ok = bool(row["estimator_ok"])
        from terrainml.estimation.ekf import I_VX, I_VY

        body = math.hypot(float(x[I_VX]), float(x[I_VY])) if ok else float("nan")
        step = self.pid.step(s_des, s_meas, v_long, body, np.zeros(n), dt)
        return step.pid_out_radps


def tractive_efficiency(res: Any) -> float:
    """Time mean of eta = (DP/H)(1 - s) over wheels in traction (H > 0, moving >= 0.2 m/s)."""
    from terrainml.lookup import terramechanics as tm

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


def run_closed_loop(terrain: str | int, policy: str, *, model: str | Path | None = None,
                    duration_s: float = 60.0, seed: int = 0, speed_mps: float = 1.0,
                    robot: RobotSpec | str | None = None, pid: SlipPIDConfig | None = None,
                    progress: Any = None) -> dict[str, Any]:
    """Simulate one straight run on ``terrain`` under ``policy``; return the report dict."""
    from terrainml.sim.scenarios import make_scenario
    from terrainml.sim.simulator import Simulator

    rb = load_robot(robot) if not isinstance(robot, RobotSpec) else robot
    cid = class_id(terrain)
    # seeds derived exactly as terrainml.sim.generate.simulate does: same seed, same world
    ss_scn, ss_sim = np.random.SeedSequence(int(seed)).spawn(2)
    scenario = make_scenario("straight", cid, speed_mps=speed_mps, duration_s=duration_s,
                             rng=np.random.default_rng(ss_scn))
    sim = Simulator(scenario, rb, ss_sim)
    ctrl = SlipController(rb, policy, model=model, true_class=cid, pid=pid)
    res = sim.run(controller=None if policy == "none" else ctrl, progress=progress)
    dist = max(float(res.distance_m), 1e-9)
    report = {
        "terrain": int(cid), "policy": policy, "seed": int(seed), "duration_s": float(duration_s),
        "speed_cmd_mps": float(speed_mps),
        "classifier": ("model" if ctrl.predictor is not None else
                       ("oracle" if policy == "terrain-aware" else None)),
        "energy_j": float(res.energy_j), "distance_m": float(res.distance_m),
        "energy_j_per_m": float(res.energy_j) / dist,
        "mean_speed_mps": float(res.distance_m) / float(duration_s),
        "mean_tractive_efficiency": tractive_efficiency(res),
        "stuck_events": int(res.stuck_events),
        "fallback_fraction": ctrl.n_fallback / ctrl.n_ticks if ctrl.n_ticks else 0.0,
    }
    return report
