"""Kinematic tracked (skid-steer) robots with per-patch slip on a patch map (design §13).

:class:`TrackedFleet` moves ``n`` tracked robots at once over a :class:`~terrainml.sim.patch_slip.
PatchGrid` whose patches slip as :class:`~terrainml.sim.patch_slip.PatchSlipModel` says, and
returns what each robot measures. It is the plant of the slip-map lap experiment
(:mod:`terrainml.experiments.slipmap_laps`, the IRLS paper's Fig. 3-4).

Why a second, light model next to :class:`terrainml.sim.Simulator`
-----------------------------------------------------------------
The full simulator integrates wheel spin dynamics and terramechanics at >= 500 Hz for swerve
robots; 25 robot-laps x 3 methods of that would not fit the lap experiment's 3-minute budget, and
the paper's quantities (track slippage as a function of track speeds) are what matters there. So
this is a *kinematic-with-slip* skid-steer model stepped at ``dt_s`` (20 Hz in the experiment):

- the low-level controller holds the sprocket speeds at their set-points ``omega_i`` (rad/s);
- the ground moves each track at ``R omega_i - beta_i`` (the patch's true slippage plus white
  process noise, terrain roughness), so ``v_x`` is their mean and the yaw rate their difference
  over the track width ``B``;
- the body slides sideways at ``v_y = v_x tan(alpha)`` (paper eq. 1), ``alpha`` the patch's slip
  angle; the pose is integrated by forward Euler in the world frame.

Sensors (white noise, 1 sigma, see :class:`TrackedNoise`): encoders on the sprocket speeds, and a
body-frame reference velocity and yaw rate (RTK GPS + IMU) of which a fraction of the samples
carry a gross outlier (a GPS glitch, uniform in +-``outlier_mps`` on ``v_x`` and ``v_y``).

Frames: world (x, y in m, yaw in rad from x); body (x forward, y left). Left is the side with
y > 0. All draws come from one generator seeded at construction, in a fixed order per step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terrainml.robot import RobotSpec, builtin_robot
from terrainml.sim.patch_slip import PatchGrid, PatchSlipModel

__all__ = ["TrackedFleet", "TrackedMeasurement", "TrackedNoise", "track_geometry", "tracked_robot"]


def tracked_robot() -> RobotSpec:
    """The tracked robot spec (``terrainml/robots/skidsteer_tracked.yaml``, MAXXII-like)."""
    return builtin_robot("skidsteer_tracked")


def track_geometry(robot: RobotSpec) -> tuple[float, float]:
    """``(radius_m, track_m)``: sprocket radius R and track width B of a two-track robot spec."""
    return robot.wheel_radius_m, abs(robot.wheels[0].y_m - robot.wheels[1].y_m)


@dataclass(frozen=True)
class TrackedNoise:
    """Process and sensor noise of :class:`TrackedFleet` (1 sigma unless said otherwise).

    Attributes
    ----------
    process_noise_mps : white noise on the true track slippage (terrain roughness), m/s.
    encoder_noise_radps : sprocket-speed encoder noise, rad/s.
    vel_noise_mps : reference-velocity noise on ``v_x`` and ``v_y``, m/s.
    yaw_rate_noise_radps : reference yaw-rate noise, rad/s.
    outlier_fraction : share of reference samples with a gross error.
    outlier_mps : size of that error (uniform in +-outlier_mps on ``v_x`` and ``v_y``), m/s.
    """

    process_noise_mps: float = 0.005
    encoder_noise_radps: float = 0.05
    vel_noise_mps: float = 0.02
    yaw_rate_noise_radps: float = 0.01
    outlier_fraction: float = 0.05
    outlier_mps: float = 0.5


@dataclass
class TrackedMeasurement:
    """What each robot measured over one step (arrays of shape (n,))."""

    omega_l_radps: np.ndarray  # left sprocket encoder
    omega_r_radps: np.ndarray  # right sprocket encoder
    vx_mps: np.ndarray  # reference velocity, body frame
    vy_mps: np.ndarray
    yaw_rate_radps: np.ndarray


class TrackedFleet:
    """``n`` kinematic tracked robots with per-patch slip (see the module docstring).

    Parameters
    ----------
    terrain : true slippage of each patch.
    grid : the patch map ``terrain`` is indexed by.
    radius_m, track_m : sprocket radius R and track width B (m), e.g. from :func:`track_geometry`.
    xy_m : array, shape (n, 2)  initial positions (world frame, m).
    yaw_rad : array, shape (n,)  initial headings (rad).
    dt_s : step (s).
    noise : process and sensor noise.
    seed : int, SeedSequence or Generator for every draw.
    """

    def __init__(self, terrain: PatchSlipModel, grid: PatchGrid, radius_m: float, track_m: float,
                 xy_m: np.ndarray, yaw_rad: np.ndarray, dt_s: float, noise: TrackedNoise | None = None,
                 seed=None):
        if not dt_s > 0:
            raise ValueError(f"dt_s must be > 0, got {dt_s}")
        self.terrain = terrain
        self.grid = grid
        self.radius_m = float(radius_m)
        self.track_m = float(track_m)
        self.xy_m = np.array(xy_m, dtype=float).reshape(-1, 2)
        self.yaw_rad = np.array(yaw_rad, dtype=float).reshape(-1)
        if len(self.yaw_rad) != len(self.xy_m):
            raise ValueError("xy_m and yaw_rad must describe the same number of robots")
        self.dt_s = float(dt_s)
        self.noise = noise if noise is not None else TrackedNoise()
        self.rng = np.random.default_rng(seed)

    @property
    def n_robots(self) -> int:
        return len(self.yaw_rad)

    def patch(self) -> np.ndarray:
        """Patch under each robot now (int array, shape (n,))."""
        return self.grid.index(self.xy_m)

    def step(self, omega_l_radps: np.ndarray, omega_r_radps: np.ndarray) -> TrackedMeasurement:
        """Hold the sprockets at ``omega_l_radps``, ``omega_r_radps`` (shape (n,), rad/s) for ``dt_s``.

        Moves the robots and returns what they measured during the step. The slippage is that of
        the patch each robot was on at the start of the step.
        """
        wl, wr = omega_l_radps, omega_r_radps
        n, nz, rng, radius, dt = self.n_robots, self.noise, self.rng, self.radius_m, self.dt_s
        # plant (paper eq. 1, 5-7): the ground moves each track at R omega - beta
        tb_l, tb_r, t_al = self.terrain.slippage(self.patch(), wl, wr, radius, self.track_m)
        tb_l = tb_l + rng.normal(0.0, nz.process_noise_mps, n)
        tb_r = tb_r + rng.normal(0.0, nz.process_noise_mps, n)
        v_tl = radius * wl - tb_l
        v_tr = radius * wr - tb_r
        vx = 0.5 * (v_tl + v_tr)
        r = (v_tr - v_tl) / self.track_m
        vy = vx * np.tan(t_al)
        c, s = np.cos(self.yaw_rad), np.sin(self.yaw_rad)
        self.xy_m = self.xy_m + dt * np.c_[vx * c - vy * s, vx * s + vy * c]
        self.yaw_rad = np.angle(np.exp(1j * (self.yaw_rad + dt * r)))  # wrapped to (-pi, pi]
        # sensors: encoders, reference velocity (GPS + IMU) with gross outliers
        wl_m = wl + rng.normal(0.0, nz.encoder_noise_radps, n)
        wr_m = wr + rng.normal(0.0, nz.encoder_noise_radps, n)
        vx_m = vx + rng.normal(0.0, nz.vel_noise_mps, n)
        vy_m = vy + rng.normal(0.0, nz.vel_noise_mps, n)
        r_m = r + rng.normal(0.0, nz.yaw_rate_noise_radps, n)
        glitch = rng.random(n) < nz.outlier_fraction
        gx, gy = rng.uniform(-nz.outlier_mps, nz.outlier_mps, (2, n))
        return TrackedMeasurement(omega_l_radps=wl_m, omega_r_radps=wr_m,
                                  vx_mps=np.where(glitch, vx_m + gx, vx_m),
                                  vy_mps=np.where(glitch, vy_m + gy, vy_m), yaw_rate_radps=r_m)
