"""Traction-control policies for the mission suite, all with one interface (design §12).

Every controller is a callable ``ctrl(sample) -> offsets or None``, like
:class:`terrainml.control.traction.SlipController`: ``sample`` is one measured sample (canonical
run-table columns, design §5, plus ``t_s`` and the low-level set-points
``wheel{i}_cmd_omega_radps`` from the robot's own inverse kinematics, as
:func:`terrainml.experiments.closed_loop.closed_loop_hook` builds it); the return value is the
per-wheel offset (rad/s, shape (N,)) added to those set-points, or None for no correction.
Attributes ``n_ticks`` and ``n_fallback`` count ticks and ticks served from the fallback.

Policies (factories at the bottom; the mission registry maps CLI names onto them):

========================  ==========================================================================
``none``                  :func:`no_control`: None (no hook at all).
``fixed``                 :func:`fixed_cap`: the slip limiter at 0.1 (traction) / -0.1 (braking).
``accel-limit``           :class:`AccelLimitController`: the wheel-speed command may rise no faster
                          than ``k mu* g`` (``mu*`` the class's net-traction peak, ``k`` 0.8): a
                          terrain-aware acceleration limit, no slip feedback.
``current-limit``         :class:`CurrentLimitController`: the wheel-speed command is lowered while
                          the motor current exceeds ``mu_H* W_i R / k_t`` (the class's gross
                          thrust peak at the wheel's static load).
``terrain-aware``         :func:`terrain_aware`: the slip limiter at the target the online
                          predictor serves (class target; the class-free safe cap on fallback),
                          refined online (:mod:`terrainml.control.cap_refiner`).
``oracle``                :func:`oracle`: the same, with the true class (a perfect classifier).
``oracle-cap``            :func:`oracle_cap`: the limiter capped at the true traction peak of the
                          terrain draw under each wheel (simulator truth, passed in as a callable;
                          the control package never imports the simulator): the upper bound.
========================  ==========================================================================

Targets (design §12): in traction the cap is the class's traction-peak slip s_T whatever the
demand. Under low demand (cruise, gentle ramps) the soil pins the slip below the peak and the cap
does not bind, so nothing is served *below* the peak: a cap at the steady slip s_S slows the
robot on any soil softer than nominal (design D35). Braking wheels get the floor s_B.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from terrainml.classes import TERRAIN_CLASSES
from terrainml.control.cap_refiner import CapRefiner, CapRefinerConfig, thrust_peak_offset
from terrainml.control.slip_limiter import SlipLimiter, SlipLimiterConfig
from terrainml.control.traction import limiter_config
from terrainml.estimation.online import OnlineEstimator
from terrainml.lookup import terramechanics as tm
from terrainml.lookup.table import DesiredSlipTable
from terrainml.robot import RobotSpec
from terrainml.schema import est_wheel_col, wheel_col
from terrainml.stream.tick.config import ServingConfig
from terrainml.stream.tick.message import UNKNOWN_TERRAIN
from terrainml.stream.tick.predictor import Predictor

__all__ = ["AccelLimitController", "CurrentLimitController", "LimiterController", "fixed_cap",
           "mission_limiter_config", "no_control", "oracle", "oracle_cap", "terrain_aware"]

_SLIP = np.linspace(0.0, 0.99, 991)


def _nominal_params(name: str):
    return tm.nominal_params(name) if name in TERRAIN_CLASSES else None


class _ClassCurves:
    """Per class (by name): traction and braking targets, thrust-peak offsets, peak coefficients."""

    def __init__(self, robot: RobotSpec, table: Any, refiner_cfg: CapRefinerConfig) -> None:
        self.robot = robot
        self.table = table
        self.cfg = refiner_cfg
        self.w_mean = float(np.mean(robot.static_wheel_loads_n()))
        self._cache: dict[int, tuple[float, float, Any, float, float]] = {}

    def get(self, cid: int) -> tuple[float, float, Any, float, float]:
        """(s_T, s_B, thrust-peak offsets, mu_net peak, gross-thrust peak H/W) of class ``cid``;
        the offsets are :func:`thrust_peak_offset`'s (L,) array, NaN without a nominal curve."""
        if cid not in self._cache:
            s_t = float(self.table.target(cid, "traction"))
            s_b = float(self.table.target(cid, "braking"))
            name = self.table.class_name(cid) if hasattr(self.table, "class_name") else TERRAIN_CLASSES[cid]
            p = _nominal_params(name)
            if p is None:
                self._cache[cid] = (s_t, s_b, math.nan, math.nan, math.nan)
            else:
                h = tm.gross_thrust_n(p, self.w_mean, _SLIP, self.robot)
                mu = tm.net_traction_coefficient(p, self.w_mean, _SLIP, self.robot)
                self._cache[cid] = (s_t, s_b, thrust_peak_offset(_SLIP, h, s_t, self.cfg),
                                    float(np.max(mu)), float(np.max(h)) / self.w_mean)
        return self._cache[cid]

    def peak_current_a(self, cid: int, loads_n: np.ndarray) -> np.ndarray:
        """(N,) motor current at class ``cid``'s gross-thrust peak per wheel, A: mu_H* W_i R / k_t
        (NaN without a nominal curve)."""
        rb = self.robot
        return self.get(int(cid))[4] * loads_n * rb.wheel_radius_m / rb.torque_constant_nm_per_a


