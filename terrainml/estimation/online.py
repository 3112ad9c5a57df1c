"""Online estimator: one canonical sample in, one EST row out (contract 2).

:class:`OnlineEstimator` chains pre-filters, the EKF (:mod:`terrainml.estimation.ekf`), per-wheel
slip (:mod:`.slip`) and the dynamic-state machine (:mod:`.dynamic_state`). The offline
:func:`terrainml.estimation.run.estimate_run` loops over the same :meth:`OnlineEstimator.core`
code, so offline and online outputs are identical.

Sample format: a mapping with ``t_s`` (s) and any canonical run-table columns (design §5), e.g.
``wheel1_omega_radps``, ``imu_ax_mps2``, ``cam_vx_mps`` and optionally ``{group}_valid``. A row
is used only when its group is valid (missing ``_valid`` key = valid) and its value is finite;
missing keys are treated as invalid, never as stale values. The EST row of a tick is an
immutable :class:`~terrainml.estimation.row.EstimatorRow` (column names: :mod:`terrainml.schema`).

Speed (``step()`` runs at 100 Hz inside a control loop): a tick is three compiled calls
(:mod:`terrainml.estimation._kernel`): the measurement pre-processing (``measurements_tick``),
the EKF (:meth:`Ekf.step`) and the per-wheel slip and dynamic state (``wheels_tick``), glued by
the policy decisions in plain Python (camera health, fallback). Everything is preallocated: no
pandas, no per-tick numpy temporaries. The compiled parts run the same primitives as the
classes of :mod:`.slip` and :mod:`.dynamic_state` (one implementation of each rule).
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from terrainml.estimation._kernel import I_AX, I_AY, I_R, I_VX, I_VY, measurements_tick
from terrainml.estimation._wheel_kernel import (MAX_P_DIAG, MAX_SPEED_MPS, SLIP_MEMORY_CLIP,  # noqa: F401
                                                SLIP_MEMORY_MIN_SPEED_MPS, wheels_tick)
from terrainml.estimation.dynamic_state import DWELL_S, MANOEUVRE_TAU_S, THETA_M2PS3, WheelStateMachine
from terrainml.estimation.ekf import Ekf, EkfPreset, PlanarModel, get_preset
from terrainml.estimation.reference import ReferenceEkf
from terrainml.estimation.row import EstimatorRow, RowLayout
from terrainml.estimation.slip import DEAD_BAND_MPS
from terrainml.robot import RobotSpec
from terrainml.schema import EST_BODY_COLUMNS, VALID_GROUPS, WHEEL_STATES, est_columns, valid_column, wheel_col

#: rows of vx, vy, r, ax, ay in the EKF state (the wheel kernel takes the layout as an argument)
_BODY_ROWS = np.array([I_VX, I_VY, I_R, I_AX, I_AY], dtype=np.int64)

PASS_WHEEL = ("omega", "current", "steer")   # wheel column kinds (schema.wheel_col)
PASS_BASE = ("imu_ax_mps2", "imu_ay_mps2", "imu_az_mps2", "imu_yaw_rate_radps")
# fallback wheel-row variance at the start of a camera gap when no slip is remembered yet
# (the IMU bridges the gap; wheels take over as it decays to r_wheel over fallback_ramp_s)
R_WHEEL_UNCOMPENSATED = 50.0
ACCEL_TAU_S = MANOEUVRE_TAU_S  # manoeuvre filter on the acceleration feeding the wheel Power
# sensor groups whose freshness the estimator tracks (order of _last_seen)
GROUPS = ("wheels", "imu", "cam", "steer")
#: a stale stretch (a health group silent past ``sensor_timeout_s``) longer than this (s) ends
#: with the filter re-initialised (:meth:`Ekf.reacquire`) on the first tick every group is fresh
REACQUIRE_AFTER_S = 1.0
G_WHEELS, G_IMU, G_CAM, G_STEER = range(4)


def est_state_columns(n_wheels: int) -> list[str]:
    """Estimated columns of the EST table (without pass-through columns), in order
    (:func:`terrainml.schema.est_columns`)."""
    return est_columns(n_wheels)


def passthrough_columns(n_wheels: int, available: list[str] | None = None) -> list[str]:
    """Run-table columns copied into the EST table (contract 2), restricted to ``available``."""
    cols = [wheel_col(kind, i) for i in range(1, n_wheels + 1) for kind in PASS_WHEEL]
    cols += list(PASS_BASE)
    cols += [valid_column(g).name for g in VALID_GROUPS]
    cols += ["terrain", "run_id"]
    if available is None:
        return cols
    avail = set(available)
    out = [c for c in cols if c in avail]
    out += [c for c in available if c.startswith("gt_") and c not in out]
    return out


def flag_groups(robot: RobotSpec) -> frozenset[str]:
    """The health groups whose freshness ``estimator_ok`` needs (``fresh_ok`` in
    :meth:`OnlineEstimator.core`): the wheels, the IMU and, on a robot with one, the camera."""
    return frozenset({"wheels", "imu", "cam"} if robot.has_camera else {"wheels", "imu"})


class OnlineEstimator:
    """EKF + slip + dynamic state, one tick at a time.

    Parameters
    ----------
    robot : RobotSpec (resolved by the caller: :func:`terrainml.robot.load_robot`).
    preset : ``"thesis"``, ``"robust"`` or an :class:`~terrainml.estimation.ekf.EkfPreset`.
    has_imu_yaw, has_cam_yaw : whether the yaw rows exist (the run table may lack the optional
        ``imu_yaw_rad`` / ``cam_yaw_rad`` columns; rows are then simply dropped every tick).
    theta, dwell_s : dynamic-state threshold (m^2/s^3) and minimum dwell (s), design §7.2.
    accel_tau_s : time constant (s) of each stage of the manoeuvre filter
        (:class:`~terrainml.estimation.dynamic_state.ManoeuvreFilter`) on the EKF acceleration
        used for the wheel Power. theta = 0.02 m^2/s^3 is ~0.02 m/s^2 at 1 m/s, below the IMU's
        noise and terrain vibration; without smoothing the state chatters or freezes
        (*departure*: design §7.2 does not filter the acceleration).
    reference : run the readable numpy filter (:class:`~terrainml.estimation.reference.ReferenceEkf`,
        the specification) instead of the compiled one: the same numbers within 1e-9, much slower.

    Examples
    --------
    >>> est = OnlineEstimator(robot, "robust")  # robot: a RobotSpec  # doctest: +SKIP
    >>> row = est.step({"t_s": 0.0, "wheel1_omega_radps": 0.0, ...})  # doctest: +SKIP
    >>> row["slip1"], row["state1"], row["estimator_ok"]  # doctest: +SKIP
    """

    def __init__(self, robot: RobotSpec, preset: str | EkfPreset = "robust", *,
                 has_imu_yaw: bool = True, has_cam_yaw: bool = True,
                 theta: float = THETA_M2PS3, dwell_s: float = DWELL_S,
                 accel_tau_s: float = ACCEL_TAU_S, reference: bool = False) -> None:
        self.robot = robot
        self.preset = get_preset(preset)
        self.model = PlanarModel(self.robot, has_imu_yaw=has_imu_yaw, has_cam_yaw=has_cam_yaw)
        self.ekf = (ReferenceEkf if reference else Ekf)(self.model, self.preset)
        rows = self.model.rows
        p = self.preset
        N = self.robot.n_wheels
        m = len(rows)
        self.n_wheels = N
        self.row_columns = [r.column for r in rows]
        self.row_groups = [r.group for r in rows]
        self.group_names = sorted(set(self.row_groups))
        self._is_wheel = np.array([r.kind == "wheel" for r in rows], dtype=bool)
        # wheel rows come first and read wheel{i}_omega_radps: the same values feed slip
        assert self.row_columns[:N] == [wheel_col("omega", i) for i in range(1, N + 1)]
        assert self._is_wheel[:N].all() and not self._is_wheel[N:].any()
        self._group_of_row = np.array([GROUPS.index(g) for g in self.row_groups], dtype=np.int64)
        # pre-filters (eq. 6.12): z_f = alpha z_f + (1 - alpha) z, per row
        alpha = {"wheel": p.alpha_wheel, "steer": p.alpha_steer}
        self._alpha = np.array([alpha.get(r.kind, p.alpha_cam if r.group == "cam" else p.alpha_imu)
                                for r in rows])
        self._one_minus_alpha = 1.0 - self._alpha
        self._any_alpha = bool(np.any(self._alpha > 0))
        self._angle = np.array([r.angle for r in rows], dtype=bool)
        r_of = {"wheel": p.r_wheel, "imu_ax": p.r_imu_acc, "imu_ay": p.r_imu_acc,
                "imu_rate": p.r_imu_rate, "imu_yaw": p.r_imu_yaw, "steer": p.r_steer,
                "cam_vx": p.r_cam_vel, "cam_vy": p.r_cam_vel, "cam_rate": p.r_cam_rate,
                "cam_yaw": p.r_cam_yaw}
        self._r_base = np.array([r_of[r.kind] for r in rows])
        self._r_cam_ok = self._r_base.copy()
        if p.r_wheel_cam_ok is not None:
            self._r_cam_ok[self._is_wheel] = p.r_wheel_cam_ok
        self._r_fallback = np.empty(m)  # R during a camera gap (wheel variance ramps)
        self._z_f = np.full(m, np.nan)  # pre-filter memory
        self._yaw_offset = np.full(m, np.nan)  # yaw zeroed at the first valid sample
        self._prev_valid = np.zeros(m, dtype=bool)
        self._z = np.empty(m)  # this tick's measurements and rows used (work arrays)
        self._use = np.empty(m, dtype=bool)
        self._last_seen = np.full(len(GROUPS), -math.inf)  # time of the last usable row per group
        self._t_prev: float | None = None
        self._has_cam = self.robot.has_camera
        self._cam_ok_prev = False
        self._stale_since: float | None = None  # start of the current stale stretch (s)
        self.n_reacquired = 0  # times the filter was re-initialised after a stale stretch
        # per-wheel state: encoder lag, slip memory, manoeuvre filter, state machine
        self._wheel_xy = np.ascontiguousarray(self.model.wheel_xy_m, dtype=float)
        self._steer_state = self.model.steer_state.astype(np.int64)
        self._radius = float(self.robot.wheel_radius_m)
        self._lag_y = np.zeros(N)
        self._slip_mem = np.zeros(N)  # low-passed slip while the camera is healthy
        self._slip_mem_age = 0.0  # seconds of slip observations behind it
        self._accel_tau_s = float(accel_tau_s)
        self._accel_y1 = np.zeros(2)  # manoeuvre filter stages on (ax, ay)
        self._accel_y2 = np.zeros(2)
        self._sm = WheelStateMachine(N, theta, dwell_s)
        # step(): sample keys, the group mask per validity pattern, EST row keys
        self._valid_keys = [valid_column(g).name for g in GROUPS]
        self._group_mask: dict[tuple[bool, ...], np.ndarray] = {}
        self._nan_wheels = np.full(N, np.nan)
        self._pass_cols = passthrough_columns(N)
        self._copy_cache: dict = {}
        self._row_layout = RowLayout(est_state_columns(N))
        self._i_bias = self.model.i_bias
        # outputs of the last tick (arrays are overwritten in place every tick: copy to keep)
        self.steer = np.zeros(N)
        self.v_long = np.zeros(N)
        self.slip = np.full(N, np.nan)
        self.state = self._sm.state  # int8 codes, order of schema.WHEEL_STATES
        self.estimator_ok = False
        self.slip_available = False
        self.t_s = float("nan")

    # ----------------------------------------------------------------- core (shared offline/online)
    def core(self, t_s: float, z_raw: np.ndarray, row_valid: np.ndarray, omega_radps: np.ndarray) -> None:
        """Advance one tick.

        Parameters
        ----------
        t_s : tick time (s).
        z_raw : (m,) float, raw measurement per EKF row (order of ``self.row_columns``).
        row_valid : (m,) bool, row has a fresh finite sample this tick (its group valid). A
            sensor group counts as seen when one of its rows is valid.
        omega_radps : (N,) float, raw wheel speeds (for slip; NaN where invalid).
        """
        p = self.preset
        N = self.n_wheels
        dt = 0.0 if self._t_prev is None else t_s - self._t_prev
        first = self._t_prev is None
        self._t_prev = t_s
        # ------------------------------------------------ measurements: yaw zeroing, pre-filters
        z, use = self._z, self._use
        measurements_tick(t_s, z_raw, row_valid, self._group_of_row, self._last_seen, self._angle,
                          self._yaw_offset, self._any_alpha, self._one_minus_alpha, self._z_f,
                          self._prev_valid, z, use)
        # ------------------------------------------------ camera health decides R and the wheel rows
        cam_gap_s = t_s - float(self._last_seen[G_CAM])
        cam_ok = self._has_cam and cam_gap_s <= p.cam_timeout_s
        r_diag = self._r_cam_ok if cam_ok else self._r_base
        fallback = not cam_ok and self._has_cam
        comp = fallback and p.fallback_slip_comp and self._slip_mem_age >= p.slip_memory_tau_s
        if comp:
            # slip-compensated wheel rows: the wheel speed the remembered slip implies on the ground
            for i in range(N):
                s_i = self._slip_mem[i]
                z[i] = z[i] * (1.0 - s_i) if s_i >= 0.0 else z[i] / (1.0 + s_i)
        if fallback and p.r_wheel_fallback_start is not None:
            # adaptive wheel variance in fallback: r_start -> r_wheel geometrically over the ramp
            frac = max(0.0, 1.0 - cam_gap_s / p.fallback_ramp_s) if math.isfinite(cam_gap_s) else 0.0
            r_start = p.r_wheel_fallback_start if comp else R_WHEEL_UNCOMPENSATED
            r_diag = self._r_fallback
            r_diag[:] = self._r_base
            r_diag[:N] = p.r_wheel * (r_start / p.r_wheel) ** frac
        if cam_ok and p.drop_wheels_when_cam_ok:
            use[:N] = False  # zero-slip rows would bias v toward wheel odometry
            if self._any_alpha:
                self._prev_valid[:N] = False  # a dropped row restarts its pre-filter when it returns
        # ------------------------------------------------ a stale stretch ends: re-initialise
        tmo = p.sensor_timeout_s
        fresh_ok = (t_s - float(self._last_seen[G_WHEELS]) <= tmo and t_s - float(self._last_seen[G_IMU]) <= tmo
                    and (cam_ok or not self._has_cam))
        ekf = self.ekf
        if not fresh_ok:
            if self._stale_since is None:
                self._stale_since = t_s
        elif self._stale_since is not None:
            if t_s - self._stale_since > REACQUIRE_AFTER_S:
                ekf.reacquire()
                self.n_reacquired += 1
            self._stale_since = None
        # ------------------------------------------------ EKF: predict over dt, update
        # no gate on the first camera sample after a gap (the prediction is the stale part)
        ekf.step(dt, z, use, r_diag, gate_enabled=self._cam_ok_prev or not cam_ok)
        self._cam_ok_prev = cam_ok
        # ------------------------------------------------ slip and dynamic state per wheel
        sm = self._sm
        sane, mem_dt = wheels_tick(
            t_s, dt, first, cam_ok, ekf.x, _BODY_ROWS, ekf.P, self._steer_state, self._wheel_xy, self._radius,
            omega_radps, DEAD_BAND_MPS, p.encoder_lag_s, self._lag_y, p.fallback_slip_comp,
            p.slip_memory_tau_s, self._slip_mem, self._accel_tau_s, self._accel_y1, self._accel_y2,
            sm.theta, sm.dwell_s, sm.idle_speed, sm.state, sm.cand, sm.cand_since,
            self.steer, self.v_long, self.slip)
        sm.started = True
        self._slip_mem_age += mem_dt
        self.slip_available = bool(cam_ok)
        # ------------------------------------------------ health
        self.estimator_ok = bool(fresh_ok and sane)
        self.t_s = t_s

    # ----------------------------------------------------------------- online API
    def step(self, sample: Mapping[str, Any]) -> EstimatorRow:
        """Process one sample (canonical column names + ``t_s``); return its EST row.

        The row (:class:`~terrainml.estimation.row.EstimatorRow`, immutable) holds the EST columns
        (:func:`est_state_columns`) and then the sample's pass-through columns
        (:func:`passthrough_columns`, simulator truth ``gt_*`` included), in the sample's order.
        """
        get = sample.get
        t = float(sample["t_s"])
        z = np.array([get(col, math.nan) for col in self.row_columns], dtype=float)  # None -> NaN
        gvalid = tuple([bool(get(key, True)) for key in self._valid_keys])
        mask = self._group_mask.get(gvalid)
        if mask is None:  # rows whose group is valid, per validity pattern (at most 16)
            ok = dict(zip(GROUPS, gvalid))
            mask = self._group_mask[gvalid] = np.array([ok[g] for g in self.row_groups], dtype=bool)
        valid = np.isfinite(z)
        valid &= mask
        self.core(t, z, valid, z[:self.n_wheels] if gvalid[G_WHEELS] else self._nan_wheels)
        keys = tuple(sample)
        cached = self._copy_cache.get(keys)
        if cached is None:  # which keys to pass through, and the row's layout (per key layout)
            wanted = set(self._pass_cols)
            copy = [k for k in keys if k in wanted or k.startswith("gt_")]
            cached = (copy, self._row_layout.plus(tuple(copy)))
            self._copy_cache = {keys: cached}
        copy, layout = cached
        return EstimatorRow(layout, self._values() + tuple([sample[k] for k in copy]))

    def row(self) -> EstimatorRow:
        """The EST columns of the last tick (names: :func:`est_state_columns`), without pass-through."""
        return EstimatorRow(self._row_layout, self._values())

    def _values(self) -> tuple[Any, ...]:
        """The values of the EST columns of the last tick, in order."""
        x = self.ekf.x.tolist()
        ekf = self.ekf
        return (self.t_s, *x[:len(EST_BODY_COLUMNS)], *self.steer.tolist(), x[self._i_bias], *self.slip.tolist(),
                *[WHEEL_STATES[c] for c in self.state.tolist()], *self.v_long.tolist(),
                float(ekf.nis), int(ekf.nis_dof), self.estimator_ok, bool(self.slip_available))
