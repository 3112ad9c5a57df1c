"""Sensor models of the simulated robot (design §6): computed from the 200 Hz truth log.

Every random quantity is drawn once per run, up front, from the run's seed, and the models are pure
functions of (truth rows, pre-drawn noise). So the sample a closed-loop controller gets online at
tick k equals, bit for bit, the value written to the log for tick k.

Models
------
wheel speed   drive's filtered estimate (first-order lag tau = 40 ms, in the physics kernel, thesis
              §7.2.2) + white noise + quantisation (100 Hz)
steering      absolute encoder, 12-bit quantisation of the true angle (the +-0.021 rad dead band is
              the actuator's: the wheel stops inside it) (100 Hz)
IMU           BNO055 IMUPLUS, 100 Hz: accel white noise, gyro white noise, gyro bias random walk,
              yaw integrated from the biased gyro (drifts); roughness shakes the z axis
T265          200 Hz, ~10 ms latency: mount-point velocity (omega x r lever arm) with small noise,
              occasional glitches (short velocity spikes) and confidence drops (noise x5, confidence
              0-1); written in the T265's own frames through :mod:`terrainml.io.t265`
currents      100 Hz: torque / k_t + commutation ripple (15 pole pairs) + noise
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terrainml.sim import physics as ph

LOG_RATE_HZ = 200.0


@dataclass(frozen=True)
class SensorConfig:
    omega_noise_radps: float = 0.02
    omega_quant_radps: float = 0.01
    steer_bits: int = 12
    accel_noise_mps2: float = 0.04
    gyro_noise_radps: float = 0.003
    gyro_bias0_radps: float = 0.003
    gyro_bias_walk: float = 2e-4          # rad/s per sqrt(s)
    cam_latency_s: float = 0.010
    cam_vel_noise_mps: float = 0.01
    cam_rate_noise_radps: float = 0.005
    cam_yaw_walk: float = 0.002           # rad per sqrt(s)
    cam_glitch_rate_hz: float = 0.05
    cam_drop_rate_hz: float = 1.0 / 60.0
    current_noise_a: float = 0.08
    current_ripple: float = 0.04          # fraction of |i|
    current_ripple_a: float = 0.05
    pole_pairs: int = 15


class SensorModel:
    """Pre-drawn noise for ``n_rows`` 200 Hz log rows and ``n_wheels`` wheels."""

    def __init__(self, n_rows: int, n_wheels: int, rng: np.random.Generator, cfg: SensorConfig = SensorConfig()):
        self.cfg = cfg
        self.n_rows = n_rows
        dt = 1.0 / LOG_RATE_HZ
        c = cfg
        self.omega_noise = rng.normal(0.0, c.omega_noise_radps, (n_rows, n_wheels))
        self.accel_noise = rng.normal(0.0, c.accel_noise_mps2, (n_rows, 3))
        self.gyro_noise = rng.normal(0.0, c.gyro_noise_radps, (n_rows, 3))
        walk = rng.normal(0.0, c.gyro_bias_walk * np.sqrt(dt), n_rows)
        self.gyro_bias = rng.normal(0.0, c.gyro_bias0_radps) + np.cumsum(walk)
        self.cam_noise = rng.normal(0.0, 1.0, (n_rows, 3)) * np.array(
            [c.cam_vel_noise_mps, c.cam_vel_noise_mps, c.cam_rate_noise_radps])
        self.cam_yaw_drift = np.cumsum(rng.normal(0.0, c.cam_yaw_walk * np.sqrt(dt), n_rows))
        self.current_noise = rng.normal(0.0, c.current_noise_a, (n_rows, n_wheels))
        self.ripple_phase = rng.uniform(0, 2 * np.pi, n_wheels)
        # glitches: 1-3 samples of a 0.3-1.0 m/s velocity spike
        glitch = np.zeros((n_rows, 2))
        starts = np.flatnonzero(rng.random(n_rows) < c.cam_glitch_rate_hz * dt)
        for k in starts:
            length = int(rng.integers(1, 4))
            ang = rng.uniform(-np.pi, np.pi)
            mag = rng.uniform(0.3, 1.0)
            glitch[k:k + length] += mag * np.array([np.cos(ang), np.sin(ang)])
        self.cam_glitch = glitch
        # confidence drops: episodes of 0.5-2 s at confidence 1 (or 0), noise x5
        conf = np.full(n_rows, 3.0)
        drops = np.flatnonzero(rng.random(n_rows) < c.cam_drop_rate_hz * dt)
        for k in drops:
            length = int(rng.uniform(0.5, 2.0) * LOG_RATE_HZ)
            conf[k:k + length] = 0.0 if rng.random() < 0.3 else 1.0
        self.cam_confidence = conf
        self.cam_noise *= np.where(conf < 2, 5.0, 1.0)[:, None]

    # ------------------------------------------------------------------ models (vectorised on rows)
    def wheel_omega(self, log: np.ndarray, rows: np.ndarray, n: int) -> np.ndarray:
        q = self.cfg.omega_quant_radps
        base = ph.N_LOG_BODY
        raw = log[rows, base + n:base + 2 * n] + self.omega_noise[rows]
        return np.round(raw / q) * q

    def steer(self, log: np.ndarray, rows: np.ndarray, n: int) -> np.ndarray:
        base = ph.N_LOG_BODY
        d = log[rows, base + 2 * n:base + 3 * n]
        d = np.pi - np.mod(np.pi - d, 2 * np.pi)
        q = 2 * np.pi / 2 ** self.cfg.steer_bits
        return np.round(d / q) * q

    def current(self, log: np.ndarray, rows: np.ndarray, n: int, k_t: float) -> np.ndarray:
        base = ph.N_LOG_BODY
        i = log[rows, base + 3 * n:base + 4 * n] / k_t
        omega = log[rows, base:base + n]
        t = log[rows, ph.L_T][:, None]
        # electrical angle ~ pole_pairs * wheel angle; wheel angle ~ omega * t (adequate for ripple)
        ripple = (self.cfg.current_ripple * np.abs(i) + self.cfg.current_ripple_a) * np.sin(
            self.cfg.pole_pairs * omega * t + self.ripple_phase)
        return i + ripple + self.current_noise[rows]

    def imu(self, log: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Specific force (body axes, z up: +9.81 at rest) and angular rate (body axes)."""
        acc = np.column_stack([log[rows, ph.L_AX], log[rows, ph.L_AY], ph.G + log[rows, ph.L_AZ]])
        gyro = np.column_stack([np.zeros(len(rows)), np.zeros(len(rows)), log[rows, ph.L_R] + self.gyro_bias[rows]])
        return acc + self.accel_noise[rows], gyro + self.gyro_noise[rows]

    def imu_yaw(self, log: np.ndarray, n_rows: int) -> np.ndarray:
        """Yaw integrated from the measured (biased) gyro at 100 Hz on even rows; (n_rows,) with NaN odd."""
        rows = np.arange(0, n_rows, 2)
        _, gyro = self.imu(log, rows)
        yaw = np.concatenate([[0.0], np.cumsum(gyro[1:, 2] * (2.0 / LOG_RATE_HZ))])
        out = np.full(n_rows, np.nan)
        out[rows] = yaw
        return out

    def cam_rows(self, rows: np.ndarray) -> np.ndarray:
        """Truth row each camera sample shows (latency)."""
        lag = int(round(self.cfg.cam_latency_s * LOG_RATE_HZ))
        return np.maximum(rows - lag, 0)

    def cam_body(self, log: np.ndarray, rows: np.ndarray, mount_xy: tuple[float, float]):
        """Camera-mount velocity in body axes (m/s), yaw rate, yaw, confidence (the ingest's view)."""
        src = self.cam_rows(rows)
        vx, vy, r = log[src, ph.L_VX], log[src, ph.L_VY], log[src, ph.L_R]
        mx, my = mount_xy
        vmx = vx - r * my + self.cam_noise[rows, 0] + self.cam_glitch[rows, 0]
        vmy = vy + r * mx + self.cam_noise[rows, 1] + self.cam_glitch[rows, 1]
        rate = r + self.cam_noise[rows, 2]
        yaw = log[src, ph.L_PSI] + self.cam_yaw_drift[rows]
        return vmx, vmy, rate, yaw, self.cam_confidence[rows]

    def cam_robot_centre(self, log: np.ndarray, rows: np.ndarray, mount_xy: tuple[float, float]):
        """Noisy robot-centre velocity whose mount velocity equals :meth:`cam_body` (for T265 output)."""
        vmx, vmy, rate, yaw, conf = self.cam_body(log, rows, mount_xy)
        mx, my = mount_xy
        return vmx + rate * my, vmy - rate * mx, rate, yaw, conf