def mission_limiter_config(robot: RobotSpec, **overrides: Any) -> SlipLimiterConfig:
    """Slip-limiter settings of the mission policies (tuned on the tuning seeds only).

    :func:`terrainml.control.traction.limiter_config` (``kp_mps`` 2.0) with a build-up gain
    ``kp_build_mps`` of 6.0 m/s per unit slip. Why (greenhouse, level ground,
    tuning seeds 5000-5011, oracle-cap against none): the wheel drive is a PI speed loop whose
    torque needs a speed error; at kp 0.5 a start from rest lost 4-13 % route time (the wheel sat
    in its rut on a ceiling a few cm/s above the body), at kp 2.0 still 3-10 % on step starts, with
    the build-up gain 6.0 the ceiling lies above the command until the shear slip nears the cap
    (tilled loam step starts +0.4-0.9 % time). ``rest_relax_s`` 0.5 s: a shear slip left above the
    cap while wheel and body are at rest decays (field tuning seed tilled_loam 5004, 3.4 deg with a
    tool: a speed estimate biased low drove the estimate to 0.2 against a 0.15 cap, the robot
    stopped and the wheels were held at rest for 13 s; with 1.0 s +5.1 % time, with 0.5 s +4.1 %).
    ``overrides`` replace fields.
    """
    return limiter_config(robot, **{"kp_build_mps": 6.0, "rest_relax_s": 0.5, **overrides})


