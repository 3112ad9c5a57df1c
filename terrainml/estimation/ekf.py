"""Planar EKF of design §7 (thesis §6.1), generalised to any :class:`~terrainml.robot.RobotSpec`.

State (body frame ``body``: x forward, y left; world frame fixed at the start pose)::

    x = [X, Y, psi, vx, vy, r, ax, ay, delta_1 .. delta_Ns, bg]

``r`` is the yaw rate, ``(ax, ay)`` the inertial acceleration of the body origin in body axes
(what an IMU at the origin measures on level ground), ``delta_j`` the steering angle of the
j-th *steerable* wheel and ``bg`` the gyro bias. A robot without steerable wheels (skid steer,
Husky) has no steering states: their angles are fixed at 0 (thesis: 12 states for 3 steerable
wheels; here ``n = 9 + Ns``).

Process model ``f`` (sampling time T), design §7 (signs of thesis eq. 4.33-4.34, *not* 6.2)::

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

Where to read it: :mod:`terrainml.estimation.reference` is the filter written the way the
equations read (dense numpy, f, F, h, H and the textbook predict / Joseph update line by line):
the specification. :class:`Ekf` here is the production filter: ``x`` and ``P`` are plain arrays,
but :meth:`Ekf.predict`, :meth:`Ekf.update`, :meth:`Ekf.step` (both in one call) and
:meth:`Ekf.batch_filter` (a whole table without Python between ticks) are one-line calls into
the compiled kernels of :mod:`terrainml.estimation._kernel` (numba; loops that visit only the
nonzeros of F and H). The kernel is tested against the reference tick by tick to 1e-9
(``tests/estimation/test_ekf.py``); ``terrainml estimate --reference`` runs the reference instead.

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

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from terrainml.estimation import _kernel as kern
from terrainml.estimation._kernel import (I_AX, I_AY, I_PSI, I_R, I_VX, I_VY, I_X, I_Y,  # noqa: F401
                                          N_BASE, EkfModel)
from terrainml.angles import wrap_angle  # noqa: F401  (re-exported: the EKF's yaw convention)
from terrainml.robot import RobotSpec
from terrainml.schema import wheel_col

NOMINAL_DT_S = 0.01  # tick length the per-tick Q values refer to (thesis: 100 Hz)
#: variance of the motion states when the filter re-acquires after a stale stretch (SI units
#: squared: (m/s)^2, (rad/s)^2, (m/s^2)^2, rad^2): wide, so the first measurements set them
REACQUIRE_VAR = 1.0




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


# row kind -> the kernel's code (the measurement model is written in _kernel, per code)
KIND_CODES = {"wheel": kern.K_WHEEL, "imu_ax": kern.K_IMU_AX, "imu_ay": kern.K_IMU_AY,
              "imu_rate": kern.K_IMU_RATE, "imu_yaw": kern.K_YAW, "cam_yaw": kern.K_YAW,
              "steer": kern.K_STEER, "cam_vx": kern.K_CAM_VX, "cam_vy": kern.K_CAM_VY,
              "cam_rate": kern.K_CAM_RATE}


@dataclass
class PlanarModel:
    """State layout and measurement rows of the EKF for one robot.

    Attributes
    ----------
    n : int, number of states (9 + number of steerable wheels).
    rows : list of MeasurementRow, every measurement the robot *can* provide, in a fixed order
        (wheel rows first).
    steer_state : array (N,), state index of each wheel's steering angle, -1 for fixed wheels.
    wheel_xy_m : array (N, 2), wheel contact-centre positions in the body frame (m).
    F_nz, F_nnz, H_nz, H_nnz : the columns where each row of F (n rows) and H (m rows) can be
        nonzero (ascending, padded with -1) and how many: what the compiled kernels visit.
    """

    robot: RobotSpec
    has_imu_yaw: bool = True
    has_cam_yaw: bool = True
    n: int = 0
    rows: list[MeasurementRow] = field(default_factory=list)
    steer_state: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    wheel_xy_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    i_bias: int = 0

    def __post_init__(self) -> None:
        robot = self.robot
        steerable = [k for k, w in enumerate(robot.wheels) if w.steerable]
        self.n = N_BASE + len(steerable) + 1
        self.i_bias = self.n - 1
        self.steer_state = np.full(robot.n_wheels, -1, dtype=np.int64)
        for j, k in enumerate(steerable):
            self.steer_state[k] = N_BASE + j
        self.wheel_xy_m = np.array([[w.x_m, w.y_m] for w in robot.wheels], dtype=float)
        rows: list[MeasurementRow] = []
        for k in range(robot.n_wheels):
            rows.append(MeasurementRow(f"wheel{k + 1}_omega", wheel_col("omega", k + 1), "wheels", "wheel", k))
        rows += [MeasurementRow("imu_ax", "imu_ax_mps2", "imu", "imu_ax"),
                 MeasurementRow("imu_ay", "imu_ay_mps2", "imu", "imu_ay"),
                 MeasurementRow("imu_yaw_rate", "imu_yaw_rate_radps", "imu", "imu_rate")]
        if self.has_imu_yaw:
            rows.append(MeasurementRow("imu_yaw", "imu_yaw_rad", "imu", "imu_yaw", angle=True))
        for k in steerable:
            rows.append(MeasurementRow(f"steer{k + 1}", wheel_col("steer", k + 1), "steer", "steer", k))
        if robot.has_camera:
            rows += [MeasurementRow("cam_vx", "cam_vx_mps", "cam", "cam_vx"),
                     MeasurementRow("cam_vy", "cam_vy_mps", "cam", "cam_vy"),
                     MeasurementRow("cam_yaw_rate", "cam_yaw_rate_radps", "cam", "cam_rate")]
            if self.has_cam_yaw:
                rows.append(MeasurementRow("cam_yaw", "cam_yaw_rad", "cam", "cam_yaw", angle=True))
        self.rows = rows
        self.n_wheel_rows = robot.n_wheels
        assert all(r.kind == "wheel" for r in rows[:self.n_wheel_rows])  # the kernels rely on it
        # sparsity of F and H: F probed at a generic state; H: v, r and the wheel's steering
        # angle for wheel rows
        F_probe = self.F(0.1 + np.arange(self.n) * 0.37, 1.0)
        self.F_nz, self.F_nnz = _nonzero_columns(F_probe != 0.0)
        H_mask = self.constant_H() != 0.0
        for i in range(self.n_wheel_rows):
            H_mask[i, [I_VX, I_VY, I_R]] = True
            if self.steer_state[i] >= 0:
                H_mask[i, self.steer_state[i]] = True
        self.H_nz, self.H_nnz = _nonzero_columns(H_mask)

    @property
    def m(self) -> int:
        return len(self.rows)

    # ----------------------------------------------------------------- f, F, h, H (allocating)
    # Thin wrappers over the kernels' model, for tests and the filterpy comparison.
    def f(self, x: np.ndarray, dt: float) -> np.ndarray:
        """Process model f(x) for tick length ``dt`` (s), shape (n,) (psi wrapped)."""
        xn = np.array(x, dtype=float)
        kern.process_model(xn, dt)
        return xn

    def F(self, x: np.ndarray, dt: float) -> np.ndarray:
        """Jacobian df/dx, shape (n, n)."""
        F = np.eye(self.n)
        kern.process_jacobian(F, np.asarray(x, dtype=float), dt)
        return F

    def h(self, x: np.ndarray) -> np.ndarray:
        """Measurement model h(x) for every row, shape (m,)."""
        x = np.asarray(x, dtype=float)
        H = self.H(x)
        return np.array([kern.h_row(H, x, i, self.n_wheel_rows, self.H_nz, self.H_nnz) for i in range(self.m)])

    def H(self, x: np.ndarray) -> np.ndarray:
        """Jacobian dh/dx for every row, shape (m, n)."""
        H = self.constant_H()
        kern.fill_wheel_H(H, np.asarray(x, dtype=float), self.wheel_xy_m, self.steer_state,
                          float(self.robot.wheel_radius_m))
        return H

    def constant_H(self) -> np.ndarray:
        """The state-independent entries of H (wheel rows left zero), shape (m, n)."""
        H = np.zeros((self.m, self.n))
        kind = np.array([KIND_CODES[r.kind] for r in self.rows], dtype=np.int64)
        state_of_row = np.array([self.steer_state[r.wheel] if r.kind == "steer" else -1 for r in self.rows],
                                dtype=np.int64)
        cam = self.robot.camera
        cam_xy = np.array([cam.x_m, cam.y_m] if cam is not None else [0.0, 0.0])
        kern.fill_linear_H(H, kind, state_of_row, cam_xy, self.i_bias)
        return H


# --------------------------------------------------------------------- filter
class Ekf:
    """The EKF itself: ``x`` (n,), ``P`` (n, n), ``predict(dt)``, ``update(z, use, r_diag)``;
    ``step(dt, z, use, r_diag)`` (both, one tick) and ``batch_filter(t_s, z, use, r_diag)`` (a
    whole table). The equations run in :mod:`terrainml.estimation._kernel`.

    Parameters
    ----------
    model : PlanarModel, the robot's state and measurement layout.
    preset : EkfPreset or name.

    Attributes
    ----------
    x : ndarray (n,), state estimate.
    P : ndarray (n, n), state covariance.
    Q0 : ndarray (n, n), process noise per 0.01 s tick (scaled by ``dt / 0.01``).
    y : ndarray (m,), last innovations (NaN for rows not used).
    S_diag : ndarray (m,), last innovation variances (NaN for rows not used).
    nis : float, last y^T S^-1 y; ``nis_dof`` its degrees of freedom (rows used).
    n_gated : int, rows rejected by the gate so far.
    """

    def __init__(self, model: PlanarModel, preset: str | EkfPreset = "robust") -> None:
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
        self.y = np.full(m, np.nan)
        self.S_diag = np.full(m, np.nan)
        self.nis = float("nan")
        self.nis_dof = 0
        # gate memory: [rows gated so far, consecutive ticks with a gated row, gate released]
        self._gate_state = np.zeros(3, dtype=np.int64)
        self._gate_chi2 = 0.0 if p.cam_gate_chi2 is None else float(p.cam_gate_chi2)
        gated = [r.group == "cam" or (p.gate_imu_acc and r.kind in ("imu_ax", "imu_ay")) for r in model.rows]
        # the kernels take the pack as a plain tuple (see _kernel's docstring)
        self._model = tuple(EkfModel(
            Q0=self.Q0, nominal_dt_s=NOMINAL_DT_S, H_const=model.constant_H(),
            F_nz=model.F_nz, F_nnz=model.F_nnz, H_nz=model.H_nz, H_nnz=model.H_nnz,
            angle_rows=np.array([r.angle for r in model.rows], dtype=bool), gated_rows=np.array(gated, dtype=bool),
            gate_max_ticks=int(p.cam_gate_max_ticks), n_wheel_rows=int(model.n_wheel_rows),
            wheel_xy_m=np.ascontiguousarray(model.wheel_xy_m, dtype=float), steer_state=model.steer_state,
            wheel_radius_m=float(model.robot.wheel_radius_m)))

    @property
    def n_gated(self) -> int:
        """Rows rejected by the gate since the filter started."""
        return int(self._gate_state[kern.G_N_GATED])

    def _state(self) -> tuple:
        """The arrays the kernels update in place (fields of ``_kernel.EkfState``)."""
        return self.x, self.P, self._gate_state, self.y, self.S_diag

    def _gate(self, gate_enabled: bool) -> float:
        return self._gate_chi2 if gate_enabled else 0.0

    def reacquire(self, variance: float = REACQUIRE_VAR) -> None:
        """Re-initialise the filter after a stale stretch (every sensor silent for a while).

        While nothing observes it the covariance grows without bound (the unobserved position
        first: after about a minute of silence it passes the health limit and, never observed
        again, stays there). On return the motion states (speeds, yaw rate, accelerations,
        steering angles) restart at 0 with a wide ``variance`` so the first measurements set
        them; the pose and the gyro bias keep their values, the pose variance restarts at
        ``p0_pose`` (dead reckoning re-based at the current estimate) and the yaw's is capped at
        ``variance``; cross-covariances are cleared and the gate memory restarts.
        """
        n = self.n
        old = np.diag(self.P).copy()
        diag = np.full(n, float(variance))
        diag[kern.I_X] = diag[kern.I_Y] = self.preset.p0_pose
        diag[kern.I_PSI] = min(old[kern.I_PSI], variance) if np.isfinite(old[kern.I_PSI]) else variance
        diag[n - 1] = old[n - 1] if np.isfinite(old[n - 1]) else self.preset.p0_bias
        keep = self.x[[kern.I_X, kern.I_Y, kern.I_PSI, n - 1]]
        keep[~np.isfinite(keep)] = 0.0
        self.x[:] = 0.0
        self.x[[kern.I_X, kern.I_Y, kern.I_PSI, n - 1]] = keep
        self.P[:] = np.diag(diag)
        self._gate_state[kern.G_RUN] = 0
        self._gate_state[kern.G_RELEASE] = 0

    def predict(self, dt: float) -> None:
        """x = f(x);  P = F P F^T + Q0 (dt / 0.01)."""
        kern.predict_kernel(self._model, self._state(), dt)

    def update(self, z: np.ndarray, use: np.ndarray, r_diag: np.ndarray, gate_enabled: bool = True) -> None:
        """Joseph-form update with the rows ``use`` (bool, (m,)) of z (m,) and R = diag(r_diag).

        y = z - h(x) (angles wrapped);  S = H P H^T + R;  K = P H^T S^-1
        x = x + K y;  P = (I - K H) P (I - K H)^T + K R K^T;  NIS = y^T S^-1 y

        With ``preset.cam_gate_chi2`` set, camera and IMU-acceleration rows whose normalised
        innovation ``y_i^2 / S_ii`` exceeds it are dropped for the tick (``gate_enabled=False``
        skips the gate, e.g. on the first camera sample after a gap). After
        ``cam_gate_max_ticks`` consecutive gated ticks the gate is released until prediction and
        sensors agree again.
        """
        self.nis, self.nis_dof = kern.update_kernel(self._model, self._state(), z, use, r_diag,
                                                    self._gate(gate_enabled))

    def step(self, dt: float, z: np.ndarray, use: np.ndarray, r_diag: np.ndarray,
             gate_enabled: bool = True) -> None:
        """:meth:`predict` over ``dt`` (skipped when ``dt <= 0``), then :meth:`update`, in one call."""
        self.nis, self.nis_dof = kern.step_kernel(self._model, self._state(), dt, z, use, r_diag,
                                                  self._gate(gate_enabled))

    def batch_filter(self, t_s: np.ndarray, z: np.ndarray, use: np.ndarray, r_diag: np.ndarray,
                     gate_enabled: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Filter a whole table: :meth:`step` for every row, ``dt = t_s[k] - t_s[k - 1]``.

        The first row is an update only (the state is taken to be at ``t_s[0]``). The loop runs
        compiled (no Python between ticks); the result is that of :meth:`step` row by row.

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
        n_ticks = len(t_s)
        xs = np.empty((n_ticks, self.n))
        nis = np.empty(n_ticks)
        dof = np.empty(n_ticks, dtype=np.int64)
        kern.batch_kernel(self._model, self._state(), np.ascontiguousarray(t_s, dtype=float),
                          np.ascontiguousarray(z, dtype=float), np.ascontiguousarray(use, dtype=bool),
                          np.ascontiguousarray(r_diag, dtype=float), self._gate(gate_enabled), xs, nis, dof)
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
