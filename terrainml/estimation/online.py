"""Online estimator: one canonical sample in, one EST row out (contract 2).

:class:`OnlineEstimator` chains pre-filters, the EKF (:mod:`terrainml.estimation.ekf`), per-wheel
slip (:mod:`.slip`) and the dynamic-state machine (:mod:`.dynamic_state`). The offline
:func:`terrainml.estimation.run.estimate_run` loops over the same :meth:`OnlineEstimator.core`
code, so offline and online outputs are identical.

Sample format: a mapping with ``t_s`` (s) and any canonical run-table columns (SYSTEM §5), e.g.
``wheel1_omega_radps``, ``imu_ax_mps2``, ``cam_vx_mps`` and optionally ``{group}_valid``. A row
is used only when its group is valid (missing ``_valid`` key = valid) and its value is finite;
missing keys are treated as invalid, never as stale values.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from terrainml.estimation.dynamic_state import (DWELL_S, MANOEUVRE_TAU_S, THETA_M2PS3, ManoeuvreFilter,
                                                WheelStateMachine, wheel_power)
from terrainml.estimation.ekf import (I_AX, I_AY, I_PSI, I_R, I_VX, I_VY, I_X, I_Y, TWO_PI, Ekf,
                                      EkfPreset, PlanarModel, get_preset)
from terrainml.estimation.slip import DEAD_BAND_MPS, EncoderLag, slip_ratio_tick
from terrainml.robot import RobotSpec, load_robot
from terrainml.schema import VALID_GROUPS, WHEEL_STATES

PASS_WHEEL = ("omega_radps", "current_a", "steer_rad")
PASS_BASE = ("imu_ax_mps2", "imu_ay_mps2", "imu_az_mps2", "imu_yaw_rate_radps")
MAX_SPEED_MPS = 50.0  # beyond this the filter is declared diverged
MAX_P_DIAG = 1e6
# fallback wheel-row variance at the start of a camera gap when no slip is remembered yet
# (the IMU bridges the gap; wheels take over as it decays to r_wheel over fallback_ramp_s)
R_WHEEL_UNCOMPENSATED = 50.0
ACCEL_TAU_S = MANOEUVRE_TAU_S  # manoeuvre filter on the acceleration feeding the wheel Power


def est_state_columns(n_wheels: int) -> list[str]:
    """Estimated columns of the EST table (without pass-through columns), in order."""
    cols = ["t_s", "ekf_x_m", "ekf_y_m", "ekf_yaw_rad", "ekf_vx_mps", "ekf_vy_mps",
            "ekf_yaw_rate_radps", "ekf_ax_mps2", "ekf_ay_mps2"]
    cols += [f"ekf_steer{i}_rad" for i in range(1, n_wheels + 1)]
    cols += ["ekf_gyro_bias_radps"]
    cols += [f"slip{i}" for i in range(1, n_wheels + 1)]
    cols += [f"state{i}" for i in range(1, n_wheels + 1)]
    cols += [f"v_long{i}_mps" for i in range(1, n_wheels + 1)]
    cols += ["nis", "nis_dof", "estimator_ok", "slip_available"]
    return cols


def passthrough_columns(n_wheels: int, available: list[str] | None = None) -> list[str]:
    """Run-table columns copied into the EST table (contract 2), restricted to ``available``."""
    cols = [f"wheel{i}_{s}" for i in range(1, n_wheels + 1) for s in PASS_WHEEL]
    cols += list(PASS_BASE)
    cols += [f"{g}_valid" for g in VALID_GROUPS]
    cols += ["terrain", "run_id"]
    if available is None:
        return cols
    avail = set(available)
    out = [c for c in cols if c in avail]
    out += [c for c in available if c.startswith("gt_") and c not in out]
    return out


class OnlineEstimator:
    """EKF + slip + dynamic state, one tick at a time.

    Parameters
    ----------
    robot : RobotSpec, name or path (None: reference robot).
    preset : ``"thesis"``, ``"robust"`` or an :class:`~terrainml.estimation.ekf.EkfPreset`.
    has_imu_yaw, has_cam_yaw : whether the yaw rows exist (the run table may lack the optional
        ``imu_yaw_rad`` / ``cam_yaw_rad`` columns; rows are then simply dropped every tick).
    theta, dwell_s : dynamic-state threshold (m^2/s^3) and minimum dwell (s), SYSTEM §7.2.
    accel_tau_s : time constant (s) of each stage of the manoeuvre filter
        (:class:`~terrainml.estimation.dynamic_state.ManoeuvreFilter`) on the EKF acceleration
        used for the wheel Power. theta = 0.02 m^2/s^3 is ~0.02 m/s^2 at 1 m/s, below the IMU's
        noise and terrain vibration; without smoothing the state chatters or freezes
        (*departure*: SYSTEM §7.2 does not filter the acceleration).

    Examples
    --------
    >>> est = OnlineEstimator("agrimaro", "robust")
    >>> row = est.step({"t_s": 0.0, "wheel1_omega_radps": 0.0, ...})  # doctest: +SKIP
    >>> row["slip1"], row["state1"], row["estimator_ok"]  # doctest: +SKIP
    """

    def __init__(self, robot: RobotSpec | str | None = None, preset: str | EkfPreset = "robust", *,
                 has_imu_yaw: bool = True, has_cam_yaw: bool = True,
                 theta: float = THETA_M2PS3, dwell_s: float = DWELL_S,
                 accel_tau_s: float = ACCEL_TAU_S) -> None:
        self.robot = load_robot(robot)
        self.preset = get_preset(preset)
        self.model = PlanarModel(self.robot, has_imu_yaw=has_imu_yaw, has_cam_yaw=has_cam_yaw)
        self.ekf = Ekf(self.model, self.preset)
        rows = self.model.rows
        p = self.preset
        N = self.robot.n_wheels
        self.n_wheels = N
        self.row_columns = [r.column for r in rows]
        self.row_groups = [r.group for r in rows]
        self.group_names = sorted(set(self.row_groups))
        self._group_of_row = np.array([self.group_names.index(g) for g in self.row_groups])
        alpha = {"wheel": p.alpha_wheel, "steer": p.alpha_steer}
        self._alpha = np.array([alpha.get(r.kind, p.alpha_cam if r.group == "cam" else p.alpha_imu)
                                for r in rows])
        self._angle = np.array([r.angle for r in rows], dtype=bool)
        self._is_wheel = np.array([r.kind == "wheel" for r in rows], dtype=bool)
        self._is_cam = np.array([r.group == "cam" for r in rows], dtype=bool)
        self._yaw_rows = np.flatnonzero(self._angle)
        self._yaw_rows_l = [int(k) for k in self._yaw_rows]
        r_of = {"wheel": p.r_wheel, "imu_ax": p.r_imu_acc, "imu_ay": p.r_imu_acc,
                "imu_rate": p.r_imu_rate, "imu_yaw": p.r_imu_yaw, "steer": p.r_steer,
                "cam_vx": p.r_cam_vel, "cam_vy": p.r_cam_vel, "cam_rate": p.r_cam_rate,
                "cam_yaw": p.r_cam_yaw}
        self._r_base = np.array([r_of[r.kind] for r in rows])
        self._r_cam_ok = self._r_base.copy()
        if p.r_wheel_cam_ok is not None:
            self._r_cam_ok[self._is_wheel] = p.r_wheel_cam_ok
        self._z_f = np.full(len(rows), np.nan)  # pre-filter memory
        self._yaw_offset = np.full(len(rows), np.nan)  # yaw zeroed at the first valid sample
        self._prev_valid = np.zeros(len(rows), dtype=bool)
        self._last_seen = {g: -math.inf for g in ("wheels", "imu", "cam", "steer")}
        self._t_prev: float | None = None
        self._lag = EncoderLag(N, p.encoder_lag_s)
        self._sm = WheelStateMachine(N, theta, dwell_s)
        self._accel_filter = ManoeuvreFilter(accel_tau_s)  # manoeuvre (ax, ay)
        self._wx = self.model.wheel_xy_m[:, 0].copy()
        self._wy = self.model.wheel_xy_m[:, 1].copy()
        self._radius = self.robot.wheel_radius_m
        self._steer_state = self.model.steer_state
        self._steer_mask = self._steer_state >= 0
        self._steer_idx = self._steer_state[self._steer_mask]
        self._any_steer = bool(self._steer_mask.any())
        self._any_alpha = bool(np.any(self._alpha > 0))
        self._one_minus_alpha = 1.0 - self._alpha
        self._not_wheel = ~self._is_wheel
        self._has_cam = self.robot.has_camera
        self._valid_keys = [(g, f"{g}_valid") for g in ("wheels", "imu", "cam", "steer")]
        self._group_rows = {g: [k for k, rg in enumerate(self.row_groups) if rg == g]
                            for g in ("wheels", "imu", "cam", "steer")}
        self._omega_cols = [f"wheel{i}_omega_radps" for i in range(1, N + 1)]
        self._pass_cols = passthrough_columns(N)
        self._copy_cache: dict = {}
        self._cam_ok_prev = False
        self._slip_mem = np.zeros(N)  # low-passed slip while the camera is healthy
        self._slip_mem_age = 0.0  # seconds of slip observations behind it
        # outputs of the last tick
        self.steer = np.zeros(N)
        self.v_long = np.zeros(N)
        self.slip = np.full(N, np.nan)
        self.state = np.zeros(N, dtype=np.int8)
        self.estimator_ok = False
        self.slip_available = False
        self.t_s = float("nan")

    # ----------------------------------------------------------------- core (shared offline/online)
    def core(self, t_s: float, z_raw: np.ndarray, row_valid: np.ndarray, omega_radps: np.ndarray,
             group_valid: Mapping[str, bool]) -> None:
        """Advance one tick.

        Parameters
        ----------
        t_s : tick time (s).
        z_raw : (m,) raw measurement per EKF row (order of ``self.row_columns``).
        row_valid : (m,) bool, row has a fresh finite sample this tick.
        omega_radps : (N,) raw wheel speeds (for slip; NaN where invalid).
        group_valid : validity of the groups ``wheels``, ``imu``, ``cam``, ``steer`` this tick.
        """
        p = self.preset
        ekf = self.ekf
        for g, ok in group_valid.items():
            if ok:
                self._last_seen[g] = t_s
        # ------------------------------------------------ predict
        if self._t_prev is not None:
            dt = t_s - self._t_prev
            if dt > 0.0:
                ekf.predict(dt)
        else:
            dt = 0.0
        self._t_prev = t_s
        # ------------------------------------------------ measurements: yaw zeroing, pre-filters
        z = z_raw.copy()
        use = row_valid.copy()
        for k in self._yaw_rows_l:
            if use[k]:
                if math.isnan(self._yaw_offset[k]):
                    self._yaw_offset[k] = z[k]
                z[k] = (z[k] - self._yaw_offset[k] + math.pi) % TWO_PI - math.pi
        if self._any_alpha:
            fresh = use & ~self._prev_valid  # first sample after a gap: restart the EMA
            zf = self._z_f
            d = z - zf
            if self._yaw_rows.size:
                d[self._yaw_rows] = (d[self._yaw_rows] + math.pi) % TWO_PI - math.pi
            new = zf + self._one_minus_alpha * d  # z_new = alpha z_prev + (1 - alpha) z_raw (eq. 6.12)
            new[fresh] = z[fresh]
            zf[use] = new[use]
            self._prev_valid = use
            z = zf
        # ------------------------------------------------ update
        cam_ok = self._has_cam and (t_s - self._last_seen["cam"] <= p.cam_timeout_s)
        r_diag = self._r_cam_ok if cam_ok else self._r_base
        comp = (not cam_ok and self._has_cam and p.fallback_slip_comp
                and self._slip_mem_age >= p.slip_memory_tau_s)
        if comp:
            # slip-compensated wheel rows: the wheel speed the remembered slip implies on the ground
            sm = self._slip_mem
            zw = z[:self.n_wheels] if z is not z_raw else z[:self.n_wheels].copy()
            z = z.copy()
            z[:self.n_wheels] = np.where(sm >= 0.0, zw * (1.0 - sm), zw / (1.0 + sm))
        if not cam_ok and self._has_cam and p.r_wheel_fallback_start is not None:
            # adaptive wheel variance in fallback: r_start -> r_wheel geometrically over the ramp
            gap = t_s - self._last_seen["cam"]
            frac = max(0.0, 1.0 - gap / p.fallback_ramp_s) if math.isfinite(gap) else 0.0
            r_diag = self._r_base.copy()
            r_start = p.r_wheel_fallback_start if comp else R_WHEEL_UNCOMPENSATED
            r_diag[self._is_wheel] = p.r_wheel * (r_start / p.r_wheel) ** frac
        if cam_ok and p.drop_wheels_when_cam_ok:
            use &= self._not_wheel  # zero-slip rows would bias v toward wheel odometry
        # no gate on the first camera sample after a gap (the prediction is the stale part)
        ekf.update(z, use, r_diag, gate_enabled=self._cam_ok_prev or not cam_ok)
        self._cam_ok_prev = cam_ok
        # ------------------------------------------------ slip and dynamic state
        x = ekf.x
        steer = self.steer
        if self._any_steer:
            steer[self._steer_mask] = x[self._steer_idx]
        c, s = np.cos(steer), np.sin(steer)
        vx, vy, r = x[I_VX], x[I_VY], x[I_R]
        v_long = (vx - r * self._wy) * c + (vy + r * self._wx) * s  # eq. 7.3-7.5
        self.v_long = v_long
        v_long_lag = self._lag(v_long, dt)  # in phase with the filtered encoder
        self.slip_available = bool(cam_ok)
        if cam_ok:
            self.slip = np.array(slip_ratio_tick(omega_radps * self._radius, v_long_lag, DEAD_BAND_MPS))
            if p.fallback_slip_comp and dt > 0.0:  # remember the slip for a camera gap
                g = 1.0 - math.exp(-dt / p.slip_memory_tau_s)
                ok = np.isfinite(self.slip) & (np.abs(v_long) >= 0.2)
                self._slip_mem = np.where(ok, self._slip_mem + g * (np.clip(self.slip, -0.95, 0.95) - self._slip_mem),
                                          self._slip_mem)
                if ok.all():
                    self._slip_mem_age += dt
        else:
            self.slip = np.full(self.n_wheels, np.nan)  # no camera: slip is unobservable
        ax, ay = float(x[I_AX]), float(x[I_AY])
        ax_f, ay_f = self._accel_filter.step_pair(t_s, ax, ay)
        r2 = r * r
        a_long = (ax_f - r2 * self._wx) * c + (ay_f - r2 * self._wy) * s
        self.state = self._sm.step(t_s, a_long * v_long, v_long)
        # ------------------------------------------------ health
        last = self._last_seen
        tmo = p.sensor_timeout_s
        fresh_ok = (t_s - last["wheels"] <= tmo and t_s - last["imu"] <= tmo
                    and (cam_ok or not self._has_cam))
        pmax = ekf.P.diagonal().max()
        sane = (abs(vx) < MAX_SPEED_MPS and abs(vy) < MAX_SPEED_MPS and pmax < MAX_P_DIAG
                and math.isfinite(pmax) and math.isfinite(x.sum()))
        self.estimator_ok = bool(fresh_ok and sane)
        self.t_s = t_s

    # ----------------------------------------------------------------- online API
    def step(self, sample: Mapping[str, Any]) -> dict[str, Any]:
        """Process one sample (canonical column names + ``t_s``); return one EST row as a dict."""
        t = float(sample["t_s"])
        gvalid = {g: bool(sample.get(key, True)) for g, key in self._valid_keys}
        z = [_f(sample.get(col)) for col in self.row_columns]
        valid_l = [gvalid[g] and v == v and abs(v) != math.inf for v, g in zip(z, self.row_groups)]
        # a group counts as "seen" when at least one of its rows is usable
        seen = {g: any(valid_l[k] for k in idx) for g, idx in self._group_rows.items()}
        if gvalid["wheels"]:
            omega = np.array([_f(sample.get(c)) for c in self._omega_cols])
        else:
            omega = np.full(self.n_wheels, np.nan)
        self.core(t, np.array(z), np.array(valid_l, dtype=bool), omega, seen)
        row = self.row()
        keys = tuple(sample)
        copy = self._copy_cache.get(keys)
        if copy is None:  # which keys to pass through (cached per key layout)
            wanted = set(self._pass_cols)
            copy = [k for k in keys if k in wanted or k.startswith("gt_")]
            self._copy_cache = {keys: copy}
        for key in copy:
            row[key] = sample[key]
        return row

    def row(self) -> dict[str, Any]:
        """The EST columns of the last tick as a dict."""
        x = self.ekf.x
        out: dict[str, Any] = {
            "t_s": self.t_s, "ekf_x_m": float(x[I_X]), "ekf_y_m": float(x[I_Y]),
            "ekf_yaw_rad": float(x[I_PSI]), "ekf_vx_mps": float(x[I_VX]), "ekf_vy_mps": float(x[I_VY]),
            "ekf_yaw_rate_radps": float(x[I_R]), "ekf_ax_mps2": float(x[I_AX]),
            "ekf_ay_mps2": float(x[I_AY]),
        }
        N = self.n_wheels
        for i in range(N):
            out[f"ekf_steer{i + 1}_rad"] = float(self.steer[i])
        out["ekf_gyro_bias_radps"] = float(x[self.model.i_bias])
        for i in range(N):
            out[f"slip{i + 1}"] = float(self.slip[i])
        for i in range(N):
            out[f"state{i + 1}"] = WHEEL_STATES[int(self.state[i])]
        for i in range(N):
            out[f"v_long{i + 1}_mps"] = float(self.v_long[i])
        out["nis"] = float(self.ekf.nis)
        out["nis_dof"] = int(self.ekf.nis_dof)
        out["estimator_ok"] = bool(self.estimator_ok)
        out["slip_available"] = bool(self.slip_available)
        return out


def _f(v: Any) -> float:
    return float("nan") if v is None else float(v)