class _Measured:
    """Wheel speeds, set-points and currents of one sample as (N,) arrays."""

    def __init__(self, n: int) -> None:
        self.om = [wheel_col("omega", i) for i in range(1, n + 1)]
        self.cmd = [wheel_col("cmd_omega", i) for i in range(1, n + 1)]
        self.cur = [wheel_col("current", i) for i in range(1, n + 1)]

    @staticmethod
    def _arr(sample: dict, keys: list[str]) -> np.ndarray:
        return np.array([sample.get(k, math.nan) for k in keys], dtype=float)

    def read(self, sample: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        cmd = self._arr(sample, self.cmd)
        if not np.all(np.isfinite(cmd)):
            missing = [k for k, v in zip(self.cmd, cmd) if not np.isfinite(v)]
            raise ValueError(f"sample lacks column {missing[0]!r}: the limiter needs the "
                             "low-level wheel-speed set-points")
        return self._arr(sample, self.om), cmd, self._arr(sample, self.cur)


class LimiterController:
    """The slip limiter with a per-tick target source and optional online refinement.

    Parameters
    ----------
    robot : RobotSpec.
    targets : ``targets(ctrl, sample) -> (s_T (N,), s_B (N,), class id or None)``: the served
        traction cap and braking floor per wheel, and the class whose nominal curve the refiner
        may use (None: serve unrefined, e.g. the safe cap on fallback).
    refine : refine the traction cap online (:class:`~terrainml.control.cap_refiner.CapRefiner`).
    limiter : :class:`SlipLimiterConfig` (default :func:`mission_limiter_config`).
    refiner : :class:`CapRefinerConfig`.
    table : desired-slip table (default ``DesiredSlipTable.build(robot)``).
    predictor : a :class:`~terrainml.stream.tick.predictor.Predictor` stepping the estimator (the
        served policy); otherwise an :class:`OnlineEstimator` gives the wheel-centre speeds.
    preset : EKF preset of the online estimator.
    """

    def __init__(self, robot: RobotSpec, targets: Callable[["LimiterController", dict], tuple],
                 *, refine: bool = False, limiter: SlipLimiterConfig | None = None,
                 refiner: CapRefinerConfig | None = None, table: Any = None,
                 predictor: Predictor | None = None, preset: str = "robust") -> None:
        self.robot = robot
        n = robot.n_wheels
        self.targets = targets
        self.table = table if table is not None else (
            predictor.table if predictor is not None else DesiredSlipTable.build(robot))
        self.limiter = SlipLimiter(n, limiter or mission_limiter_config(robot))
        self.refiner = CapRefiner(n, refiner) if refine else None
        self.curves = _ClassCurves(robot, self.table, refiner or CapRefinerConfig())
        self.wheel_loads_n = np.asarray(robot.static_wheel_loads_n(), dtype=float)
        self.predictor = predictor
        self.estimator = None if predictor is not None else OnlineEstimator(robot, preset,
                                                                             has_imu_yaw=False)
        self.msg: Any = None        # the predictor's message of this tick
        self._io = _Measured(n)
        self._vkeys = [est_wheel_col("v_long", i) for i in range(1, n + 1)]
        self._t_prev: float | None = None
        self._v = np.zeros(n)
        self.n_ticks = 0
        self.n_fallback = 0
        self.last_cap = np.full(n, np.nan)
        self.limiting = np.zeros(n, dtype=bool)   # the limit bound on the previous tick, per wheel
        self.dt_s = 0.01
        self.cmd_radps = np.zeros(n)
        self.current_a = np.full(n, np.nan)
        # per-tick record for analysis: (t, cap, slip_shear, offset) when a list
        self.trace: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] | None = None

    def _wheel_speeds(self, sample: dict) -> np.ndarray:
        """Estimated wheel-centre speed along each wheel (m/s); the last good one when unhealthy."""
        if self.predictor is not None:
            self.msg = self.predictor.step(sample)
            v = np.asarray(getattr(self.predictor.estimator, "v_long", self._v), dtype=float)
            if self.msg is not None and self.msg.fallback:
                self.n_fallback += 1
        else:
            row = self.estimator.step(sample)  # type: ignore[union-attr]
            v = np.array([row.get(k, math.nan) for k in self._vkeys], dtype=float)
        self._v = np.where(np.isfinite(v), v, self._v)
        return self._v

    def __call__(self, sample: dict) -> np.ndarray:
        s = dict(sample)
        conf = s.get("cam_confidence")
        if conf is not None and "cam_valid" not in s:
            s["cam_valid"] = bool(np.isfinite(conf) and conf >= 2)  # as ingest does
        t = float(s["t_s"])
        dt = 0.01 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        self.n_ticks += 1
        om, cmd, cur = self._io.read(s)
        v = self._wheel_speeds(s)
        self.dt_s, self.cmd_radps, self.current_a = dt, cmd, cur   # what a target source may read
        s_t, s_b, cid = self.targets(self, s)
        s_t = np.asarray(s_t, dtype=float)
        if self.refiner is not None:
            off = self.curves.get(cid)[2] if cid is not None else math.nan
            s_t = self.refiner.cap(s_t, off)
        out = self.limiter.step_pair(om, cmd, v, s_t, s_b, dt)
        self.limiting = out.limiting
        if self.refiner is not None:
            rw = self.robot.wheel_radius_m
            d = np.where(cmd < 0.0, -1.0, 1.0)
            thrust = d * cur * self.robot.torque_constant_nm_per_a / rw
            self.refiner.update(d * out.slip_shear, thrust, np.abs(om) * rw * max(dt, 0.0), dt)
        self.last_cap = s_t
        if self.trace is not None:
            self.trace.append((t, np.array(s_t), out.slip_shear.copy(), out.offset_radps.copy()))
        return out.offset_radps


