"""Small fakes and data helpers for the stream tests: an estimator, a slip table and a window classifier.

They stand in for the real chain only where a test is about the predictor's own behaviour
(ordering, health, fault handling, serving); the end-to-end tests use the real chain.
"""

from __future__ import annotations

import math

import numpy as np

RATE_HZ = 100.0


class FakeEstimator:
    """EST row from a sample: body speed = cam_vx (held while invalid); slip per design §7.1."""

    def __init__(self, robot, nan_at=()):
        self.robot = robot
        self.nan_at = set(nan_at)
        self.k = 0

    def step(self, s):
        self.k += 1
        n, r = self.robot.n_wheels, self.robot.wheel_radius_m
        v = s.get("cam_vx_mps", math.nan)
        if not math.isfinite(v):  # no camera this tick: hold the last speed (like EKF prediction)
            v = getattr(self, "_v", 0.0)
        self._v = v
        row = {"t_s": s["t_s"], "ekf_vx_mps": v, "ekf_vy_mps": 0.0, "ekf_yaw_rate_radps": 0.0,
               "estimator_ok": True, "terrain": s.get("terrain", -1)}
        for i in range(1, n + 1):
            w = s.get(f"wheel{i}_omega_radps", math.nan) * r
            big = max(abs(w), abs(v))
            slip = 0.0 if big < 0.05 else (w - v) / big
            row[f"slip{i}"] = math.nan if self.k in self.nan_at else slip
            row[f"state{i}"] = "steady" if abs(v) >= 0.05 else "idle"
            row[f"v_long{i}_mps"] = v
            row[f"wheel{i}_current_a"] = s.get(f"wheel{i}_current_a", math.nan)
        row["imu_az_mps2"] = s.get("imu_az_mps2", math.nan)
        return row


class FakeTable:
    """target(c, state): traction 0.1 + 0.05 c, braking -(0.15 + 0.05 c), steady 0.005 + 0.01 c."""

    def target(self, c, state):
        return {"traction": 0.1 + 0.05 * c, "braking": -(0.15 + 0.05 * c),
                "steady": 0.005 + 0.01 * c, "idle": 0.0}[state]


class FakeClassifier:
    """One-hot-ish (0.9) on the window's majority ``terrain``; None unless |v| >= 0.2 m/s on 95% of ticks."""

    class_ids = list(range(8))

    def __init__(self, raise_on_calls=()):
        self.calls = 0
        self.raise_on_calls = set(raise_on_calls)

    def classify(self, window):
        self.calls += 1
        if self.calls in self.raise_on_calls:
            raise RuntimeError("boom (test)")
        if not (window["ekf_vx_mps"].abs() >= 0.2).mean() >= 0.95:
            return None
        c = int(np.bincount(window["terrain"].astype(int).clip(0, 7)).argmax())
        p = np.full(8, 0.1 / 7)
        p[c] = 0.9
        return p


def make_samples(robot, duration_s, *, speed_mps=1.0, slip=0.1, terrain=3, t0=0.0, seed=0):
    """Base-rate samples of a robot cruising straight: list of dicts with canonical columns."""
    rng = np.random.default_rng(seed)
    n = robot.n_wheels
    out = []
    for k in range(int(round(duration_s * RATE_HZ))):
        t = round(t0 + k / RATE_HZ, 6)
        s = {"t_s": t, "terrain": terrain, "imu_ax_mps2": rng.normal(0, 0.02),
             "imu_ay_mps2": rng.normal(0, 0.02), "imu_az_mps2": 9.81 + rng.normal(0, 0.05),
             "imu_yaw_rate_radps": rng.normal(0, 0.001), "cam_vx_mps": speed_mps,
             "cam_vy_mps": 0.0, "cam_yaw_rate_radps": 0.0, "cam_yaw_rad": 0.0}
        for i in range(1, n + 1):
            s[f"wheel{i}_omega_radps"] = speed_mps / (1 - slip) / robot.wheel_radius_m
            s[f"wheel{i}_steer_rad"] = 0.0
            s[f"wheel{i}_current_a"] = 3.0 + rng.normal(0, 0.1)
        out.append(s)
    return out


def _synthetic_windows(robot, seed_base=0):
    """Steady windows of 4 'classes' (slip levels 0.02, 0.12, 0.22, 0.32) from kinematic runs."""
    from terrainml.estimation.run import estimate_run
    from terrainml.testing import kinematic_run, trapezoid_speed
    from terrainml.features.windows import Windows, cut_windows

    wins = []
    for k, cid in enumerate(CLASS_IDS):
        for rep in range(2):
            table = kinematic_run(robot, duration_s=24.0, slip=SLIP_OF[cid], terrain=cid,
                                  seed=seed_base + 10 * k + rep, imu_acc_noise=0.005,
                                  vx=lambda t: trapezoid_speed(t, 1.0, 1.0, 1.0),
                                  run_id=f"c{cid}r{rep}")
            w, _ = cut_windows(estimate_run(table, robot), robot)
            wins.append(w)
    return Windows.concat(wins)


CLASS_IDS = (0, 2, 5, 7)
SLIP_OF = {0: 0.02, 2: 0.12, 5: 0.22, 7: 0.32}
