"""The slip-map lap experiment (IRLS paper Fig. 3-4, design §13).

Several tracked skid-steer robots drive laps of a closed spline path over a 9 x 9 m map made of
3 x 3 m patches of different terrain. Each robot logs its wheel speeds and a reference body velocity
(RTK GPS + IMU, noisy, with occasional gross outliers) and computes the slippage targets of paper
eq. 5-7. After its first lap, and then every half lap, each robot refits its local IRLS estimators
(one per patch), sends its sufficient statistics as a JSON message, and every robot uses the merged
global map to compensate its wheel-speed set-points (eq. 8) and its tracker heading (alpha).
Three methods run on identical noise: ``none`` (unicycle control), ``exponential`` (fixed constants
identified once on a default terrain) and ``irls``. The report holds the mean cross-track error per
lap of each method.

The robots and the terrain are simulated by :mod:`terrainml.sim.tracked` (kinematic tracked robots
with per-patch slip, stepped at ``dt_s``) and :mod:`terrainml.sim.patch_slip` (the patch map and
its true slippage); this module holds the experiment: the robot-side tracker, compensation and
estimation, the laps, the report. The figure is drawn by :mod:`terrainml.experiments.slipmap_plot`.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from terrainml.atomic import write_text
from terrainml.classes import class_name
from terrainml.experiments.slipmap_plot import plot_experiment
from terrainml.sim.patch_slip import CLASS_SLIP_AT_1MPS, PatchGrid, PatchSlipModel
from terrainml.sim.tracked import TrackedFleet, TrackedNoise, track_geometry, tracked_robot
from terrainml.slipmap.exponential import ExponentialSlipModel
from terrainml.slipmap.kinematics import (compensate_wheel_speed_radps, lateral_slip_angle_rad,
                                          longitudinal_slippage_mps, wheel_speeds_from_twist_radps)
from terrainml.slipmap.slipmap import SlipMap, SlipMapConfig, merge_maps
from terrainml.slipmap.tracker import ClosedSplinePath, path_following_yaw_rate

__all__ = ["METHODS", "ExperimentConfig", "ExperimentResult", "identify_exponential", "plot_experiment",
           "run_experiment", "simulate_method", "write_report"]

METHODS = ("none", "exponential", "irls")
REPORT_SCHEMA = "terrainml.experiments.slipmap_laps"
REPORT_VERSION = 1

DEFAULT_CLASS = 2  # short_grass: the "default terrain" on which the exponential constants are identified

# via-points of the closed path inside the 9 x 9 m map (m); curvature radius varies along it
# (samples of r = 3.3 + 0.45 cos(3 phi) about the map centre: radius of curvature 1.25 m to straight,
# with left and right bends)
VIA_POINTS_M = ((8.25, 4.5), (7.06, 6.36), (5.41, 7.29), (3.37, 7.98), (1.72, 6.52), (1.65, 4.5),
                (1.72, 2.48), (3.37, 1.02), (5.41, 1.71), (7.06, 2.64))


@dataclass
class ExperimentConfig:
    """Settings of the lap experiment (defaults: the paper's setup where it gives one).

    Attributes
    ----------
    n_robots, n_laps : robots on the path (paper: 5) and laps each drives.
    seed : seed of every random draw (terrain map, start positions, noise).
    dt_s : integration and logging period (s).
    speed_mps : forward speed command (m/s).
    k_lateral_per_m2, k_heading_radps : gains of the path-following law
        (:func:`terrainml.slipmap.tracker.path_following_yaw_rate`).
    map_size_m, patch_size_m : square map and patch sizes (paper: 9 and 3).
    min_patch_samples : samples a robot needs on a patch before it fits that patch.
    vel_noise_mps, yaw_rate_noise_radps : reference-velocity noise (1 sigma).
    encoder_noise_radps : wheel-speed noise (1 sigma).
    process_noise_mps : white noise on the true track slippage (terrain roughness).
    outlier_fraction, outlier_mps : share of reference samples with a gross error, and its size
        (uniform in +-outlier_mps on v_x and v_y).
    norm : IRLS robust norm ("huber" or "bisquare").
    fixed_point_iterations : 1 (default) applies eq. 8 in the paper's one-step form
        ``omega_des = omega + beta(omega) / R``. More steps solve ``omega_des = omega + beta(omega_des) / R``
        (exact with the true slippage, but it amplifies estimation errors). The slip angle used by the
        tracker is predicted at the last ``omega_des`` iterate.
    ridge : relative ridge term of the map solve (:class:`SlipMapConfig`).
    speed_variation, speed_cycles_per_lap : relative amplitude and frequency of the speed command's
        slow variation along the path (on top of slowing down in bends).
    jitter : relative spread of a patch's slip parameters around its class's nominal values.
    """

    n_robots: int = 5
    n_laps: int = 5
    seed: int = 0
    dt_s: float = 0.05
    speed_mps: float = 0.5
    k_lateral_per_m2: float = 4.0
    k_heading_radps: float = 2.0
    map_size_m: float = 9.0
    patch_size_m: float = 3.0
    min_patch_samples: int = 60
    vel_noise_mps: float = 0.02
    yaw_rate_noise_radps: float = 0.01
    encoder_noise_radps: float = 0.05
    process_noise_mps: float = 0.005
    outlier_fraction: float = 0.05
    outlier_mps: float = 0.5
    norm: str = "huber"
    fixed_point_iterations: int = 1
    ridge: float = 1e-4
    speed_variation: float = 0.2
    speed_cycles_per_lap: float = 2.37
    jitter: float = 0.15

    def check(self) -> None:
        if self.n_robots < 1 or self.n_laps < 2:
            raise ValueError("need at least 1 robot and 2 laps")
        for name in ("dt_s", "speed_mps", "k_lateral_per_m2", "k_heading_radps", "map_size_m", "patch_size_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")
        if not 0 <= self.outlier_fraction < 0.5:
            raise ValueError("outlier_fraction must be in [0, 0.5)")

    def grid(self) -> PatchGrid:
        """The patch map (``map_size_m`` x ``map_size_m`` in patches of ``patch_size_m``)."""
        return PatchGrid(self.map_size_m, self.patch_size_m)

    def noise(self) -> TrackedNoise:
        """The simulated robots' process and sensor noise."""
        return TrackedNoise(process_noise_mps=self.process_noise_mps,
                            encoder_noise_radps=self.encoder_noise_radps, vel_noise_mps=self.vel_noise_mps,
                            yaw_rate_noise_radps=self.yaw_rate_noise_radps,
                            outlier_fraction=self.outlier_fraction, outlier_mps=self.outlier_mps)


def identify_exponential(model: PatchSlipModel, patch: int, speed_mps: float, radius_m: float,
                         track_m: float) -> ExponentialSlipModel:
    """Identify the exponential constants on open-loop constant-radius turns on one patch (noise-free)."""
    radii = np.geomspace(0.8, 20.0, 40)
    radii = np.r_[radii, -radii]
    v = np.full_like(radii, speed_mps)
    w = v / radii
    wl, wr = wheel_speeds_from_twist_radps(v, w, radius_m, track_m)
    bl, br, al = model.slippage(np.full(len(radii), patch), wl, wr, radius_m, track_m)
    return ExponentialSlipModel.identify(v, w, bl, br, al)


# ---------------------------------------------------------------------------- one method's laps
@dataclass
class _MethodResult:
    lap_error_m: np.ndarray  # (n_robots, n_laps) mean cross-track error
    traj_robot0: list  # per lap: array (k, 2)
    n_refits: int = 0
    final_map: SlipMap | None = None


class _SampleLog:
    """Per-robot log of the IRLS inputs (wheel speeds), targets (eq. 5-7) and patch of each step."""

    def __init__(self, n_robots: int, max_steps: int):
        self.x = np.zeros((n_robots, max_steps, 2))
        self.y = np.zeros((n_robots, max_steps, 3))
        self.patch = np.zeros((n_robots, max_steps), dtype=int)
        self.n = 0

    def append(self, x, y, patch) -> None:
        self.x[:, self.n], self.y[:, self.n], self.patch[:, self.n] = x, y, patch
        self.n += 1

    def robot(self, k: int):
        """``(x, y, patch)`` logged so far by robot ``k``."""
        return self.x[k, :self.n], self.y[k, :self.n], self.patch[k, :self.n]


def _speed_profile_mps(path: ClosedSplinePath, idx, progress_m, cfg: ExperimentConfig):
    """Forward speed command along the path: slower in tight bends, plus a slow variation whose period
    does not divide the lap, so successive laps visit new (omega_L, omega_R) combinations."""
    kappa = np.abs(path.curvature_per_m[idx])
    phase = 2 * np.pi * cfg.speed_cycles_per_lap * progress_m / path.length_m
    return cfg.speed_mps * (1.0 - 0.3 * kappa / np.abs(path.curvature_per_m).max()) * (
        1.0 + cfg.speed_variation * np.sin(phase))


@dataclass(frozen=True)
class _SlipSources:
    """What a compensation method predicts slippage from.

    Attributes
    ----------
    truth : the true patch slip model (the ``oracle`` method's upper bound).
    exponential : the exponential model of the ``exponential`` method.
    patch_keys : ndarray (n_patches,) of str, the slip map's key of every patch (the ``irls`` method).
    """

    truth: PatchSlipModel
    exponential: ExponentialSlipModel
    patch_keys: np.ndarray


@dataclass(frozen=True)
class _Tracks:
    """The tracked robot's geometry: sprocket radius and track width, m."""

    radius_m: float
    track_m: float


def _compensated_wheel_speeds(method: str, v_cmd, w_cmd, patch, sources: _SlipSources, global_map: SlipMap | None,
                              tracks: _Tracks, iterations: int):
    """Wheel-speed set-points ``(omega_L, omega_R)`` (rad/s) and predicted slip angle (rad) of one method.

    ``v_cmd`` (m/s), ``w_cmd`` (rad/s), ``patch``: per robot (n,). Paper eq. 8, evaluated at the
    compensated speeds by ``iterations`` fixed-point steps.
    """
    radius_m, track_m = tracks.radius_m, tracks.track_m
    wl, wr = wheel_speeds_from_twist_radps(v_cmd, w_cmd, radius_m, track_m)
    if method == "exponential":
        bl, br, al = sources.exponential.predict(v_cmd, w_cmd)
        return (compensate_wheel_speed_radps(wl, bl, radius_m),
                compensate_wheel_speed_radps(wr, br, radius_m), al)
    if method == "oracle" or (method == "irls" and global_map is not None):
        wl0, wr0 = wl, wr
        for _ in range(iterations):
            if method == "oracle":  # true slippage (diagnostic upper bound)
                bl, br, al = sources.truth.slippage(patch, wl, wr, radius_m, track_m)
            else:
                pred = global_map.predict(sources.patch_keys[patch], np.c_[wl, wr], fill=0.0)
                bl, br, al = pred[:, 0], pred[:, 1], pred[:, 2]
            wl = compensate_wheel_speed_radps(wl0, bl, radius_m)
            wr = compensate_wheel_speed_radps(wr0, br, radius_m)
        return wl, wr, al
    return wl, wr, np.zeros(len(wl))


def _local_map(log: _SampleLog, k: int, keys, smap_cfg: SlipMapConfig, min_samples: int) -> SlipMap:
    """Robot ``k``'s IRLS fit of every patch it has enough samples of, sent as a JSON message."""
    local = SlipMap(smap_cfg, robot_id=f"robot{k}")
    x, y, patches = log.robot(k)
    for p in np.unique(patches):
        sel = patches == p
        if sel.sum() >= min_samples:
            local.fit_patch(keys[p], x[sel], y[sel])
    # robots exchange their estimates as JSON messages (any transport)
    return SlipMap.from_json(local.to_json())


def simulate_method(method: str, cfg: ExperimentConfig, path: ClosedSplinePath, truth: PatchSlipModel,
                    exp_model: ExponentialSlipModel, start_idx: np.ndarray, radius_m: float, track_m: float,
                    noise_seed: np.random.SeedSequence, progress: Callable[[float], None] | None = None
                    ) -> _MethodResult:
    """Drive every robot ``cfg.n_laps`` laps with one compensation method (or ``"oracle"``)."""
    if method not in METHODS + ("oracle",):
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    n = cfg.n_robots
    grid = cfg.grid()
    keys = grid.keys()
    fleet = TrackedFleet(truth, grid, radius_m, track_m, path.points_m[start_idx],
                         path.heading_rad[start_idx], cfg.dt_s, cfg.noise(), noise_seed)
    lap_len = path.length_m
    max_steps = int(3.0 * cfg.n_laps * lap_len / (cfg.speed_mps * cfg.dt_s)) + 10
    omega_max = 2.5 * cfg.speed_mps / radius_m

    idx = start_idx.copy()
    prog = np.zeros(n)
    alpha_hat = np.zeros(n)
    err_sum = np.zeros((n, cfg.n_laps))
    err_cnt = np.zeros((n, cfg.n_laps))
    half_done = np.ones(n, dtype=int)  # refits start when progress reaches 2 half laps
    log = _SampleLog(n, max_steps)
    local_maps: dict[int, SlipMap] = {}
    global_map: SlipMap | None = None
    smap_cfg = SlipMapConfig(degree=3, norm=cfg.norm, input_scale_radps=cfg.speed_mps / radius_m,
                             wheel_radius_m=radius_m, track_width_m=track_m, ridge=cfg.ridge)
    traj0: list[list] = [[] for _ in range(cfg.n_laps)]
    n_refits = 0
    rows = np.arange(n)
    sources, tracks = _SlipSources(truth, exp_model, keys), _Tracks(radius_m, track_m)

    for step in range(max_steps):
        if not (np.floor(prog / lap_len).astype(int) < cfg.n_laps).any():
            break
        patch = fleet.patch()
        # ---- tracker: path following on the velocity direction yaw + alpha_hat
        w_cmd = path_following_yaw_rate(fleet.xy_m, fleet.yaw_rad, path, idx, cfg.speed_mps,
                                        cfg.k_lateral_per_m2, cfg.k_heading_radps, alpha_hat)
        v_cmd = _speed_profile_mps(path, idx, prog, cfg)
        wl, wr, alpha_hat = _compensated_wheel_speeds(method, v_cmd, w_cmd, patch, sources, global_map, tracks,
                                                      cfg.fixed_point_iterations)
        # ---- plant and sensors (terrainml.sim.tracked)
        meas = fleet.step(np.clip(wl, -omega_max, omega_max), np.clip(wr, -omega_max, omega_max))
        # ---- slippage targets from the measurements (paper eq. 5-7)
        b_l, b_r = longitudinal_slippage_mps(meas.omega_l_radps, meas.omega_r_radps, meas.vx_mps,
                                             meas.yaw_rate_radps, radius_m, track_m)
        a_m = lateral_slip_angle_rad(meas.vx_mps, meas.vy_mps)
        log.append(np.c_[meas.omega_l_radps, meas.omega_r_radps], np.c_[b_l, b_r, a_m], patch)
        # ---- progress, cross-track error per lap
        xy = fleet.xy_m
        new_idx, _ = path.nearest(xy, idx)
        _, dist = path.nearest(xy)  # cross-track error: global nearest point
        d_idx = (new_idx - idx + path.n // 2) % path.n - path.n // 2
        prog = prog + d_idx * path.spacing_m
        idx = new_idx
        lap_now = np.floor(prog / lap_len).astype(int)
        ok = (lap_now >= 0) & (lap_now < cfg.n_laps)
        err_sum[rows[ok], lap_now[ok]] += dist[ok]
        err_cnt[rows[ok], lap_now[ok]] += 1
        if ok[0]:
            traj0[lap_now[0]].append(xy[0].copy())
        # ---- refit every half lap after the first lap, then merge (IRLS paper §I-A)
        if method == "irls":
            half = np.floor(prog / (0.5 * lap_len)).astype(int)
            due = np.flatnonzero((half > half_done) & (half >= 2))
            for k in due:
                local_maps[int(k)] = _local_map(log, k, keys, smap_cfg, cfg.min_patch_samples)
                half_done[k] = half[k]
                n_refits += 1
            if len(due):
                global_map = merge_maps(local_maps.values(), robot_id="global")
        if progress is not None and step % 200 == 0:
            progress(float(np.clip(prog, 0, None).sum() / (n * cfg.n_laps * lap_len)))

    lap_err = np.where(err_cnt > 0, err_sum / np.maximum(err_cnt, 1), np.nan)
    return _MethodResult(lap_error_m=lap_err, traj_robot0=[np.array(t).reshape(-1, 2) for t in traj0],
                         n_refits=n_refits, final_map=global_map)


# ---------------------------------------------------------------------------- experiment
@dataclass
class ExperimentResult:
    """Report dictionary plus data for the figure."""

    report: dict
    path: ClosedSplinePath
    truth: PatchSlipModel
    trajectories: dict = field(default_factory=dict)  # method -> list of per-lap arrays (robot 0)


def run_experiment(cfg: ExperimentConfig | None = None,
                   progress: Callable[[str, float], None] | None = None) -> ExperimentResult:
    """Run the three methods on the same terrain map, start positions and noise.

    Returns
    -------
    ExperimentResult whose ``report["mean_tracking_error_m"][method][lap]`` is the mean cross-track
    error (m) of lap ``lap`` (0-based list index; lap 1 first), averaged over the robots.
    """
    cfg = cfg or ExperimentConfig()
    cfg.check()
    robot = tracked_robot()
    radius_m, track_m = track_geometry(robot)
    ss_map, ss_start, ss_noise = np.random.SeedSequence(cfg.seed).spawn(3)
    grid = cfg.grid()
    truth = PatchSlipModel.draw(grid.n_patches, np.random.default_rng(ss_map), cfg.jitter)
    path = ClosedSplinePath(np.asarray(VIA_POINTS_M) * (cfg.map_size_m / 9.0))
    rng_start = np.random.default_rng(ss_start)
    start_idx = ((np.arange(cfg.n_robots) + rng_start.uniform(0, 0.5, cfg.n_robots))
                 * path.n / cfg.n_robots).astype(int) % path.n
    default = PatchSlipModel.from_s1([DEFAULT_CLASS], [CLASS_SLIP_AT_1MPS[DEFAULT_CLASS]])
    exp_model = identify_exponential(default, 0, cfg.speed_mps, radius_m, track_m)

    errors, trajs, refits = {}, {}, {}
    t0 = time.perf_counter()
    for m, method in enumerate(METHODS):
        cb = None if progress is None else (lambda f, m=m, method=method: progress(method, (m + f) / len(METHODS)))
        res = simulate_method(method, cfg, path, truth, exp_model, start_idx, radius_m, track_m,
                              ss_noise, cb)
        errors[method] = [float(v) for v in np.nanmean(res.lap_error_m, axis=0)]
        trajs[method] = res.traj_robot0
        refits[method] = res.n_refits
    elapsed = time.perf_counter() - t0
    report = {
        "schema": REPORT_SCHEMA,
        "schema_version": REPORT_VERSION,
        "config": asdict(cfg),
        "robot": robot.name,
        "path_length_m": round(path.length_m, 6),
        "patches": [{"key": grid.key(i), "class_id": int(truth.class_id[i]),
                     "class": class_name(int(truth.class_id[i])), "s1": float(truth.s1[i]),
                     "c_turn": float(truth.c_turn[i]), "alpha_max_rad": float(truth.alpha_max_rad[i])}
                    for i in range(len(truth.s1))],
        "exponential_constants": exp_model.to_dict(),
        "mean_tracking_error_m": errors,
        "irls_refits": refits["irls"],
        "model": "kinematic skid-steer with per-patch nonlinear slip (terrainml.sim.tracked)",
    }
    if progress is not None:
        progress("done", 1.0)
    result = ExperimentResult(report=report, path=path, truth=truth, trajectories=trajs)
    result.elapsed_s = elapsed  # not in the report: the report is deterministic
    return result


def write_report(result: ExperimentResult, out_json: str | Path) -> tuple[Path, Path]:
    """Write the JSON report and the PNG figure next to it (same stem)."""
    out_json = Path(out_json)
    out_json.parent.mkdir(parents=True, exist_ok=True)
    write_text(out_json, json.dumps(result.report, indent=2, sort_keys=True))
    png = plot_experiment(result, out_json.with_suffix(".png"))
    return out_json, png
