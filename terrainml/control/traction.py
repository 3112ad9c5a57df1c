"""Traction controller: measured sample -> per-wheel wheel-speed corrections (design §12).

:class:`SlipController` is what runs on the robot (or in the simulator's closed-loop hook, see
:mod:`terrainml.experiments.closed_loop`): every control tick (100 Hz) it takes one measured sample (the
canonical run-table columns of design §5 plus ``t_s``), estimates slip, wheel states and
wheel-centre speeds with the online estimator, picks the targets per wheel and returns a
per-wheel correction (rad/s, shape (N,)) to be added to the low-level wheel-speed set-points:
``omega_cmd = omega_low_level + out`` (eq. 8.3). It knows nothing about the simulator.

Control law (``law``)
---------------------
``"limiter"`` (default)  the per-wheel slip limiter
                   (:class:`terrainml.control.slip_limiter.SlipLimiter`): caps each wheel's
                   shear-displacement slip at the class's traction target s_T and floors it at the
                   braking target s_B; it keeps acting at a stall and from rest, releases smoothly
                   and never resets while driving. ``out`` is its command offset.
``"pid"``          the slip PID of thesis §8.3 (:class:`terrainml.control.pid.SlipPID`, settings
                   ``pid``, default :func:`tuned_config`); ``out`` is ``PID_out``. Kept for the
                   thesis configuration (Table 8.1) and the former ``*-pid`` mission policies.
                   Passing a ``pid`` configuration selects it (``law=None``).

Why the limiter is the default (measured, docs/control.md): the PID's enable rule (body and wheel
>= 0.05 m/s, reset when disabled) lets go exactly at a stall, and its feed-forward from a lagging
speed estimate holds a start from rest back (dry sand, seed 2: 6.2 % slower than no control).

Policies
--------
``none``           no traction control (returns None)
``fixed``          slip PID towards a fixed target: ``sgn(v_long) 0.1`` in traction and steady,
                   ``sgn(v_long) (-0.1)`` in braking (the "0.1 everywhere" baseline)
``terrain-aware``  slip PID towards the served desired slip: with ``model`` the online predictor
                   (:class:`terrainml.stream.tick.predictor.Predictor`: EKF, windows, classifier,
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

On the limiter path the targets are the served class's *pair* (s_T, s_B) per wheel, whatever
the wheel state: the limiter picks the cap or the floor from the command against the ground speed
itself, so a stalled wheel (v_long ~ 0, no sign) is still capped. ``steady_target="served"`` caps
wheels in ``steady`` at the class's s_S instead; on fallback the pair is the safe cap's
(``"serve"``) or none at all (``"release"``: the limiter lets go at its release rate, no reset).

Measured slip, wheel states and v_long always come from the online estimator. The low-level
set-points ``omega_low_level`` are read from the sample's optional ``wheel{i}_cmd_omega_radps``
columns (design §5); the limiter and the PID's feed-forward (``SlipPIDConfig.wheel_radius_m``)
need them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from terrainml.control.pid import SlipPID, SlipPIDConfig
from terrainml.control.slip_limiter import SlipLimiter, SlipLimiterConfig
from terrainml.estimation.ekf import I_VX, I_VY
from terrainml.estimation.online import OnlineEstimator
from terrainml.lookup.wheel_targets import desired_slip_per_wheel
from terrainml.lookup.table import DesiredSlipTable
from terrainml.robot import RobotSpec
from terrainml.schema import wheel_col
from terrainml.stream.tick.config import ServingConfig
from terrainml.stream.tick.policy import safe_cap_for
from terrainml.stream.tick.predictor import Predictor

__all__ = ["FIXED_TARGET", "LAWS", "ON_FALLBACK", "POLICIES", "STEADY_TARGETS", "ControlSettings",
           "FixedTargetTable",
           "SlipController", "limiter_config", "tuned_config"]

POLICIES = ("none", "fixed", "terrain-aware")
LAWS = ("limiter", "pid")
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


def limiter_config(robot: RobotSpec, **overrides: Any) -> SlipLimiterConfig:
    """Slip-limiter settings of :class:`SlipController`'s default law (docs/control.md).

    The limiter's defaults with a build-up gain ``kp_mps`` of 2.0 m/s per unit slip instead of 0.5.
    Why (measured, dry sand, seed 2, 1 m/s^2 ramp start): the wheel drive is a PI speed loop, so
    its torque needs a speed error; with 0.5 the ceiling at a start from rest (the body still at
    rest, the shear slip 0.28 of a 0.42 cap) leaves the wheel only ~0.07 m/s above the body, the
    drive's torque builds through its integrator alone and the start is delayed by ~1.3 s (-13.5 %
    mean speed, one stuck event). With 2.0 the start keeps no control's speed (-0.5 %) and the
    towed-load stall case still holds the shear slip at the peak. ``overrides`` replace fields.
    """
    base: dict[str, Any] = dict(wheel_radius_m=float(robot.wheel_radius_m), kp_mps=2.0)
    base.update(overrides)
    return SlipLimiterConfig(**base)


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


@dataclass(frozen=True)
class ControlSettings:
    """How :class:`SlipController` controls, whatever tells it the terrain.

    Attributes
    ----------
    law : one of :data:`LAWS` or None (default: ``"pid"`` when ``pid`` is given, else
        ``"limiter"``; module docstring).
    pid : SlipPIDConfig of the PID law (default :func:`tuned_config`).
    limiter : SlipLimiterConfig of the limiter law (default :func:`limiter_config`).
    preset : EKF preset.
    steady_target : ``"peak"`` (default: the class's traction target also in steady and idle
        states) or ``"served"`` (the served targets of design §10: s_S when steady, 0 when idle;
        the limiter has no "0" cap and keeps the traction target for idle wheels).
    on_fallback : with a model, what to do while the predictor serves its fallback:
        ``"serve"`` (default: limit the slip to the served safe cap, design §10) or
        ``"release"`` (no correction, the wheels follow the low-level command).

    Raises ValueError on a law, steady target or fallback mode it does not know.
    """

    law: str | None = None
    pid: SlipPIDConfig | None = None
    limiter: SlipLimiterConfig | None = None
    preset: str = "robust"
    steady_target: str = "peak"
    on_fallback: str = "serve"

    def __post_init__(self) -> None:
        if self.steady_target not in STEADY_TARGETS:
            raise ValueError(f"steady_target must be one of {', '.join(STEADY_TARGETS)}, "
                             f"got {self.steady_target!r}")
        if self.on_fallback not in ON_FALLBACK:
            raise ValueError(f"on_fallback must be one of {', '.join(ON_FALLBACK)}, "
                             f"got {self.on_fallback!r}")
        if self.law is not None and self.law not in LAWS:
            raise ValueError(f"law must be one of {', '.join(LAWS)}, got {self.law!r}")

    @property
    def law_in_use(self) -> str:
        """The law controlled with: ``law``, else ``"pid"`` when ``pid`` is given, else ``"limiter"``."""
        if self.law is not None:
            return self.law
        return "pid" if self.pid is not None else "limiter"


class SlipController:
    """Per-wheel slip control from measured samples (callable: ``ctrl(sample) -> out``).

    Parameters
    ----------
    robot : RobotSpec.
    policy : one of :data:`POLICIES`.
    settings : :class:`ControlSettings` (law, its gains, EKF preset, steady target, fallback mode).
    model : model folder for the terrain-aware policy served by the online predictor.
    true_class : class id for the oracle terrain-aware policy (no model).
    class_lookup : callable ``t_s -> class id`` (oracle on mixed terrain), overrides
        ``true_class``.
    table : desired-slip table for the oracle policy (default ``DesiredSlipTable.build(robot)``).

    Attributes
    ----------
    law : the control law in use.
    pid : :class:`SlipPID` (PID law) or None; ``config`` its settings.
    limiter : :class:`SlipLimiter` (limiter law) or None.
    trace : None, or a list that receives ``(t, target, measured slip, out)`` per tick (the
        limiter law records its traction cap and its shear slip).
    """

    def __init__(self, robot: RobotSpec, policy: str, settings: ControlSettings = ControlSettings(), *,
                 model: str | Path | None = None, true_class: int | None = None,
                 class_lookup: Callable[[float], int] | None = None, table: Any = None):
        if policy not in POLICIES:
            raise ValueError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}")
        law, pid, limiter, preset = settings.law_in_use, settings.pid, settings.limiter, settings.preset
        steady_target, on_fallback = settings.steady_target, settings.on_fallback
        self.steady_target = steady_target
        self.on_fallback = on_fallback
        self.robot = robot
        self.policy = policy
        self.law = law
        n = robot.n_wheels
        self.config: SlipPIDConfig | None = None
        self.pid: SlipPID | None = None
        self.limiter: SlipLimiter | None = None
        if law == "pid":
            self.config = pid if pid is not None else tuned_config(robot)
            self.pid = SlipPID(n, self.config)
        else:
            self.limiter = SlipLimiter(n, limiter or limiter_config(robot))
        self.predictor = None
        self.estimator = None
        self.class_lookup = class_lookup
        self.true_class = true_class
        self.table: Any = None
        if policy == "terrain-aware" and model is not None:
            self.predictor = Predictor.from_model_dir(model, robot=robot, config=ServingConfig(preset=preset))
        elif policy != "none":
            self.estimator = OnlineEstimator(robot, preset, has_imu_yaw=False)
        if policy == "fixed":
            self.table = FixedTargetTable()
        elif policy == "terrain-aware" and self.predictor is None:
            self.table = table if table is not None else DesiredSlipTable.build(robot)
        self._cmd_keys = [wheel_col("cmd_omega", i) for i in range(1, n + 1)]
        self._omega_keys = [wheel_col("omega", i) for i in range(1, n + 1)]
        self._t_prev: float | None = None
        self._v_last = np.zeros(n)      # last finite wheel-centre speeds (the limiter's input)
        self._out = np.zeros(n)         # last correction (served again on a dropped sample)
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
            if self.limiter is not None or self.config.wheel_radius_m is not None:  # type: ignore[union-attr]
                missing = self._cmd_keys[[v is None for v in vals].index(True)]
                raise ValueError(f"sample lacks column {missing!r}: the slip limiter and the "
                                 "PID's feed-forward need the low-level wheel-speed set-points")
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

    def _target_pair(self, table: Any, cid: int, states) -> tuple[np.ndarray, np.ndarray]:
        """Limiter law: (traction cap s_T > 0, braking floor s_B < 0) per wheel, any wheel state."""
        n = self.robot.n_wheels
        s_t = np.full(n, abs(float(table.target(int(cid), "traction"))))
        s_b = np.full(n, -abs(float(table.target(int(cid), "braking"))))
        if self.steady_target == "served":
            steady = np.array([st == "steady" for st in states])
            s_t = np.where(steady, abs(float(table.target(int(cid), "steady"))), s_t)
        return s_t, s_b

    def _safe_cap_pair(self) -> tuple[np.ndarray, np.ndarray]:
        """Limiter law on fallback: the safe cap's (s_T, s_B) over the model's classes (design §10),
        taken exactly as the predictor takes it for its fallback messages."""
        pred = self.predictor
        ids = getattr(pred.classifier, "class_ids", None)  # type: ignore[union-attr]
        ids = range(len(pred.class_names)) if ids is None else ids  # type: ignore[union-attr]
        names = [pred.class_names[int(c)] for c in ids]  # type: ignore[union-attr]
        cap = safe_cap_for(pred.table, ids, names).safe_cap(  # type: ignore[union-attr]
            names if hasattr(pred.table, "class_names") else None)  # type: ignore[union-attr]
        n = self.robot.n_wheels
        return (np.full(n, abs(float(cap.target("traction")))),
                np.full(n, -abs(float(cap.target("braking")))))

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
        pair: tuple[np.ndarray, np.ndarray] | None = None     # the limiter's targets
        if self.predictor is not None:
            msg = self.predictor.step(s)
            if msg is None:  # a dropped sample (clock policy): keep the last correction
                return None if self.limiter is None else self._out.copy()
            est = self.predictor.estimator
            s_des = np.asarray(msg.slip_desired, dtype=float)
            s_meas = np.array([float(v) for v in est.slip])  # NaN when unavailable: PID disables
            self.n_fallback += int(msg.fallback)
            v_long = np.asarray(est.v_long, dtype=float)
            if msg.fallback and self.on_fallback == "release":
                if self.pid is not None:
                    self.pid.reset()
                    self._trace(t, s_des, s_meas, np.zeros(n))
                    return np.zeros(n)
                pair = (np.full(n, np.nan), np.full(n, np.nan))  # no targets: the limiter lets go
            elif msg.fallback:  # the safe cap: steady and idle moving wheels at its traction target
                s_des = self._steady_at_peak(s_des, msg.wheel_state, v_long, 0,
                                             _CapAsTable(self.predictor.safe_cap_traction()))
                if self.limiter is not None:
                    pair = self._safe_cap_pair()
            else:
                s_des = self._steady_at_peak(s_des, msg.wheel_state, v_long, msg.terrain_class,
                                             self.predictor.table)
                if self.limiter is not None:
                    pair = self._target_pair(self.predictor.table, msg.terrain_class,
                                             msg.wheel_state)
            x = est.ekf.x
            ok = msg.estimator_ok
        else:
            row = self.estimator.step(s)  # type: ignore[union-attr]
            states = list(row.wheels("state", n))
            v_long = np.array(row.wheels("v_long", n), dtype=float)
            cid = self.true_class
            if self.class_lookup is not None:
                cid = int(self.class_lookup(t))
            s_des = np.asarray(desired_slip_per_wheel(cid or 0, states, v_long, self.table))
            s_des = self._steady_at_peak(s_des, states, v_long, cid or 0, self.table)
            s_meas = np.array(row.wheels("slip", n), dtype=float)
            if self.limiter is not None:
                pair = self._target_pair(self.table, cid or 0, states)
            x = self.estimator.ekf.x  # type: ignore[union-attr]
            ok = row.estimator_ok
        if self.limiter is not None:
            return self._limit(t, s, omega_ll, v_long, pair, dt)  # type: ignore[arg-type]
        body = math.hypot(float(x[I_VX]), float(x[I_VY])) if ok else float("nan")
        step = self.pid.step(s_des, s_meas, v_long, body, omega_ll, dt)  # type: ignore[union-attr]
        self._trace(t, s_des, s_meas, step.pid_out_radps)
        return step.pid_out_radps

    def _limit(self, t: float, s: dict, omega_ll: np.ndarray, v_long: np.ndarray,
               pair: tuple[np.ndarray, np.ndarray], dt: float) -> np.ndarray:
        """One tick of the limiter law: measured wheel speeds against the served (s_T, s_B)."""
        # an unhealthy estimate keeps the last good wheel-centre speed (a NaN would release)
        self._v_last = np.where(np.isfinite(v_long), v_long, self._v_last)
        omega = np.array([s.get(k, math.nan) for k in self._omega_keys], dtype=float)
        s_t, s_b = pair
        out = self.limiter.step_pair(omega, omega_ll, self._v_last, s_t, s_b, dt)  # type: ignore[union-attr]
        self._out = out.offset_radps
        self._trace(t, s_t, out.slip_shear, out.offset_radps)
        return out.offset_radps

    def _trace(self, t: float, s_des, s_meas, out) -> None:
        if self.trace is not None:
            self.trace.append((t, np.array(s_des, dtype=float), np.array(s_meas, dtype=float),
                               np.array(out, dtype=float)))