# ------------------------------------------------------------------ target sources
def _class_targets(ctrl: LimiterController, cid: int) -> tuple[np.ndarray, np.ndarray, int]:
    s_t, s_b = ctrl.curves.get(int(cid))[:2]
    n = ctrl.robot.n_wheels
    return np.full(n, s_t), np.full(n, s_b), int(cid)


def _safe_cap_targets(ctrl: LimiterController) -> tuple[np.ndarray, np.ndarray, None]:
    """The class-free safe cap (design §10) of the predictor's classes, on every wheel, unrefined."""
    n = ctrl.robot.n_wheels
    pred = ctrl.predictor
    names = getattr(pred, "class_names", None) or None
    try:
        cap = ctrl.table.safe_cap(names)
        return np.full(n, cap.traction), np.full(n, cap.braking), None
    except Exception:  # noqa: BLE001 - a table without safe_cap: the predictor's own cap
        s = pred.safe_cap_traction()  # type: ignore[union-attr]
        return np.full(n, s), np.full(n, -s), None


def _cap_class(ctrl: LimiterController, s_cap: float) -> int | None:
    """The class whose traction target is the safe cap ``s_cap`` (the largest peak), or None."""
    names = getattr(ctrl.predictor, "class_names", None) or None
    ids = getattr(ctrl.table, "class_ids", None) or ()
    for cid in ids:
        if names is not None and ctrl.table.class_name(cid) not in names:
            continue
        if abs(float(ctrl.table.target(cid, "traction")) - s_cap) < 1e-9:
            return int(cid)
    return None


def _unknown_ground_targets(ctrl: LimiterController) -> tuple[np.ndarray, np.ndarray, int | None]:
    """The safe cap on unknown ground (``unknown_terrain``), refined online.

    No class names the ground, so the cap refiner reads the shift of the measured thrust-slip
    rise against the nominal curve of the class that sets the safe cap (its traction peak is the
    cap): the served cap stays within the refiner's band around the safe cap. Off in the served
    mission policy: on the open-set suite's tuning seeds it did worse than the unrefined safe cap
    (one wet-mud mission lost, a dry-sand mission +3.6% energy per metre over the oracle cap;
    docs/control.md "Online cap refinement").
    """
    s_t, s_b, _ = _safe_cap_targets(ctrl)
    return s_t, s_b, _cap_class(ctrl, float(s_t[0]))


#: m/s, a wheel's command must lead its estimated ground speed by this for it to count as held back
LAG_MARGIN_MPS = 0.05
#: s, how long a wheel must be held at its cap on weak thrust before the class counts as contradicted
#: (*assumption*: one online classification hop, so one noisy current sample does not count)
WEAK_THRUST_S = 0.1


