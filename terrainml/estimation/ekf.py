"""Planar EKF of SYSTEM §7 (thesis §6.1), generalised to any :class:`~terrainml.robot.RobotSpec`.

State (body frame ``body``: x forward, y left; world frame fixed at the start pose)::

    x = [X, Y, psi, vx, vy, r, ax, ay, delta_1 .. delta_Ns, bg]

``r`` is the yaw rate, ``(ax, ay)`` the inertial acceleration of the body origin in body axes
(what an IMU at the origin measures on level ground), ``delta_j`` the steering angle of the
j-th *steerable* wheel and ``bg`` the gyro bias. A robot without steerable wheels (skid steer,
Husky) has no steering states: their angles are fixed at 0 (thesis: 12 states for 3 steerable
wheels; here ``n = 9 + Ns``).

Process model ``f`` (sampling time T), SYSTEM §7 (signs of thesis eq. 4.33-4.34, *not* 6.2)::

    X'   = X + T (vx cos psi - vy sin psi)      Y' = Y + T (vx sin psi + vy cos psi)
    psi' = psi + T r
    vx'  = vx + T (ax + r vy)                   vy' = vy + T (ay - r vx)
    r' = r, ax' = ax, ay' = ay, delta' = delta, bg' = bg          (random walks)

Measurement model ``h`` (rows of sensors the robot lacks are absent; rows whose sensor has no
valid sample this tick are dropped from the update)::

    w_i     = ((vx - r y_i) cos d_i + (vy + r x_i) sin d_i) / R_w     (zero-slip wheel, eq. 4.46)
    ax_imu  = ax,   ay_imu = ay,   r_imu = r + bg,   psi_imu = psi
    d_j     = delta_j                                                  (steering encoders)
    vx_cam  = vx - r y_c,  vy_cam = vy + r x_c,  r_cam = r,  psi_cam = psi   (lever arm, eq. 6.6)

The filter is written filterpy-style: ``x`` and ``P`` are plain arrays and :meth:`Ekf.predict`
/ :meth:`Ekf.update` follow the textbook equations line by line. With numba they run compiled
(:mod:`terrainml.estimation._kernel`, the same equations as loops that visit only the nonzeros
of F and H); :meth:`Ekf.step` runs both in one compiled call and :meth:`Ekf.batch_filter` a
whole table without Python between ticks.

Presets (:data:`PRESETS`)
-------------------------
``thesis``  P0 eq. 6.9, R eq. 6.13, Q eq. 6.14, EMA pre-filters (alpha 0.1 IMU and steering,
            0.2 camera, none on wheel speeds; eq. 6.12 and §7.2.2). Q is the thesis's per-tick
            value at 100 Hz and is scaled by ``dt / 0.01`` for other tick lengths.
``robust``  Beyond the thesis. The zero-slip wheel rows pull the velocity toward wheel odometry
            on soft ground (thesis §4.6), which biases slip toward 0. ``robust`` therefore
            (1) drops the wheel rows while the camera is healthy, and falls back to them when the
            camera has been silent for ``cam_timeout_s``, corrected by the slip measured before
            the gap, with a variance that starts larger and decays to the thesis value over 10 s;
            (2) rejects individual camera and IMU-acceleration rows whose normalised innovation
            exceeds a chi-square gate (camera glitches, vibration spikes), released after 3
            consecutive gated ticks so a wrong prediction cannot lock the camera out; (3) uses a
            process noise tuned for 100 Hz (accelerations as random walks, small velocity noise)
            so the IMU carries the velocity between camera samples instead of the wheels; (4) no
            EMA pre-filters (they only add lag); (5) compensates the wheel-encoder lag when
            forming slip (see ``slip.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.linalg.lapack import dpotrf as _dpotrf
from scipy.linalg.lapack import dpotrs as _dpotrs

from terrainml.robot import RobotSpec

# indices of the fixed part of the state
I_X, I_Y, I_PSI, I_VX, I_VY, I_R, I_AX, I_AY = range(8)
N_BASE = 8  # states before the steering angles
NOMINAL_DT_S = 0.01  # tick length the per-tick Q values refer to (thesis: 100 Hz)

TWO_PI = 2.0 * math.pi


def wrap_angle(a):
    """Wrap angle(s) to (-pi, pi] (rad). Works on scalars and arrays."""
    w = np.mod(np.asarray(a, dtype=float) + math.pi, TWO_PI) - math.pi
    w = np.where(w == -math.pi, math.pi, w)
    return float(w) if np.ndim(w) == 0 else w


def _wrap_scalar(a: float) -> float:
    w = (a + math.pi) % TWO_PI - math.pi
    return math.pi if w == -math.pi else w


# --------------------------------------------------------------------- presets
@dataclass(frozen=True)
class EkfPreset:
    """Tuning of the filter. Variances are per tick at 100 Hz (Q) or per sample (R, P0).

    Attributes (units: the square of the quantity's unit)
    ----------
    p0_* : initial covariance diagonal (eq. 6.9).
    q_* : process noise per 0.01 s tick (eq. 6.14).
    r_* : measurement noise (eq. 6.13); ``r_wheel`` in (rad/s)^2.
    r_wheel_cam_ok : wheel-row variance while the camera is healthy; ``None`` means always
        ``r_wheel``.
    drop_wheels_when_cam_ok : drop the zero-slip wheel rows while the camera is healthy
        (``robust``); they return, with ``r_wheel``, as the fallback when it is not.
    alpha_* : EMA pre-filter constants ``z = alpha z_prev + (1 - alpha) z_raw`` (eq. 6.12).
    r_wheel_fallback_start : wheel-row variance right after the camera is lost; it decays
        geometrically to ``r_wheel`` over ``fallback_ramp_s`` (short gaps are bridged by the
        IMU, long ones by the wheels). ``None``: ``r_wheel`` at once.
    fallback_slip_comp : in fallback, correct each wheel speed by the slip last measured while
        the camera was healthy (low-passed with ``slip_memory_tau_s``) before it enters the
        zero-slip row: ``omega (1 - s)`` in traction, ``omega / (1 + s)`` in braking.
    cam_gate_chi2 : per-row gate on camera rows (``y^2 / S_ii``); ``None`` disables gating.
    gate_imu_acc : gate the IMU acceleration rows as well.
    cam_gate_max_ticks : after this many consecutive ticks with a gated camera row the gate is
        released for one tick (a glitch lasts 1-3 samples; a longer disagreement means the
        prediction, not the camera, is wrong, and the filter must not lock the camera out).
    cam_timeout_s : camera considered unhealthy after this long without a valid sample.
    encoder_lag_s : first-order lag applied to v_long before the slip formula so it is in
        phase with the (filtered) wheel encoder; 0 disables.
    """

    name: str
    # P0 (eq. 6.9)
    p0_pose: float = 1e-5
    p0_vel: float = 1e-5
    p0_acc: float = 1e-5
    p0_steer: float = 1.5e-4
    p0_bias: float = 1e-4
    # Q per 0.01 s tick (eq. 6.14)
    q_xy: float = 0.5
    q_psi: float = 0.08
    q_vxy: float = 0.08
    q_r: float = 0.15
    q_acc: float = 0.12
    q_steer: float = 0.002
    q_bias: float = 0.002
    # R (eq. 6.13)
    r_wheel: float = 0.05
    r_imu_acc: float = 0.001
    r_imu_rate: float = 0.001
    r_imu_yaw: float = 0.01
    r_steer: float = 1e-5
    r_cam_vel: float = 5e-5
    r_cam_rate: float = 0.001
    r_cam_yaw: float = 0.0005
    # robustness
    r_wheel_cam_ok: float | None = None
    drop_wheels_when_cam_ok: bool = False
    r_wheel_fallback_start: float | None = None
    fallback_ramp_s: float = 3.0
    fallback_slip_comp: bool = False
    slip_memory_tau_s: float = 1.0
    cam_gate_chi2: float | None = None
    cam_gate_max_ticks: int = 3
    gate_imu_acc: bool = False
    cam_timeout_s: float = 0.2
    encoder_lag_s: float = 0.0
    # pre-filters (eq. 6.12, §7.2.2)
    alpha_imu: float = 0.1
    alpha_steer: float = 0.1
    alpha_cam: float = 0.2
    alpha_wheel: float = 0.0
    # health
    sensor_timeout_s: float = 0.2

    def with_(self, **kw: Any) -> "EkfPreset":
        """A copy with some fields changed (``preset.with_(r_wheel=0.1)``)."""
        return replace(self, **kw)


THESIS = EkfPreset(name="thesis")

ROBUST = EkfPreset(
    name="robust",
    q_xy=1e-6, q_psi=1e-6, q_vxy=2e-5, q_r=2e-3, q_acc=0.02, q_steer=1e-3, q_bias=1e-9,
    r_wheel=0.05, drop_wheels_when_cam_ok=True, r_wheel_fallback_start=0.5, fallback_ramp_s=10.0,
    fallback_slip_comp=True, slip_memory_tau_s=1.0,
    r_imu_acc=0.01, r_imu_rate=1e-4, r_imu_yaw=0.01,
    r_steer=1e-5, r_cam_vel=1e-4, r_cam_rate=1e-3, r_cam_yaw=5e-4,
    cam_gate_chi2=25.0, cam_timeout_s=0.2, encoder_lag_s=0.04,
    alpha_imu=0.0, alpha_steer=0.0, alpha_cam=0.0, alpha_wheel=0.0,
)

PRESETS: dict[str, EkfPreset] = {"thesis": THESIS, "robust": ROBUST}


def get_preset(preset: str | EkfPreset) -> EkfPreset:
    """Return a preset by name (``thesis`` | ``robust``) or pass an :class:`EkfPreset` through."""
    if isinstance(preset, EkfPreset):
        return preset
    try:
        return PRESETS[str(preset)]
    except KeyError:
        raise ValueError(f"unknown EKF preset {preset!r}; expected one of: {', '.join(PRESETS)}") from None


# --------------------------------------------------------------------- model
@dataclass
class MeasurementRow:
    """One scalar measurement: its name, source column, validity group and kind."""

    name: str
    column: str
    group: str
    kind: str  # wheel | imu_ax | imu_ay | imu_rate | imu_yaw | steer | cam_vx | cam_vy | cam_rate | cam_yaw
    wheel: int = -1  # wheel index (0-based) for wheel/steer rows
    angle: bool = False


@dataclass
class PlanarModel:
    """State layout and measurement rows of the EKF for one robot.

    Attributes
    ----------
    n : int, number of states (9 + number of steerable wheels).
    rows : list of MeasurementRow, every measurement the robot *can* provide, in a fixed order.
    steer_state : array (N,), state index of each wheel's steering angle, -1 for fixed wheels.
    wheel_xy_m : array (N, 2), wheel contact-centre positions in the body frame (m).
    """

    robot: RobotSpec
    has_imu_yaw: bool = True
    has_cam_yaw: bool = True
    n: int = 0
    rows: list[MeasurementRow] = field(default_factory=list)
    steer_state: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    wheel_xy_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    i_bias: int = 0

    def __post_init__(self) -> None:
        robot = self.robot
        steerable = [k for k, w in enumerate(robot.wheels) if w.steerable]
        self.n = N_BASE + len(steerable) + 1
        self.i_bias = self.n - 1
        self.steer_state = np.full(robot.n_wheels, -1, dtype=int)
        for j, k in enumerate(steerable):
            self.steer_state[k] = N_BASE + j
        self.wheel_xy_m = np.array([[w.x_m, w.y_m] for w in robot.wheels], dtype=float)
        rows: list[MeasurementRow] = []
        for k in range(robot.n_wheels):
            rows.append(MeasurementRow(f"wheel{k + 1}_omega", f"wheel{k + 1}_omega_radps", "wheels", "wheel", k))
        rows += [MeasurementRow("imu_ax", "imu_ax_mps2", "imu", "imu_ax"),
                 MeasurementRow("imu_ay", "imu_ay_mps2", "imu", "imu_ay"),
                 MeasurementRow("imu_yaw_rate", "imu_yaw_rate_radps", "imu", "imu_rate")]
        if self.has_imu_yaw:
            rows.append(MeasurementRow("imu_yaw", "imu_yaw_rad", "imu", "imu_yaw", angle=True))
        for k in steerable:
            rows.append(MeasurementRow(f"steer{k + 1}", f"wheel{k + 1}_steer_rad", "steer", "steer", k))
        if robot.has_camera:
            rows += [MeasurementRow("cam_vx", "cam_vx_mps", "cam", "cam_vx"),
                     MeasurementRow("cam_vy", "cam_vy_mps", "cam", "cam_vy"),
                     MeasurementRow("cam_yaw_rate", "cam_yaw_rate_radps", "cam", "cam_rate")]
            if self.has_cam_yaw:
                rows.append(MeasurementRow("cam_yaw", "cam_yaw_rad", "cam", "cam_yaw", angle=True))
        self.rows = rows

    @property
    def m(self) -> int:
        return len(self.rows)

    @property
    def state_names(self) -> list[str]:
        names = ["X", "Y", "psi", "vx", "vy", "r", "ax", "ay"]
        names += [f"delta{k + 1}" for k in range(self.robot.n_wheels) if self.steer_state[k] >= 0]
        return names + ["bg"]

    # ----------------------------------------------------------------- reference f, h, F, H
    # Plain (allocating) versions: readable, used by tests and by the benchmark's filterpy run.
    def f(self, x: np.ndarray, dt: float) -> np.ndarray:
        """Process model f(x) for tick length ``dt`` (s)."""
        xn = x.copy()
        c, s = math.cos(x[I_PSI]), math.sin(x[I_PSI])
        vx, vy, r = x[I_VX], x[I_VY], x[I_R]
        xn[I_X] = x[I_X] + dt * (vx * c - vy * s)
        xn[I_Y] = x[I_Y] + dt * (vx * s + vy * c)
        xn[I_PSI] = x[I_PSI] + dt * r
        xn[I_VX] = vx + dt * (x[I_AX] + r * vy)
        xn[I_VY] = vy + dt * (x[I_AY] - r * vx)
        return xn

    def F(self, x: np.ndarray, dt: float) -> np.ndarray:
        """Jacobian df/dx, shape (n, n)."""
        F = np.eye(self.n)
        fill_F(F, x, dt)
        return F

    def steer_angles(self, x: np.ndarray) -> np.ndarray:
        """Steering angle of every wheel (rad), 0 for fixed wheels, shape (N,)."""
        d = np.zeros(self.robot.n_wheels)
        m = self.steer_state >= 0
        d[m] = x[self.steer_state[m]]
        return d

    def v_long(self, x: np.ndarray) -> np.ndarray:
        """Longitudinal velocity of every wheel centre (m/s), SYSTEM §7.1, shape (N,)."""
        d = self.steer_angles(x)
        u = x[I_VX] - x[I_R] * self.wheel_xy_m[:, 1]
        w = x[I_VY] + x[I_R] * self.wheel_xy_m[:, 0]
        return u * np.cos(d) + w * np.sin(d)

    def h(self, x: np.ndarray) -> np.ndarray:
        """Measurement model h(x) for every row, shape (m,)."""
        out = np.empty(self.m)
        vl = self.v_long(x)
        R = self.robot.wheel_radius_m
        cam = self.robot.camera
        for k, row in enumerate(self.rows):
            out[k] = {
                "wheel": lambda: vl[row.wheel] / R,
                "imu_ax": lambda: x[I_AX],
                "imu_ay": lambda: x[I_AY],
                "imu_rate": lambda: x[I_R] + x[self.i_bias],
                "imu_yaw": lambda: x[I_PSI],
                "steer": lambda: x[self.steer_state[row.wheel]],
                "cam_vx": lambda: x[I_VX] - x[I_R] * cam.y_m,
                "cam_vy": lambda: x[I_VY] + x[I_R] * cam.x_m,
                "cam_rate": lambda: x[I_R],
                "cam_yaw": lambda: x[I_PSI],
            }[row.kind]()
        return out

    def H(self, x: np.ndarray) -> np.ndarray:
        """Jacobian dh/dx for every row, shape (m, n)."""
        H = self.constant_H()
        fill_wheel_H(H, x, self._wheel_rows(), self.wheel_xy_m, self.steer_state,
                     self.robot.wheel_radius_m)
        return H

    # ----------------------------------------------------------------- helpers for the fast path
    def _wheel_rows(self) -> np.ndarray:
        return np.array([k for k, r in enumerate(self.rows) if r.kind == "wheel"], dtype=int)

    def constant_H(self) -> np.ndarray:
        """The state-independent entries of H (wheel rows left zero), shape (m, n)."""
        H = np.zeros((self.m, self.n))
        cam = self.robot.camera
        for k, row in enumerate(self.rows):
            if row.kind == "imu_ax":
                H[k, I_AX] = 1.0
            elif row.kind == "imu_ay":
                H[k, I_AY] = 1.0
            elif row.kind == "imu_rate":
                H[k, I_R] = 1.0
                H[k, self.i_bias] = 1.0
            elif row.kind in ("imu_yaw", "cam_yaw"):
                H[k, I_PSI] = 1.0
            elif row.kind == "steer":
                H[k, self.steer_state[row.wheel]] = 1.0
            elif row.kind == "cam_vx":
                H[k, I_VX] = 1.0
                H[k, I_R] = -cam.y_m
            elif row.kind == "cam_vy":
                H[k, I_VY] = 1.0
                H[k, I_R] = cam.x_m
            elif row.kind == "cam_rate":
                H[k, I_R] = 1.0
        return H


def fill_F(F: np.ndarray, x: np.ndarray, dt: float) -> None:
    """Write the state-dependent entries of F = df/dx into ``F`` (identity elsewhere).

    dX'/dpsi = -T (vx sin psi + vy cos psi), dX'/dvx = T cos psi, dX'/dvy = -T sin psi
    dY'/dpsi =  T (vx cos psi - vy sin psi), dY'/dvx = T sin psi, dY'/dvy =  T cos psi
    dpsi'/dr = T
    dvx'/dvy = T r, dvx'/dr = T vy, dvx'/dax = T
    dvy'/dvx = -T r, dvy'/dr = -T vx, dvy'/day = T
    """
    c, s = math.cos(x[I_PSI]), math.sin(x[I_PSI])
    vx, vy, r = x[I_VX], x[I_VY], x[I_R]
    F[I_X, I_PSI] = -dt * (vx * s + vy * c)
    F[I_X, I_VX] = dt * c
    F[I_X, I_VY] = -dt * s
    F[I_Y, I_PSI] = dt * (vx * c - vy * s)
    F[I_Y, I_VX] = dt * s
    F[I_Y, I_VY] = dt * c
    F[I_PSI, I_R] = dt
    F[I_VX, I_VY] = dt * r
    F[I_VX, I_R] = dt * vy
    F[I_VX, I_AX] = dt
    F[I_VY, I_VX] = -dt * r
    F[I_VY, I_R] = -dt * vx
    F[I_VY, I_AY] = dt


def fill_wheel_H(H: np.ndarray, x: np.ndarray, wheel_rows: np.ndarray, wheel_xy: np.ndarray,
                 steer_state: np.ndarray, radius_m: float) -> None:
    """Write the wheel rows of H (analytic derivatives of eq. 4.46).

    With u = vx - r y_i, w = vy + r x_i, c = cos d_i, s = sin d_i, h_i = (u c + w s) / R:
    dh/dvx = c / R, dh/dvy = s / R, dh/dr = (-y_i c + x_i s) / R, dh/dd_i = (-u s + w c) / R.
    The wheel rows are the first N rows of H (``PlanarModel`` puts them there).
    """
    nw = len(wheel_rows)
    steer = steer_state >= 0
    inv_r = 1.0 / radius_m
    if steer.any():
        d = np.zeros(nw)
        d[steer] = x[steer_state[steer]]
        c, s = np.cos(d), np.sin(d)
        u = x[I_VX] - x[I_R] * wheel_xy[:, 1]
        w = x[I_VY] + x[I_R] * wheel_xy[:, 0]
        H[:nw, I_VX] = c * inv_r
        H[:nw, I_VY] = s * inv_r
        H[:nw, I_R] = (wheel_xy[:, 0] * s - wheel_xy[:, 1] * c) * inv_r
        H[wheel_rows[steer], steer_state[steer]] = ((w * c - u * s) * inv_r)[steer]
    else:  # fixed wheels: d = 0, constant rows
        H[:nw, I_VX] = inv_r
        H[:nw, I_VY] = 0.0
        H[:nw, I_R] = -wheel_xy[:, 1] * inv_r


# --------------------------------------------------------------------- filter
class Ekf:
    """The EKF itself: ``x`` (n,), ``P`` (n, n), ``predict(dt)``, ``update(z, use, r_diag)``;
    ``step(dt, z, use, r_diag)`` (both, one tick) and ``batch_filter(t_s, z, use, r_diag)`` (a
    whole table).

    Parameters
    ----------
    model : PlanarModel, the robot's state and measurement layout.
    preset : EkfPreset or name.
    compiled : use the numba kernels (default: when numba is available); False: the numpy
        reference methods.

    Attributes
    ----------
    x : ndarray (n,), state estimate.
    P : ndarray (n, n), state covariance.
    y : ndarray (m,), last innovations (NaN for rows not used).
    S_diag : ndarray (m,), last innovation variances (NaN for rows not used).
    nis : float, last y^T S^-1 y; ``nis_dof`` its degrees of freedom (rows used).
    n_gated : int, rows rejected by the gate so far.
    """

    def __init__(self, model: PlanarModel, preset: str | EkfPreset = "robust",
                 compiled: bool | None = None) -> None:
        from terrainml.estimation import _kernel

        self._kernel = _kernel
        self.compiled = _kernel.HAVE_NUMBA if compiled is None else bool(compiled and _kernel.HAVE_NUMBA)
        self.model = model
        self.preset = p = get_preset(preset)
        n, m = model.n, model.m
        self.n, self.m = n, m
        steer_n = n - N_BASE - 1
        self.x = np.zeros(n)
        self.P = np.diag([p.p0_pose] * 3 + [p.p0_vel] * 3 + [p.p0_acc] * 2
                         + [p.p0_steer] * steer_n + [p.p0_bias]).astype(float)
        self.Q0 = np.diag([p.q_xy, p.q_xy, p.q_psi, p.q_vxy, p.q_vxy, p.q_r, p.q_acc, p.q_acc]
                          + [p.q_steer] * steer_n + [p.q_bias]).astype(float)
        self._I = np.eye(n)
        self._F = np.eye(n)
        self._tmp = np.empty((n, n))
        self._H_all = model.constant_H()
        self._h_all = np.zeros(m)
        self._wheel_rows = model._wheel_rows()
        self._n_wheel_rows = len(self._wheel_rows)
        assert np.array_equal(self._wheel_rows, np.arange(self._n_wheel_rows))  # wheel rows first
        self._wheel_xy = model.wheel_xy_m
        self._steer_state = model.steer_state
        self._steer_mask = self._steer_state >= 0
        self._radius = model.robot.wheel_radius_m
        kinds = [r.kind for r in model.rows]
        self._angle_rows = np.array([r.angle for r in model.rows], dtype=bool)
        self._angle_idx = np.flatnonzero(self._angle_rows)
        # constant parts of h(x) as index maps: h = x[src] (+ x[src2] * coef) for non-wheel rows
        self._lin_rows = np.array([k for k, kd in enumerate(kinds) if kd != "wheel"], dtype=int)
        Hl = self._H_all[self._lin_rows]
        self._H_lin = Hl  # h_lin = H_lin @ x  (all non-wheel rows are linear in x)
        self._cam_rows = np.array([r.group == "cam" for r in model.rows], dtype=bool)
        self.y = np.full(m, np.nan)
        self.S_diag = np.full(m, np.nan)
        self.nis = float("nan")
        self.nis_dof = 0
        # gate memory, shared with the compiled kernels: [rows gated so far, consecutive ticks
        # with a gated row, gate released (0/1)]
        self._gate_state = np.zeros(3, dtype=np.int64)
        self._gate_chi2 = 0.0 if p.cam_gate_chi2 is None else float(p.cam_gate_chi2)
        self._gated_rows = np.array([r.group == "cam" or (p.gate_imu_acc and r.kind in ("imu_ax", "imu_ay"))
                                     for r in model.rows], dtype=bool)
        # sparsity of F and H for the compiled kernels: the columns each row can be nonzero in
        # (F probed at a generic state; H: v, r and the wheel's steering angle for wheel rows)
        F_probe = np.eye(n)
        fill_F(F_probe, 0.1 + np.arange(n) * 0.37, 1.0)
        self._F_nz, self._F_nnz = _nonzero_columns(F_probe != 0.0)
        H_mask = self._H_all != 0.0
        for i in range(self._n_wheel_rows):
            H_mask[i, [I_VX, I_VY, I_R]] = True
            if self._steer_state[i] >= 0:
                H_mask[i, self._steer_state[i]] = True
        self._H_nz, self._H_nnz = _nonzero_columns(H_mask)

    # gate memory (readable names for the entries of _gate_state)
    @property
    def n_gated(self) -> int:
        """Rows rejected by the gate since the filter started."""
        return int(self._gate_state[0])

    @n_gated.setter
    def n_gated(self, value: int) -> None:
        self._gate_state[0] = value

    @property
    def _gated_run(self) -> int:  # consecutive ticks with a gated row
        return int(self._gate_state[1])

    @_gated_run.setter
    def _gated_run(self, value: int) -> None:
        self._gate_state[1] = value

    @property
    def _gate_release(self) -> bool:  # gate released after a long disagreement
        return bool(self._gate_state[2])

    @_gate_release.setter
    def _gate_release(self, value: bool) -> None:
        self._gate_state[2] = int(value)

    # ----------------------------------------------------------------- predict
    def predict(self, dt: float) -> None:
        """x = f(x);  P = F P F^T + Q (dt / 0.01)."""
        if self.compiled:  # same equations, compiled (terrainml.estimation._kernel)
            self._kernel.predict_kernel(self.x, self.P, self.Q0, dt, dt / NOMINAL_DT_S, self._F, self._F_nz,
                                        self._F_nnz, self._tmp)
            return
        x, F = self.x, self._F
        fill_F(F, x, dt)  # Jacobian at the prior mean, before x moves
        c, s = math.cos(x[I_PSI]), math.sin(x[I_PSI])
        vx, vy, r = x[I_VX], x[I_VY], x[I_R]
        x[I_X] += dt * (vx * c - vy * s)  # X' = X + T (vx cos psi - vy sin psi)
        x[I_Y] += dt * (vx * s + vy * c)  # Y' = Y + T (vx sin psi + vy cos psi)
        x[I_PSI] = _wrap_scalar(x[I_PSI] + dt * r)  # psi' = psi + T r
        x[I_VX] = vx + dt * (x[I_AX] + r * vy)  # vx' = vx + T (ax + r vy)
        x[I_VY] = vy + dt * (x[I_AY] - r * vx)  # vy' = vy + T (ay - r vx)
        # r, ax, ay, delta, bg: random walks (x' = x)
        P = F @ self.P @ F.T  # P = F P F^T + Q
        P += self.Q0 * (dt / NOMINAL_DT_S)
        self.P = P

    # ----------------------------------------------------------------- h and H
    def h_and_H(self, wheels: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """h(x) and H = dh/dx at the current (prior) state for every row.

        ``wheels=False`` skips the (state-dependent) wheel rows when none is used this tick.
        """
        x, H, h = self.x, self._H_all, self._h_all
        if wheels:
            fill_wheel_H(H, x, self._wheel_rows, self._wheel_xy, self._steer_state, self._radius)
            # wheel rows: h_i = v_long_i / R = H_i[vx, vy, r] . x[vx, vy, r] (exactly linear in v, r)
            nw = self._n_wheel_rows
            h[:nw] = H[:nw, I_VX:I_R + 1] @ x[I_VX:I_R + 1]
        h[self._lin_rows] = self._H_lin @ x
        return h, H

    # ----------------------------------------------------------------- update
    def update(self, z: np.ndarray, use: np.ndarray, r_diag: np.ndarray, gate_enabled: bool = True) -> None:
        """Joseph-form update with the rows ``use`` (bool, (m,)) of z (m,) and R = diag(r_diag).

        With ``preset.cam_gate_chi2`` set, camera and IMU-acceleration rows whose normalised
        innovation exceeds it are dropped for the tick (``gate_enabled=False`` skips the gate,
        e.g. on the first camera sample after a gap). After ``cam_gate_max_ticks`` consecutive
        gated ticks the gate is released until prediction and sensors agree again.

        y = z - h(x) (angles wrapped);  S = H P H^T + R;  K = P H^T S^-1
        x = x + K y;  P = (I - K H) P (I - K H)^T + K R K^T;  NIS = y^T S^-1 y
        """
        if self.compiled and self._update_compiled(z, use, r_diag, gate_enabled):
            return
        self._update_numpy(z, use, r_diag, gate_enabled)

    def _update_numpy(self, z: np.ndarray, use: np.ndarray, r_diag: np.ndarray, gate_enabled: bool) -> None:
        """:meth:`update` in numpy (the reference; also the fallback of the compiled kernel)."""
        self.y.fill(np.nan)
        self.S_diag.fill(np.nan)
        idx = np.flatnonzero(use)
        if idx.size == 0:
            self.nis, self.nis_dof = float("nan"), 0
            return
        h_all, H_all = self.h_and_H(wheels=bool(idx[0] < self._n_wheel_rows))
        y_all = z - h_all
        ang = self._angle_idx
        if len(ang):
            y_all[ang] = np.mod(y_all[ang] + math.pi, TWO_PI) - math.pi  # wrapped angle innovations
        P = self.P
        gate = self.preset.cam_gate_chi2 if gate_enabled else None
        gated_now = False
        for _ in range(2):
            H = H_all[idx]
            y = y_all[idx]
            r = r_diag[idx]
            k = len(y)
            HP = H @ P  # H P              (k, n)
            S = HP @ H.T  # S = H P H^T + R  (k, k)
            S.flat[:: k + 1] += r
            if gate is None:
                break
            # per-row chi-square gate on camera (and IMU acceleration) rows: y_k^2 / S_kk > gate
            bad = self._gated_rows[idx] & (y * y > gate * S.diagonal())
            if not bad.any():
                self._gate_release = False  # prediction and sensors agree again
                break
            if self._gate_release:
                break  # released: a long disagreement means the prediction is wrong, not the sensor
            gated_now = True
            self.n_gated += int(bad.sum())
            idx = idx[~bad]
            if idx.size == 0:
                break
            gate = None  # the remaining rows are used as they are
        self._gated_run = self._gated_run + 1 if gated_now else 0
        if self._gated_run > self.preset.cam_gate_max_ticks:
            self._gate_release = True
            self._gated_run = 0
        if idx.size == 0:
            self.nis, self.nis_dof = float("nan"), 0
            return
        rhs = np.empty((k, self.n + 1))
        rhs[:, :-1] = HP
        rhs[:, -1] = y
        L, info = _dpotrf(S, lower=1, clean=0)
        if info == 0:
            sol, info = _dpotrs(L, rhs, lower=1)
        if info != 0:  # not positive definite (should not happen): least-squares fallback
            sol = np.linalg.lstsq(S, rhs, rcond=None)[0]
        K = sol[:, :-1].T  # Kalman gain     (n, k)
        self.x += K @ y  # x = x + K y
        self.x[I_PSI] = _wrap_scalar(self.x[I_PSI])
        A = self._I - K @ H  # Joseph form: P = (I - K H) P (I - K H)^T + K R K^T
        P = A @ P @ A.T + (K * r) @ K.T
        self.P = 0.5 * (P + P.T)  # keep exact symmetry against round-off
        self.nis = float(y @ sol[:, -1])  # NIS = y^T S^-1 y
        self.nis_dof = k
        self.y[idx] = y
        self.S_diag[idx] = S.diagonal()

    def _update_compiled(self, z: np.ndarray, use: np.ndarray, r_diag: np.ndarray, gate_enabled: bool) -> bool:
        """The same update through the compiled kernel; False if it could not (S not PD)."""
        nis, dof = self._kernel.update_kernel(
            self.x, self.P, self._H_all, self._H_nz, self._H_nnz, z, use, r_diag, self._angle_rows,
            self._gated_rows, self._gate_chi2 if gate_enabled else 0.0, self.preset.cam_gate_max_ticks,
            self._gate_state, self._n_wheel_rows, self._wheel_xy, self._steer_state, self._radius,
            self.y, self.S_diag)
        if dof < 0:  # Cholesky failed (x, P and the gate untouched): let the numpy path handle it
            return False
        self.nis = nis
        self.nis_dof = dof
        return True

    # ----------------------------------------------------------------- one tick, a whole table
    def step(self, dt: float, z: np.ndarray, use: np.ndarray, r_diag: np.ndarray,
             gate_enabled: bool = True) -> None:
        """:meth:`predict` over ``dt`` (skipped when ``dt <= 0``), then :meth:`update`.

        Compiled, both run in one call (the online tick pays one dispatch instead of two).
        """
        if self.compiled:
            nis, dof = self._kernel.step_kernel(
                self.x, self.P, self.Q0, dt, NOMINAL_DT_S, self._F, self._F_nz, self._F_nnz, self._tmp,
                self._H_all, self._H_nz, self._H_nnz, z, use, r_diag, self._angle_rows, self._gated_rows,
                self._gate_chi2 if gate_enabled else 0.0, self.preset.cam_gate_max_ticks, self._gate_state,
                self._n_wheel_rows, self._wheel_xy, self._steer_state, self._radius, self.y, self.S_diag)
            if dof >= 0:
                self.nis = nis
                self.nis_dof = dof
            else:  # S not PD (predict done, update not): the numpy update decides
                self._update_numpy(z, use, r_diag, gate_enabled)
            return
        if dt > 0.0:
            self.predict(dt)
        self.update(z, use, r_diag, gate_enabled)

    def batch_filter(self, t_s: np.ndarray, z: np.ndarray, use: np.ndarray, r_diag: np.ndarray,
                     gate_enabled: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Filter a whole table: :meth:`step` for every row, ``dt = t_s[k] - t_s[k - 1]``.

        The first row is an update only (the state is taken to be at ``t_s[0]``). With numba the
        loop itself is compiled (no Python between ticks); the result is the same as calling
        :meth:`step` row by row.

        Parameters
        ----------
        t_s : (n_ticks,) tick times (s).
        z : (n_ticks, m) measurements, columns in the order of ``model.rows``.
        use : (n_ticks, m) bool, rows to use at each tick.
        r_diag : (m,) measurement variances (the diagonal of R).

        Returns
        -------
        xs : (n_ticks, n) state after each tick; nis : (n_ticks,) NIS; nis_dof : (n_ticks,) rows used.
        """
        t_s = np.ascontiguousarray(t_s, dtype=float)
        z = np.ascontiguousarray(z, dtype=float)
        use = np.ascontiguousarray(use, dtype=bool)
        r_diag = np.ascontiguousarray(r_diag, dtype=float)
        n_ticks = len(t_s)
        xs = np.empty((n_ticks, self.n))
        nis = np.empty(n_ticks)
        dof = np.empty(n_ticks, dtype=np.int64)
        k = 0
        while k < n_ticks:
            if self.compiled:
                k = self._kernel.batch_kernel(
                    k, t_s, z, use, r_diag, self.x, self.P, self.Q0, NOMINAL_DT_S, self._F, self._F_nz,
                    self._F_nnz, self._tmp, self._H_all, self._H_nz, self._H_nnz, self._angle_rows,
                    self._gated_rows, self._gate_chi2 if gate_enabled else 0.0, self.preset.cam_gate_max_ticks,
                    self._gate_state, self._n_wheel_rows, self._wheel_xy, self._steer_state, self._radius,
                    self.y, self.S_diag, xs, nis, dof)
                if k == n_ticks:
                    break
                self._update_numpy(z[k], use[k], r_diag, gate_enabled)  # predicted, S not PD
            else:
                self.step(t_s[k] - t_s[k - 1] if k else 0.0, z[k], use[k], r_diag, gate_enabled)
            xs[k] = self.x
            nis[k] = self.nis
            dof[k] = self.nis_dof
            k += 1
        if n_ticks:
            self.nis, self.nis_dof = float(nis[-1]), int(dof[-1])
        return xs, nis, dof


def _nonzero_columns(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of a boolean (rows, n) mask: its True columns, ascending, padded with -1 to a
    (rows, max count) int64 array, and the count per row."""
    cols = [np.flatnonzero(row) for row in mask]
    width = max((len(c) for c in cols), default=0)
    nz = np.full((len(cols), max(width, 1)), -1, dtype=np.int64)
    for i, c in enumerate(cols):
        nz[i, :len(c)] = c
    return nz, np.array([len(c) for c in cols], dtype=np.int64)
