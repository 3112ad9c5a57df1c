"""The EKF of :mod:`terrainml.estimation.ekf` in readable dense numpy: its specification (design §7).

The compiled filter (:class:`~terrainml.estimation.ekf.Ekf`, kernels in
:mod:`terrainml.estimation._kernel`) visits only the structural nonzeros of F and H, in loops
written for numba; this module is the same filter written the way the equations read: its own
f, F, h, H (transcribed from the ``ekf`` module docstring, thesis eq. 4.33-4.34, 4.46, 6.6) and
the textbook predict and Joseph-form update with dense products and a LAPACK Cholesky solve.
Only the layout (:class:`~terrainml.estimation.ekf.PlanarModel`: rows, steering states, wheel
positions) and the tuning (P0, Q0 of ``Ekf``) are shared with the kernel.

The kernel is tested against it, tick by tick, to 1e-9 (``tests/estimation/test_ekf.py``), and
``terrainml estimate --reference`` runs a whole run through it (slow: dense products and Python
per tick) to check the compiled filter on a user's own data; the estimation benchmark times it
beside filterpy. :class:`ReferenceEkf` has the interface of ``Ekf`` (``x``, ``P``, ``y``,
``S_diag``, ``nis``, ``nis_dof``, ``n_gated``, ``predict``, ``update``, ``step``,
``batch_filter``), so :class:`~terrainml.estimation.online.OnlineEstimator` runs either.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from terrainml.estimation.ekf import REACQUIRE_VAR, Ekf, PlanarModel, get_preset

__all__ = ["ReferenceEkf", "f", "F", "h", "H"]

X, Y, PSI, VX, VY, R, AX, AY = range(8)


def wrap(a):
    """Angle wrapped to (-pi, pi] (rad), as the kernel wraps psi."""
    w = (a + math.pi) % (2 * math.pi) - math.pi
    return math.pi if w == -math.pi else w


def f(model: PlanarModel, x: np.ndarray, dt: float) -> np.ndarray:
    """Process model (thesis eq. 4.33-4.34), psi wrapped."""
    xn = x.copy()
    c, s = math.cos(x[PSI]), math.sin(x[PSI])
    xn[X] = x[X] + dt * (x[VX] * c - x[VY] * s)
    xn[Y] = x[Y] + dt * (x[VX] * s + x[VY] * c)
    xn[PSI] = wrap(x[PSI] + dt * x[R])
    xn[VX] = x[VX] + dt * (x[AX] + x[R] * x[VY])
    xn[VY] = x[VY] + dt * (x[AY] - x[R] * x[VX])
    return xn


def F(model: PlanarModel, x: np.ndarray, dt: float) -> np.ndarray:
    """df/dx."""
    J = np.eye(model.n)
    c, s = math.cos(x[PSI]), math.sin(x[PSI])
    vx, vy, r = x[VX], x[VY], x[R]
    J[X, [PSI, VX, VY]] = [-dt * (vx * s + vy * c), dt * c, -dt * s]
    J[Y, [PSI, VX, VY]] = [dt * (vx * c - vy * s), dt * s, dt * c]
    J[PSI, R] = dt
    J[VX, [VY, R, AX]] = [dt * r, dt * vy, dt]
    J[VY, [VX, R, AY]] = [-dt * r, -dt * vx, dt]
    return J


def _wheel_terms(model, x):
    d = np.array([x[k] if k >= 0 else 0.0 for k in model.steer_state])
    u = x[VX] - x[R] * model.wheel_xy_m[:, 1]
    w = x[VY] + x[R] * model.wheel_xy_m[:, 0]
    return d, u, w


def h(model: PlanarModel, x: np.ndarray) -> np.ndarray:
    """Measurement model (eq. 4.46, 6.6) for every row."""
    d, u, w = _wheel_terms(model, x)
    v_long = u * np.cos(d) + w * np.sin(d)
    cam = model.robot.camera
    out = []
    for row in model.rows:
        out.append({"wheel": lambda: v_long[row.wheel] / model.robot.wheel_radius_m,
                    "imu_ax": lambda: x[AX], "imu_ay": lambda: x[AY],
                    "imu_rate": lambda: x[R] + x[model.i_bias], "imu_yaw": lambda: x[PSI],
                    "steer": lambda: x[model.steer_state[row.wheel]],
                    "cam_vx": lambda: x[VX] - x[R] * cam.y_m, "cam_vy": lambda: x[VY] + x[R] * cam.x_m,
                    "cam_rate": lambda: x[R], "cam_yaw": lambda: x[PSI]}[row.kind]())
    return np.array(out)


def H(model: PlanarModel, x: np.ndarray) -> np.ndarray:
    """dh/dx for every row."""
    J = np.zeros((model.m, model.n))
    d, u, w = _wheel_terms(model, x)
    inv_r = 1.0 / model.robot.wheel_radius_m
    cam = model.robot.camera
    for k, row in enumerate(model.rows):
        if row.kind == "wheel":
            i = row.wheel
            c, s = math.cos(d[i]), math.sin(d[i])
            xi, yi = model.wheel_xy_m[i]
            J[k, [VX, VY, R]] = [c * inv_r, s * inv_r, (xi * s - yi * c) * inv_r]
            if model.steer_state[i] >= 0:
                J[k, model.steer_state[i]] = (w[i] * c - u[i] * s) * inv_r
        else:
            cols = {"imu_ax": {AX: 1.0}, "imu_ay": {AY: 1.0}, "imu_rate": {R: 1.0, model.i_bias: 1.0},
                    "imu_yaw": {PSI: 1.0}, "cam_yaw": {PSI: 1.0}, "cam_rate": {R: 1.0},
                    "steer": {int(model.steer_state[row.wheel]): 1.0} if row.kind == "steer" else {},
                    "cam_vx": {VX: 1.0, R: -cam.y_m} if cam else {},
                    "cam_vy": {VY: 1.0, R: cam.x_m} if cam else {}}[row.kind]
            for j, v in cols.items():
                J[k, j] = v
    return J


class ReferenceEkf:
    """The EKF in dense numpy; same interface as :class:`terrainml.estimation.ekf.Ekf` (``x``,
    ``P``, ``y``, ``S_diag``, ``nis``, ``nis_dof``, ``n_gated``, ``predict``, ``update``, ``step``,
    ``batch_filter``).

    Parameters
    ----------
    model : PlanarModel (the robot's rows and states). preset : ``thesis``, ``robust`` or an
        :class:`~terrainml.estimation.ekf.EkfPreset` (P0, Q0, the camera gate).
    """

    def __init__(self, model: PlanarModel, preset="robust"):
        self.model = model
        self.preset = p = get_preset(preset)
        ekf = Ekf(model, p)  # P0 and Q0 only
        self.x, self.P, self.Q0 = ekf.x.copy(), ekf.P.copy(), ekf.Q0.copy()
        self.y = np.full(model.m, np.nan)
        self.S_diag = np.full(model.m, np.nan)
        self.nis, self.nis_dof, self.n_gated = float("nan"), 0, 0
        self.angle = np.array([r.angle for r in model.rows])
        self.gated_rows = np.array([r.group == "cam" or (p.gate_imu_acc and r.kind in ("imu_ax", "imu_ay"))
                                    for r in model.rows])
        self.gated_run, self.gate_release = 0, False

    def predict(self, dt):
        """Propagate over ``dt`` (s): x = f(x), P = F P F^T + Q0 dt / 0.01 (Q per 100 Hz tick)."""
        Fk = F(self.model, self.x, dt)  # F = df/dx at the prior mean
        self.x = f(self.model, self.x, dt)  # x(k|k-1) = f(x(k-1|k-1))
        self.P = Fk @ self.P @ Fk.T + self.Q0 * (dt / 0.01)  # P(k|k-1) = F P F^T + Q

    def update(self, z, use, r_diag, gate_enabled=True):
        """Update with the rows ``use`` of ``z`` (m,), variances ``r_diag`` (m,); chi-square gate.

        y = z - h(x) (angles wrapped), S = H P H^T + R, K = P H^T S^-1, x = x + K y,
        P = (I - K H) P (I - K H)^T + K R K^T (Joseph form, symmetrised); NIS = y^T S^-1 y.
        Gated rows (camera, and IMU acceleration in presets that gate it) whose y^2 exceeds
        ``cam_gate_chi2`` S_ii are dropped, unless they have been for ``cam_gate_max_ticks``.
        """
        self.y.fill(np.nan)
        self.S_diag.fill(np.nan)
        idx = np.flatnonzero(use)
        y_all = z - h(self.model, self.x)
        y_all[self.angle] = np.mod(y_all[self.angle] + math.pi, 2 * math.pi) - math.pi
        H_all = H(self.model, self.x)
        gate = self.preset.cam_gate_chi2 if gate_enabled else None
        gated_now = False
        if gate is not None:
            Hg = H_all[idx]
            s_ii = np.einsum("ij,jk,ik->i", Hg, self.P, Hg) + r_diag[idx]
            bad = self.gated_rows[idx] & (y_all[idx] ** 2 > gate * s_ii)
            if not bad.any():
                self.gate_release = False  # prediction and sensors agree again
            elif not self.gate_release:
                gated_now = True
                self.n_gated += int(bad.sum())
                idx = idx[~bad]
        self.gated_run = self.gated_run + 1 if gated_now else 0
        if self.gated_run > self.preset.cam_gate_max_ticks:
            self.gate_release, self.gated_run = True, 0
        if idx.size == 0:
            self.nis, self.nis_dof = float("nan"), 0
            return
        Hk, y, Rk = H_all[idx], y_all[idx], np.diag(r_diag[idx])
        S = Hk @ self.P @ Hk.T + Rk  # S = H P H^T + R
        cho = cho_factor(S, lower=True)
        K = cho_solve(cho, Hk @ self.P).T  # K = P H^T S^-1 (S symmetric)
        self.x = self.x + K @ y  # x(k|k) = x(k|k-1) + K y
        self.x[PSI] = wrap(self.x[PSI])
        A = np.eye(self.model.n) - K @ Hk
        P = A @ self.P @ A.T + K @ Rk @ K.T  # Joseph form: P stays positive semi-definite
        self.P = 0.5 * (P + P.T)
        self.nis, self.nis_dof = float(y @ cho_solve(cho, y)), len(idx)  # NIS = y^T S^-1 y
        self.y[idx], self.S_diag[idx] = y, np.diag(S)

    def reacquire(self, variance: float = REACQUIRE_VAR) -> None:
        """Re-initialise after a stale stretch (:meth:`terrainml.estimation.ekf.Ekf.reacquire`).

        Motion states restart at 0 with ``variance``; pose and gyro bias keep their values, the
        pose variance restarts at ``p0_pose``, the yaw's is capped at ``variance`` (the bias's kept);
        cross-covariances cleared, gate memory restarted.
        """
        n = self.model.n
        old = np.diag(self.P).copy()
        diag = np.full(n, float(variance))
        diag[X] = diag[Y] = self.preset.p0_pose
        diag[PSI] = min(old[PSI], variance) if np.isfinite(old[PSI]) else variance
        diag[n - 1] = old[n - 1] if np.isfinite(old[n - 1]) else self.preset.p0_bias
        keep = self.x[[X, Y, PSI, n - 1]]
        keep[~np.isfinite(keep)] = 0.0
        self.x = np.zeros(n)
        self.x[[X, Y, PSI, n - 1]] = keep
        self.P = np.diag(diag)
        self.gated_run, self.gate_release = 0, False

    def step(self, dt, z, use, r_diag, gate_enabled=True):
        """One tick: predict over ``dt`` (when > 0), then update."""
        if dt > 0.0:
            self.predict(dt)
        self.update(z, use, r_diag, gate_enabled)

    def batch_filter(self, t_s, z, use, r_diag, gate_enabled=True):
        """:meth:`step` over every row (``dt = t_s[k] - t_s[k - 1]``); states, NIS and rows used."""
        xs, nis, dof = np.empty((len(t_s), self.model.n)), np.empty(len(t_s)), np.empty(len(t_s), dtype=int)
        for k in range(len(t_s)):
            self.step(t_s[k] - t_s[k - 1] if k else 0.0, z[k], use[k], r_diag, gate_enabled)
            xs[k], nis[k], dof[k] = self.x, self.nis, self.nis_dof
        return xs, nis, dof