class ServedTargets:
    """Target source of the served policy: the predictor's class; the class-free safe cap on
    fallback, after an estimator-unhealthy episode until reclassified, and for ``hold_m`` after a
    wheel at the served cap shows the class too firm (a stall, speed lost, or weak thrust).

    The class comes from windows of past travel, fused over distance (design §10-11), so it lags
    a terrain change by metres, and its staleness counts distance: at a stall nothing is
    travelled, no window completes and the class never goes stale. Entering a softer patch
    (mission suite, greenhouse tuning seeds: dry sand into wet mud) the limiter held every wheel
    at dry sand's 0.42 on mud whose peak lies near 0.52, the body crept at 0.02 m/s for up to
    48 s, and the fused posterior still read dry sand at 0.93. A wheel held at the served cap
    while the body is stalled is the evidence that the cap is below what the soil needs, so after
    ``stall_s`` of it the class-free safe cap (the largest traction peak of the classes: no known
    class is stalled) is served until the robot has travelled ``hold_m``, then the class again.

    Parameters
    ----------
    stall_speed_mps : m/s, a wheel is stalled at its cap while the limit binds, its estimated
        ground speed is below this and its command above it (*assumption*: 0.1 m/s, a fifth of
        the greenhouse cruise speed).
    stall_s : s, how long any wheel must be stalled at its cap before the safe cap is served
        (*assumption*: 0.5 s; a start from rest on the right class builds up within it).
    hold_m : m, distance (mean estimated wheel-centre speed integrated) the safe cap is held after
        a stall (*assumption*: 2.0 m: a soft patch plus the wheelbase, below the fusion's 3 m).
    relearn : after an ``estimator_unhealthy`` fallback, serve the safe cap until a window has
        been classified after it (``classification_age_s`` shorter than the time since the
        episode). The predictor's odometer counts no unhealthy tick, so a class from before the
        episode comes back unaged although the robot drove on, often onto the ground that upset
        the estimator (greenhouse tuning seed compacted_dirt 5004: compacted dirt's 0.142 served
        on a tilled-loam patch, a 0.5 s stall, +4.9% energy against no control; with the rule
        +2.5%; 8 of 48 greenhouse tuning missions changed, no tuning-seed criterion worse).
        Here and not in the predictor: the class after an episode is usually still right (the
        serving benchmark counts it), and in stop-and-go the next window may come only a second
        after the restart; a consumer that caps wheels on it reads ``classification_age_s``.
    lag_decel_mps2 : m/s^2 or None (off), a wheel held at its cap while its command leads its
        ground speed and the body slows faster than this is a stall on its way; after ``lag_s``
        the safe cap is served as at a stall, while the body still moves (*assumption*: 0.3
        m/s^2, the greenhouse route's own stopping ramp is 0.28 m/s^2 and then the command is
        below the ground speed, so the cap does not bind; 0.5 helped less). Greenhouse tuning
        seeds: 4 missions better (tilled_loam 5006 +0.9 -> +0.0% energy, 5008 +1.8 -> +1.0%,
        time +3.6 -> +2.8%), none worse; field tuning seeds: one +0.1 -> +1.4% energy, spinning
        missions 68% saved either way.
    lag_s : s, how long the body must lose speed at the cap (*assumption*: 0.2 s, two online
        classification hops).
    thrust_gate : share of the served class's gross-thrust peak, or None (off). On the served
        class a wheel reaches the cap (its traction-peak slip) only under near-peak thrust; a
        wheel held at the cap for ``WEAK_THRUST_S`` (0.1 s) while its gross thrust (k_t i / R over its static load)
        is below this share of the class's peak H/W contradicts the class: the ground is softer
        than served and needs more slip for the same thrust, so the cap only holds the robot
        back (low demand, design §12 "What is served"). It escalates as at a stall
        (*assumption*: 0.5, midway; greenhouse tuning seed compacted_dirt 5004, compacted dirt's
        0.142 on a tilled-loam patch at about 0.3 of its peak thrust: +2.5% -> +0.0% energy).
        Tuning seeds, every mission: worst energy change against none +2.5 -> +0.1%
        (greenhouse), +1.4 -> +0.0% (field); worst time +2.8 -> +0.3%, +2.0 -> +0.1%; step-start
        and spinning savings unchanged (28.1%, 68%).
    refine_unknown : on a message saying ``unknown_terrain`` serve the safe cap
        refined online (the controller's ``refine``; :func:`_unknown_ground_targets`), not while a
        stall escalation holds it (that serves the largest peak unrefined). Other fallbacks serve
        it unrefined (no class, no curve: design §12).
    refine_classes : refine a served class's cap too (the controller's ``refine``); False: only
        the safe cap on unknown ground is refined (:func:`terrain_aware` ``refine="unknown"``).
    """

    def __init__(self, stall_speed_mps: float = 0.1, stall_s: float = 0.5, hold_m: float = 2.0,
                 relearn: bool = True, lag_decel_mps2: float | None = 0.3, lag_s: float = 0.2,
                 thrust_gate: float | None = 0.5, refine_unknown: bool = True,
                 refine_classes: bool = True):
        for name, v in (("stall_speed_mps", stall_speed_mps), ("stall_s", stall_s), ("hold_m", hold_m),
                        ("lag_s", lag_s), ("lag_decel_mps2", 1.0 if lag_decel_mps2 is None else lag_decel_mps2)):
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"ServedTargets.{name} must be finite and > 0, got {v!r}")
        self.stall_speed_mps = float(stall_speed_mps)
        self.stall_s = float(stall_s)
        self.hold_m = float(hold_m)
        self.stalled_s = 0.0           # how long some wheel has been stalled at its cap
        self.hold_left_m = 0.0         # > 0: the safe cap is served for this much more travel
        self.n_escalations = 0
        self.relearn = bool(relearn)
        self.unhealthy_gap_s: float | None = None   # s since an estimator-unhealthy episode ended
        self.lag_decel_mps2 = None if lag_decel_mps2 is None else float(lag_decel_mps2)
        self.lag_s = float(lag_s)
        self.losing_s = 0.0            # how long some wheel at its cap has been losing speed
        self._v_smooth: float | None = None
        if thrust_gate is not None and not (math.isfinite(thrust_gate) and 0.0 < thrust_gate < 1.0):
            raise ValueError(f"ServedTargets.thrust_gate must be None or in (0, 1), got {thrust_gate!r}")
        self.thrust_gate = None if thrust_gate is None else float(thrust_gate)
        self.weak_s = 0.0              # how long some wheel has been held at its cap on weak thrust
        self.refine_unknown = bool(refine_unknown)
        self.refine_classes = bool(refine_classes)

    def _stale_after_unhealthy(self, msg: Any, dt: float) -> bool:
        """True while the served class predates the last estimator-unhealthy episode."""
        if not self.relearn or msg is None:
            return False
        if msg.fallback and msg.fallback_reason == "estimator_unhealthy":
            self.unhealthy_gap_s = 0.0
            return False
        if self.unhealthy_gap_s is None:
            return False
        self.unhealthy_gap_s += dt
        if 0.0 <= msg.classification_age_s < self.unhealthy_gap_s:
            self.unhealthy_gap_s = None     # a window classified after the episode
            return False
        return True

    def _losing_speed(self, ctrl: LimiterController, v: np.ndarray, u_cmd: np.ndarray, dt: float) -> bool:
        """True once some wheel has been held at its cap for ``lag_s`` while the body, behind its
        command, slowed faster than ``lag_decel_mps2`` (mean wheel-centre speed, low-passed
        over 0.1 s so that one noisy estimate does not count)."""
        vb = float(np.mean(v))
        prev = vb if self._v_smooth is None else self._v_smooth
        self._v_smooth = prev + (vb - prev) * dt / (0.1 + dt)
        decel = (prev - self._v_smooth) / dt
        behind = ctrl.limiting & (u_cmd > v + LAG_MARGIN_MPS)
        self.losing_s = self.losing_s + dt if (np.any(behind) and decel > self.lag_decel_mps2) else 0.0
        return self.losing_s >= self.lag_s

    def _stalled(self, ctrl: LimiterController, v: np.ndarray, u_cmd: np.ndarray, dt: float) -> bool:
        """True once some wheel has been stalled at its cap for ``stall_s``, or sooner when the
        body loses speed at the cap (``lag_decel_mps2``)."""
        stalled = ctrl.limiting & (v < self.stall_speed_mps) & (u_cmd > self.stall_speed_mps)
        self.stalled_s = self.stalled_s + dt if np.any(stalled) else 0.0
        if self.lag_decel_mps2 is not None and dt > 0.0 and self._losing_speed(ctrl, v, u_cmd, dt):
            self.stalled_s = max(self.stalled_s, self.stall_s)   # a stall on its way: act now
        return self.stalled_s >= self.stall_s

    def _weak_at_cap(self, ctrl: LimiterController, cid: int, dt: float) -> bool:
        """True once some wheel has been held at the served cap for ``WEAK_THRUST_S`` with a motor
        current (gross thrust) below ``thrust_gate`` of the current at the served class's thrust
        peak: on the served class the cap is reached only near that peak, so the class is
        contradicted there. No logged current (NaN) contradicts nothing."""
        d = np.where(ctrl.cmd_radps < 0.0, -1.0, 1.0)
        i_peak = ctrl.curves.peak_current_a(cid, ctrl.wheel_loads_n)
        weak = ctrl.limiting & np.isfinite(ctrl.current_a) & (d * ctrl.current_a < self.thrust_gate * i_peak)
        self.weak_s = self.weak_s + dt if np.any(weak) else 0.0
        return self.weak_s >= WEAK_THRUST_S

    def _escalate(self) -> None:
        """Serve the safe cap for the next ``hold_m`` of travel (counted once per episode)."""
        if self.hold_left_m <= 0.0:
            self.n_escalations += 1
        self.hold_left_m = self.hold_m

    def __call__(self, ctrl: LimiterController, sample: dict):
        dt = max(float(ctrl.dt_s), 0.0) if math.isfinite(ctrl.dt_s) else 0.0
        msg = ctrl.msg
        v = np.abs(ctrl._v)
        u_cmd = np.abs(ctrl.cmd_radps) * ctrl.robot.wheel_radius_m
        self.hold_left_m = max(self.hold_left_m - float(np.mean(v)) * dt, 0.0)
        classed = msg is not None and not msg.fallback and msg.terrain_class >= 0
        if self._stalled(ctrl, v, u_cmd, dt):
            self._escalate()
        elif (self.thrust_gate is not None and classed and self.hold_left_m <= 0.0
              and self._weak_at_cap(ctrl, msg.terrain_class, dt)):
            self._escalate()
        stale = self._stale_after_unhealthy(msg, dt)
        if not classed or self.hold_left_m > 0.0 or stale:
            unknown = msg is not None and msg.fallback_reason == UNKNOWN_TERRAIN
            if unknown and self.refine_unknown and self.hold_left_m <= 0.0:
                return _unknown_ground_targets(ctrl)
            return _safe_cap_targets(ctrl)
        s_t, s_b, cid = _class_targets(ctrl, msg.terrain_class)
        return s_t, s_b, cid if self.refine_classes else None


