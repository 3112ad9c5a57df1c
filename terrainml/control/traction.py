"""Traction controller: measured sample -> per-wheel wheel-speed corrections (design §12).

:class:`SlipController` is what runs on the robot (or in the simulator's closed-loop hook, see
:mod:`terrainml.experiments.closed_loop`): every control tick (100 Hz) it takes one measured sample (the
canonical run-table columns of design §5 plus ``t_s``), estimates slip, wheel states and
wheel-centre speeds with the online estimator, picks the desired slip per wheel and returns the
slip PID's output ``PID_out`` (rad/s, shape (N,)), to be added to the low-level wheel-speed
set-points: ``omega_cmd = omega_low_level + PID_out`` (eq. 8.3). It knows nothing about the
simulator.

Policies
--------
``none``           no traction control (returns None)
``fixed``          slip PID towards a fixed target: ``sgn(v_long) 0.1`` in traction and steady,
                   ``sgn(v_long) (-0.1)`` in braking (the "0.1 everywhere" baseline)
``terrain-aware``  slip PID towards the served desired slip: with ``model`` the online predictor
                   (:class:`terrainml.stream.predictor.Predictor`: EKF, windows, classifier,
                   lookup policy and fallback); without a model the class given by ``true_class``
                   / ``class_lookup`` with the lookup table (an oracle classifier)

In ``steady`` and ``idle`` wheel states the controller's threshold is, by default
(``steady_target="peak"``), the served class's *traction* target (the peak of net traction), not
the steady target s_S (steady) or 0 (idle) of design §10 (``steady_target="served"``). Reasons
(measured, docs/control.md): s_S is the slip at which the nominal soil just carries the cruise; a
run whose soil is softer than nominal needs more, so a controller held at s_S slows the robot (up
to -7% speed on wet mud) without saving energy, while slip beyond the traction peak is never
useful. And the dynamic-state estimator reports ``idle`` for ~0.3 s after a start (its manoeuvre
filter and dwell), exactly when a hard start spins the wheels up; a moving wheel (the PID's enable
rule) in ``idle`` is capped at the peak too. Departure from design §10/§12, recorded.

While the predictor serves its fallback (no class: none yet, stale, uncertain, or estimator
unhealthy) it serves the class-free **safe cap** of design §10 (the largest traction-peak slip of
the model's classes, the most negative braking target), and the controller follows it
(``on_fallback="serve"``, the default): no known class is stalled by the cap and no wheel runs
away past it. Steady and idle moving wheels are capped at the safe cap's traction target, as
they are at the served class's peak otherwise (D35). ``on_fallback="release"`` (PID_out = 0) is
the former behaviour (departure D36, retired: it existed because the fallback used to be the
least aggressive row, pavement, which stalled the robot on soft soil; design §12).

Measured slip, wheel states and v_long always come from the online estimator. The low-level
set-points ``omega_low_level`` are read from the sample's optional ``wheel{i}_cmd_omega_radps``
columns (design §5); the PID's feed-forward (``SlipPIDConfig.wheel_radius_m``) needs them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from terrainml.control.pid import SlipPID, SlipPIDConfig
from terrainml.estimation.ekf import I_VX, I_VY
from terrainml.estimation.online import OnlineEstimator
from terrainml.lookup.policy import desired_slip_per_wheel
from terrainml.lookup.table import DesiredSlipTable
from terrainml.robot import RobotSpec
from terrainml.stream.predictor import Predictor

__all__ = ["FIXED_TARGET", "ON_FALLBACK", "POLICIES", "STEADY_TARGETS", "FixedTargetTable", "SlipController",
           "tuned_config"]

POLICIES = ("none", "fixed", "terrain-aware")
STEADY_TARGETS = ("peak", "served")
ON_FALLBACK = ("release", "serve")
FIXED_TARGET = 0.1


def tuned_config(robot: RobotSpec, **overrides: Any) -> SlipPIDConfig:
    """Slip-PID settings tuned in the simulator for the reference robot (docs/control.md).

    A one-sided slip limiter (``mode="limit"``) with feed-forward of the wheel speed that gives
    the target slip at the estimated wheel-centre speed, a PI trim and a slew limit. ``overrides``
    replace single fields.
    """
    base = dict(kp=2.0, ki=10.0, kd=0.0, output_limit_radps=8.0, integral_limit_radps=2.0,
                rate_limit_radps2=40.0, wheel_radius_m=float(robot.wheel_radius_m),
                mode="limit")
    base.update(overrides)
    return SlipPIDConfig(**base)


@dataclass
class _CapAsTable:
    """The safe cap's traction target as a one-class table (for ``_steady_at_peak``)."""

    traction: float

    def target(self, class_id: int, state: str) -> float:
        return self.traction


@dataclass
class FixedTargetTable:
    """``target(c, state)``: ``value`` in traction and steady, ``-value`` in braking, any class."""

    value: float = FIXED_TARGET

    def target(self, class_id: int, state: str) -> float:
        if state == "idle":
            return 0.0
        return -self.value if state == "braking" else self.value