# ------------------------------------------------------------------ factories
def no_control(robot: RobotSpec) -> None:
    """No traction control: no hook at all."""
    return None


def fixed_cap(robot: RobotSpec, value: float = 0.1, **kw: Any) -> LimiterController:
    """The slip limiter at a fixed ``value`` (traction) and ``-value`` (braking), any terrain."""
    n = robot.n_wheels
    return LimiterController(robot, lambda c, s: (np.full(n, value), np.full(n, -value), None), **kw)


def oracle(robot: RobotSpec, class_lookup: Callable[[float], int], *, refine: bool = True,
           **kw: Any) -> LimiterController:
    """The limiter at the true class's targets (``class_lookup(t_s) -> class id``), refined."""
    return LimiterController(robot, lambda c, s: _class_targets(c, class_lookup(float(s["t_s"]))),
                             refine=refine, **kw)


def terrain_aware(robot: RobotSpec, model: str | Path | None = None, *,
                  predictor: Predictor | None = None, refine: bool | str = True,
                  preset: str | None = None, escalation: dict | None = None, open_set: bool = True,
                  **kw: Any) -> LimiterController:
    """The limiter at the target the online predictor serves from ``model`` (or ``predictor``),
    with the safe cap after a stall at the served cap (:class:`ServedTargets`; ``escalation``
    its keyword arguments).

    ``refine``: True refines every served cap online, ``"unknown"`` only the safe cap served on
    unknown ground, False none. ``open_set``: :class:`ServingConfig` ``open_set``
    (False: the model's novelty score is not used, never ``unknown_terrain``).
    """
    if refine not in (True, False, "unknown"):
        raise ValueError(f"terrain_aware: refine must be True, False or 'unknown', got {refine!r}")
    if predictor is None:
        if model is None:
            raise ValueError("terrain_aware needs a model folder or a Predictor")
        predictor = Predictor.from_model_dir(model, robot=robot,
                                             config=ServingConfig(preset=preset, open_set=open_set))
    targets = ServedTargets(**{"refine_classes": refine is True, **(escalation or {})})
    return LimiterController(robot, targets, refine=bool(refine), predictor=predictor, **kw)


def oracle_cap(robot: RobotSpec, peak_per_wheel: Callable[[], Sequence[float]],
               class_lookup: Callable[[float], int], **kw: Any) -> LimiterController:
    """The limiter capped at the true traction-peak slip under each wheel (``peak_per_wheel()``,
    simulator truth); braking floors from the true class's table row. Never refined."""
    def targets(ctrl: LimiterController, sample: dict):
        _, s_b, _ = _class_targets(ctrl, class_lookup(float(sample["t_s"])))
        return np.asarray(peak_per_wheel(), dtype=float), s_b, None
    return LimiterController(robot, targets, refine=False, **kw)


class _CommandShaper:
    """Shared plumbing of the two non-slip baselines: class lookup, set-points, tick counting."""

    def __init__(self, robot: RobotSpec, class_lookup: Callable[[float], int],
                 table: Any = None) -> None:
        self.robot = robot
        self.class_lookup = class_lookup
        self.table = table if table is not None else DesiredSlipTable.build(robot)
        self.curves = _ClassCurves(robot, self.table, CapRefinerConfig())
        self._io = _Measured(robot.n_wheels)
        self._t_prev: float | None = None
        self.n_ticks = 0
        self.n_fallback = 0

    def _tick(self, sample: dict):
        t = float(sample["t_s"])
        dt = 0.01 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        self.n_ticks += 1
        return t, max(dt, 0.0), *self._io.read(sample)