class SlipController:
    """Per-wheel slip control from measured samples (callable: ``ctrl(sample) -> PID_out``).

    Parameters
    ----------
    robot : RobotSpec.
    policy : one of :data:`POLICIES`.
    model : model folder for the terrain-aware policy served by the online predictor.
    true_class : class id for the oracle terrain-aware policy (no model).
    class_lookup : callable ``t_s -> class id`` (oracle on mixed terrain), overrides
        ``true_class``.
    pid : SlipPIDConfig (default :func:`tuned_config`).
    preset : EKF preset.
    table : desired-slip table for the oracle policy (default ``DesiredSlipTable.build(robot)``).
    on_fallback : with a model, what to do while the predictor serves its fallback:
        ``"serve"`` (default: limit the slip to the served safe cap, design §10) or
        ``"release"`` (no correction, the wheels follow the low-level command; the former D36).
    steady_target : ``"peak"`` (default: the class's traction target also in steady and idle
        states) or ``"served"`` (the served targets of design §10: s_S when steady, 0 when idle).
    """

    def __init__(self, robot: RobotSpec, policy: str, *, model: str | Path | None = None,
                 true_class: int | None = None, class_lookup: Callable[[float], int] | None = None,
                 pid: SlipPIDConfig | None = None, preset: str = "robust", table: Any = None,
                 steady_target: str = "peak", on_fallback: str = "serve"):
        if policy not in POLICIES:
            raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}")
        if steady_target not in STEADY_TARGETS:
            raise ValueError(f"steady_target must be one of {', '.join(STEADY_TARGETS)}, "
                             f"got {steady_target!r}")
        self.steady_target = steady_target
        if on_fallback not in ON_FALLBACK:
            raise ValueError(f"on_fallback must be one of {', '.join(ON_FALLBACK)}, "
                             f"got {on_fallback!r}")
        self.on_fallback = on_fallback
        self.robot = robot
        self.policy = policy
        self.config = pid if pid is not None else tuned_config(robot)
        self.pid = SlipPID(robot.n_wheels, self.config)
        self.predictor = None
        self.estimator = None
        self.class_lookup = class_lookup
        self.true_class = true_class
        self.table: Any = None
        if policy == "terrain-aware" and model is not None:
            self.predictor = Predictor.from_model_dir(model, robot=robot, preset=preset)
        elif policy != "none":
            self.estimator = OnlineEstimator(robot, preset, has_imu_yaw=False)
        if policy == "fixed":
            self.table = FixedTargetTable()
        elif policy == "terrain-aware" and self.predictor is None:
            self.table = table if table is not None else DesiredSlipTable.build(robot)
        n = robot.n_wheels
        self._cmd_keys = [f"wheel{i}_cmd_omega_radps" for i in range(1, n + 1)]
        self._t_prev: float | None = None
        self.n_fallback = 0
        self.n_ticks = 0
        # per-tick record for analysis: t, desired slip, measured slip, PID_out (lists)
        self.trace: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] | None = None

    @property
    def classifier(self) -> str | None:
        """``"model"``, ``"oracle"`` (terrain-aware without a model) or None."""
        if self.predictor is not None:
            return "model"
        return "oracle" if self.policy == "terrain-aware" else None

    @staticmethod
    def _prepare(sample: dict) -> dict:
        s = dict(sample)
        conf = s.get("cam_confidence")
        if conf is not None and "cam_valid" not in s:
            s["cam_valid"] = bool(np.isfinite(conf) and conf >= 2)  # as ingest does
        return s

    def _omega_low_level(self, s: dict) -> np.ndarray:
        vals = [s.get(k) for k in self._cmd_keys]
        if any(v is None for v in vals):
            if self.config.wheel_radius_m is not None:
                missing = self._cmd_keys[[v is None for v in vals].index(True)]
                raise ValueError(f"sample lacks column {missing!r}: the slip PID's feed-forward "
                                 "needs the low-level wheel-speed set-points")
            return np.zeros(self.robot.n_wheels)
        return np.array(vals, dtype=float)

    def _steady_at_peak(self, s_des: np.ndarray, states, v_long: np.ndarray, cid: int,
                        table: Any) -> np.ndarray:
        """Steady and idle wheels: the class's traction target (``steady_target="peak"``)."""
        if self.steady_target != "peak":
            return s_des
        steady = np.array([st in ("steady", "idle") for st in states]) & np.isfinite(v_long)
        if not steady.any():
            return s_des
        try:
            peak = float(table.target(int(cid), "traction"))
        except Exception:  # noqa: BLE001 - an unknown class keeps the served target
            return s_des
        return np.where(steady, np.sign(v_long) * peak, s_des)

    def __call__(self, sample: dict) -> np.ndarray | None:
        if self.policy == "none":
            return None
        s = self._prepare(sample)
        t = float(s["t_s"])
        dt = 0.01 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        n = self.robot.n_wheels
        omega_ll = self._omega_low_level(s)
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
            if msg.fallback and self.on_fallback == "release":
                self.pid.reset()
                self._trace(t, s_des, s_meas, np.zeros(n))
                return np.zeros(n)
            if msg.fallback:  # the safe cap: steady and idle moving wheels at its traction target
                s_des = self._steady_at_peak(s_des, msg.wheel_state, v_long, 0,
                                             _CapAsTable(self.predictor.safe_cap_traction()))
            else:
                s_des = self._steady_at_peak(s_des, msg.wheel_state, v_long, msg.terrain_class,
                                             self.predictor.table)
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
            s_des = self._steady_at_peak(s_des, states, v_long, cid or 0, self.table)
            s_meas = np.array([row[f"slip{i}"] for i in range(1, n + 1)], dtype=float)
            x = self.estimator.ekf.x  # type: ignore[union-attr]
            ok = bool(row["estimator_ok"])
        body = math.hypot(float(x[I_VX]), float(x[I_VY])) if ok else float("nan")
        step = self.pid.step(s_des, s_meas, v_long, body, omega_ll, dt)
        self._trace(t, s_des, s_meas, step.pid_out_radps)
        return step.pid_out_radps

    def _trace(self, t: float, s_des, s_meas, out) -> None:
        if self.trace is not None:
            self.trace.append((t, np.array(s_des, dtype=float), np.array(s_meas, dtype=float),
                               np.array(out, dtype=float)))