class AccelLimitController(_CommandShaper):
    """Terrain-aware acceleration limit: each wheel's speed command rises at most ``k mu* g / R``
    rad/s per second (``mu*`` the served class's nominal net-traction peak); decreases pass.

    Parameters
    ----------
    robot, class_lookup, table : as :func:`oracle`.
    k : share of ``mu* g`` the body may be asked to accelerate with (*assumption*: 0.8).
    """

    def __init__(self, robot: RobotSpec, class_lookup: Callable[[float], int], *,
                 k: float = 0.8, table: Any = None) -> None:
        super().__init__(robot, class_lookup, table)
        self.k = float(k)
        self._out: np.ndarray | None = None

    def __call__(self, sample: dict) -> np.ndarray:
        t, dt, om, cmd, _ = self._tick(sample)
        mu = self.curves.get(int(self.class_lookup(t)))[3]
        step = self.k * max(mu, 0.05) * 9.81 / self.robot.wheel_radius_m * dt
        prev = om if self._out is None else self._out
        # rise towards the command at the limit; any decrease in magnitude passes at once
        up = np.abs(cmd) > np.abs(prev)
        out = np.where(up, prev + np.clip(cmd - prev, -step, step), cmd)
        out = np.where(np.sign(out) * np.sign(cmd) < 0, 0.0, out)
        self._out = out
        return out - cmd


class CurrentLimitController(_CommandShaper):
    """Current limit at ``mu_H* W_i R / k_t`` per wheel (``mu_H*`` the served class's gross-thrust
    peak over load, ``W_i`` the static load): while ``|i|`` exceeds it the speed command is pulled
    down by an integrator (``gain`` rad/s per A s), which drains at ``release_radps2`` below it.

    The limit uses the *gross* thrust peak (what the motor current measures); the net-traction peak
    ``mu*`` would leave the wheel short of the rolling resistance it must also overcome.
    """

    def __init__(self, robot: RobotSpec, class_lookup: Callable[[float], int], *,
                 gain: float = 20.0, release_radps2: float = 6.0, table: Any = None) -> None:
        super().__init__(robot, class_lookup, table)
        self.gain = float(gain)
        self.release = float(release_radps2)
        self.loads = np.asarray(robot.static_wheel_loads_n(), dtype=float)
        self.offset = np.zeros(robot.n_wheels)

    def limit_a(self, cid: int) -> np.ndarray:
        """(N,) current limit per wheel, A."""
        return self.curves.peak_current_a(cid, self.loads)

    def __call__(self, sample: dict) -> np.ndarray:
        t, dt, om, cmd, cur = self._tick(sample)
        lim = self.limit_a(int(self.class_lookup(t)))
        d = np.where(cmd < 0.0, -1.0, 1.0)
        excess = np.nan_to_num(np.abs(cur) - lim)
        mag = d * self.offset                        # <= 0: how much the command is lowered
        mag = np.where(excess > 0, mag - self.gain * excess * dt, np.minimum(mag + self.release * dt, 0.0))
        mag = np.maximum(mag, -np.abs(cmd))          # never reverse the wheel
        self.offset = d * mag
        return self.offset
