"""The slip-map lap experiment (IRLS paper Fig. 3-4, SYSTEM §13).

Several tracked skid-steer robots drive laps of a closed spline path over a 9 x 9 m map made of
3 x 3 m patches of different terrain. Each robot logs its wheel speeds and a reference body velocity
(RTK GPS + IMU, noisy, with occasional gross outliers) and computes the slippage targets of paper
eq. 5-7. After its first lap, and then every half lap, each robot refits its local IRLS estimators
(one per patch), sends its sufficient statistics as a JSON message, and every robot uses the merged
global map to compensate its wheel-speed set-points (eq. 8) and its tracker heading (alpha).
Three methods run on identical noise: ``none`` (unicycle control), ``exponential`` (fixed constants
identified once on a default terrain) and ``irls``. The report holds the mean cross-track error per
lap of each method.

Robot model (why not ``terrainml.sim``)
---------------------------------------
The full simulator integrates wheel spin dynamics and terramechanics at >= 500 Hz for swerve robots;
25 robot-laps x 3 methods of that would not fit the experiment's 3-minute budget, and the paper's
quantities (track slippage as a function of track speeds) are what matters here. So this module uses
a light *kinematic-with-slip* skid-steer model at ``dt_s`` (default 20 Hz): the low-level controller
holds the sprocket speeds at their set-points; the ground moves each track at ``R omega_i - beta_i``
and the body slides sideways at ``v_x tan(alpha)`` (paper eq. 1). The true slippage of each patch is
a seeded nonlinear function of the track speeds:

- longitudinal (traction) slip of each track ``s1 * v_i * (0.5 + 0.5 v_i^2)`` (m/s, odd in v_i),
  with ``s1`` the steady slip at 1 m/s of the patch's terrain class (SYSTEM §6.1 calibration
  targets) jittered by +-15 %;
- skid-steer turning slip ``+- c_turn * d / 2 * (1 + k_turn |d|)``, ``d = v_R - v_L``: the outer
  track slips (beta > 0), the inner one skids (beta < 0), so the robot turns less than kinematics says;
- lateral slip angle ``alpha = -alpha_max * tanh(v * omega_kin / a_ref)``: the body drifts out of turns;
- white process noise on the true slippage, white measurement noise on encoders and the reference
  velocity, and gross outliers (GPS glitches) on a fraction of the reference samples.

``c_turn`` and ``alpha_max`` grow with ``s1`` (softer ground slips more in turns).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Callable

import numpy as np

from terrainml.classes import class_name
from terrainml.slipmap.exponential import ExponentialSlipModel
from terrainml.slipmap.kinematics import (compensate_wheel_speed_radps, lateral_slip_angle_rad,
                                          longitudinal_slippage_mps, wheel_speeds_from_twist_radps)
from terrainml.slipmap.slipmap import SlipMap, SlipMapConfig, merge_maps
from terrainml.slipmap.tracker import ClosedSplinePath, path_following_yaw_rate

METHODS = ("none", "exponential", "irls")
REPORT_SCHEMA = "terrainml.experiments.slipmap_laps"
REPORT_VERSION = 1

# steady longitudinal slip ratio at 1 m/s per terrain class id (SYSTEM §6.1 calibration targets,
# mid-range); the patch's true slippage scales with it.
CLASS_SLIP_AT_1MPS = {0: 0.01, 1: 0.035, 2: 0.125, 3: 0.134, 4: 0.19, 5: 0.20, 6: 0.30, 7: 0.42}
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


@dataclass
class PatchSlipModel:
    """True slippage parameters of the patches (arrays over patches)."""

    class_id: np.ndarray
    s1: np.ndarray  # steady slip ratio at 1 m/s
    c_turn: np.ndarray  # share of the track speed difference lost to skid-steer slip
    k_turn_spmps: np.ndarray  # growth of c_turn with |d| (s/m)
    alpha_max_rad: np.ndarray
    a_ref_mps2: np.ndarray

    @classmethod
    def draw(cls, n_patches: int, rng: np.random.Generator, jitter: float = 0.15) -> "PatchSlipModel":
        """Terrain classes and jittered parameters for ``n_patches`` patches (seeded)."""
        ids = np.r_[rng.permutation(8), rng.integers(0, 8, size=max(n_patches - 8, 0))][:n_patches]
        s1 = np.array([CLASS_SLIP_AT_1MPS[int(i)] for i in ids]) * rng.uniform(1 - jitter, 1 + jitter, n_patches)
        return cls.from_s1(ids, s1)

    @classmethod
    def from_s1(cls, ids, s1) -> "PatchSlipModel":
        s1 = np.asarray(s1, float)
        n = len(s1)
        return cls(class_id=np.asarray(ids, int), s1=s1, c_turn=0.10 + 0.30 * s1,
                   k_turn_spmps=np.full(n, 0.2), alpha_max_rad=0.03 + 0.20 * s1,
                   a_ref_mps2=np.full(n, 0.3))

    def slippage(self, patch, omega_l_radps, omega_r_radps, radius_m: float, track_m: float):
        """True (beta_left_mps, beta_right_mps, alpha_rad) for each robot on patch ``patch``."""
        v_l = radius_m * np.asarray(omega_l_radps, float)
        v_r = radius_m * np.asarray(omega_r_radps, float)
        s1 = self.s1[patch]
        d = v_r - v_l
        turn = self.c_turn[patch] * 0.5 * d * (1.0 + self.k_turn_spmps[patch] * np.abs(d))
        beta_l = s1 * v_l * (0.5 + 0.5 * v_l ** 2) - turn
        beta_r = s1 * v_r * (0.5 + 0.5 * v_r ** 2) + turn
        v = 0.5 * (v_l + v_r)
        alpha = -self.alpha_max_rad[patch] * np.tanh(v * (d / track_m) / self.a_ref_mps2[patch])
        return beta_l, beta_r, alpha


def tracked_robot():
    """The experiment's robot spec (``terrainml/robots/skidsteer_tracked.yaml``)."""
    from terrainml.robot import RobotSpec

    ref = resources.files("terrainml.robots").joinpath("skidsteer_tracked.yaml")
    with resources.as_file(ref) as path:
        return RobotSpec.from_yaml(path)


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


# ---------------------------------------------------------------------------- simulation
@dataclass
class _MethodResult:
    lap_error_m: np.ndarray  # (n_robots, n_laps) mean cross-track error
    traj_robot0: list  # per lap: array (k, 2)
    n_refits: int = 0
    final_map: SlipMap | None = None


def _speed_profile_mps(path: ClosedSplinePath, idx, progress_m, cfg: ExperimentConfig):
    """Forward speed command along the path: slower in tight bends, plus a slow variation whose period
    does not divide the lap, so successive laps visit new (omega_L, omega_R) combinations."""
    kappa = np.abs(path.curvature_per_m[idx])
    phase = 2 * np.pi * cfg.speed_cycles_per_lap * progress_m / path.length_m
    return cfg.speed_mps * (1.0 - 0.3 * kappa / np.abs(path.curvature_per_m).max()) * (
        1.0 + cfg.speed_variation * np.sin(phase))


def _patch_index(xy, cfg: ExperimentConfig):
    n = int(round(cfg.map_size_m / cfg.patch_size_m))
    col = np.clip(np.floor(xy[:, 0] / cfg.patch_size_m).astype(int), 0, n - 1)
    row = np.clip(np.floor(xy[:, 1] / cfg.patch_size_m).astype(int), 0, n - 1)
    return row * n + col


def _patch_key(i: int, n_side: int) -> str:
    return f"r{i // n_side}c{i % n_side}"


def simulate_method(method: str, cfg: ExperimentConfig, path: ClosedSplinePath, truth: PatchSlipModel,
                    exp_model: ExponentialSlipModel, start_idx: np.ndarray, radius_m: float, track_m: float,
                    noise_seed: np.random.SeedSequence, progress: Callable[[float], None] | None = None
                    ) -> _MethodResult:
    """Drive every robot ``cfg.n_laps`` laps with one compensation method."""
    if method not in METHODS + ("oracle",):
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    rng = np.random.default_rng(noise_seed)
    n = cfg.n_robots
    n_side = int(round(cfg.map_size_m / cfg.patch_size_m))
    keys_all = np.array([_patch_key(i, n_side) for i in range(n_side * n_side)], dtype=object)
    lap_len = path.length_m
    max_steps = int(3.0 * cfg.n_laps * lap_len / (cfg.speed_mps * cfg.dt_s)) + 10
    omega_max = 2.5 * cfg.speed_mps / radius_m

    xy = path.points_m[start_idx].copy()
    yaw = path.heading_rad[start_idx].copy()
    idx = start_idx.copy()
    prog = np.zeros(n)
    alpha_hat = np.zeros(n)
    err_sum = np.zeros((n, cfg.n_laps))
    err_cnt = np.zeros((n, cfg.n_laps))
    half_done = np.ones(n, dtype=int)  # refits start when progress reaches 2 half laps
    # per-robot logs
    log_x = np.zeros((n, max_steps, 2))
    log_y = np.zeros((n, max_steps, 3))
    log_p = np.zeros((n, max_steps), dtype=int)
    n_log = 0
    local_maps: dict[int, SlipMap] = {}
    global_map: SlipMap | None = None
    smap_cfg = SlipMapConfig(degree=3, norm=cfg.norm, input_scale_radps=cfg.speed_mps / radius_m,
                             wheel_radius_m=radius_m, track_width_m=track_m, ridge=cfg.ridge)
    traj0: list[list] = [[] for _ in range(cfg.n_laps)]
    n_refits = 0
    rows = np.arange(n)

    for step in range(max_steps):
        lap = np.floor(prog / lap_len).astype(int)
        active = lap < cfg.n_laps
        if not active.any():
            break
        patch = _patch_index(xy, cfg)
        # ---- tracker: path following on the velocity direction yaw + alpha_hat
        w_cmd = path_following_yaw_rate(xy, yaw, path, idx, cfg.speed_mps, cfg.k_lateral_per_m2,
                                        cfg.k_heading_radps, alpha_hat)
        v_cmd = _speed_profile_mps(path, idx, prog, cfg)
        wl, wr = wheel_speeds_from_twist_radps(v_cmd, w_cmd, radius_m, track_m)
        # ---- compensation (paper eq. 8), evaluated at the compensated speeds by fixed-point iteration
        if method == "exponential":
            bl, br, al = exp_model.predict(v_cmd, w_cmd)
            wl = compensate_wheel_speed_radps(wl, bl, radius_m)
            wr = compensate_wheel_speed_radps(wr, br, radius_m)
        elif method == "oracle" or (method == "irls" and global_map is not None):
            wl0, wr0 = wl, wr
            for _ in range(cfg.fixed_point_iterations):
                if method == "oracle":  # true slippage (diagnostic upper bound)
                    bl, br, al = truth.slippage(patch, wl, wr, radius_m, track_m)
                else:
                    pred = global_map.predict(keys_all[patch], np.c_[wl, wr], fill=0.0)
                    bl, br, al = pred[:, 0], pred[:, 1], pred[:, 2]
                wl = compensate_wheel_speed_radps(wl0, bl, radius_m)
                wr = compensate_wheel_speed_radps(wr0, br, radius_m)
        else:
            al = np.zeros(n)
        alpha_hat = al
        wl = np.clip(wl, -omega_max, omega_max)
        wr = np.clip(wr, -omega_max, omega_max)
        # ---- plant: kinematic skid-steer with slip (paper eq. 1, 5-7)
        tb_l, tb_r, t_al = truth.slippage(patch, wl, wr, radius_m, track_m)
        tb_l = tb_l + rng.normal(0.0, cfg.process_noise_mps, n)
        tb_r = tb_r + rng.normal(0.0, cfg.process_noise_mps, n)
        v_tl = radius_m * wl - tb_l
        v_tr = radius_m * wr - tb_r
        vx = 0.5 * (v_tl + v_tr)
        r = (v_tr - v_tl) / track_m
        vy = vx * np.tan(t_al)
        c, s = np.cos(yaw), np.sin(yaw)
        xy = xy + cfg.dt_s * np.c_[vx * c - vy * s, vx * s + vy * c]
        yaw = np.angle(np.exp(1j * (yaw + cfg.dt_s * r)))
        # ---- sensors: encoders, reference velocity (GPS + IMU) with gross outliers
        wl_m = wl + rng.normal(0.0, cfg.encoder_noise_radps, n)
        wr_m = wr + rng.normal(0.0, cfg.encoder_noise_radps, n)
        vx_m = vx + rng.normal(0.0, cfg.vel_noise_mps, n)
        vy_m = vy + rng.normal(0.0, cfg.vel_noise_mps, n)
        r_m = r + rng.normal(0.0, cfg.yaw_rate_noise_radps, n)
        glitch = rng.random(n) < cfg.outlier_fraction
        gx, gy = rng.uniform(-cfg.outlier_mps, cfg.outlier_mps, (2, n))
        vx_m = np.where(glitch, vx_m + gx, vx_m)
        vy_m = np.where(glitch, vy_m + gy, vy_m)
        b_l, b_r = longitudinal_slippage_mps(wl_m, wr_m, vx_m, r_m, radius_m, track_m)
        a_m = lateral_slip_angle_rad(vx_m, vy_m)
        log_x[:, n_log] = np.c_[wl_m, wr_m]
        log_y[:, n_log] = np.c_[b_l, b_r, a_m]
        log_p[:, n_log] = patch
        n_log += 1
        # ---- progress, cross-track error per lap
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
                local = SlipMap(smap_cfg, robot_id=f"robot{k}")
                for p in np.unique(log_p[k, :n_log]):
                    sel = log_p[k, :n_log] == p
                    if sel.sum() >= cfg.min_patch_samples:
                        local.fit_patch(keys_all[p], log_x[k, :n_log][sel], log_y[k, :n_log][sel])
                # robots exchange their estimates as JSON messages (any transport)
                local_maps[int(k)] = SlipMap.from_json(local.to_json())
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
    radius_m = robot.wheel_radius_m
    track_m = abs(robot.wheels[0].y_m - robot.wheels[1].y_m)
    ss_map, ss_start, ss_noise = np.random.SeedSequence(cfg.seed).spawn(3)
    n_side = int(round(cfg.map_size_m / cfg.patch_size_m))
    truth = PatchSlipModel.draw(n_side * n_side, np.random.default_rng(ss_map), cfg.jitter)
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
        "patches": [{"key": _patch_key(i, n_side), "class_id": int(truth.class_id[i]),
                     "class": class_name(int(truth.class_id[i])), "s1": float(truth.s1[i]),
                     "c_turn": float(truth.c_turn[i]), "alpha_max_rad": float(truth.alpha_max_rad[i])}
                    for i in range(len(truth.s1))],
        "exponential_constants": exp_model.to_dict(),
        "mean_tracking_error_m": errors,
        "irls_refits": refits["irls"],
        "model": "kinematic skid-steer with per-patch nonlinear slip (terrainml.experiments.slipmap_laps)",
    }
    if progress is not None:
        progress("done", 1.0)
    result = ExperimentResult(report=report, path=path, truth=truth, trajectories=trajs)
    result.elapsed_s = elapsed  # not in the report: the report is deterministic
    return result


def plot_experiment(result: ExperimentResult, out_png: str | Path) -> Path:
    """Figure like the paper's Fig. 3-4: the map with lap-1 and last-lap paths, and error per lap."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rep = result.report
    cfg = rep["config"]
    n_side = int(round(cfg["map_size_m"] / cfg["patch_size_m"]))
    ps = cfg["patch_size_m"]
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 5.2))
    grid = np.asarray(result.truth.s1).reshape(n_side, n_side)
    im = ax0.imshow(grid, origin="lower", extent=(0, n_side * ps, 0, n_side * ps), cmap="YlOrBr",
                    alpha=0.6)
    fig.colorbar(im, ax=ax0, label="steady slip at 1 m/s (patch)")
    for i, p in enumerate(rep["patches"]):
        ax0.text((i % n_side + 0.5) * ps, (i // n_side + 0.15) * ps, p["class"], ha="center", fontsize=7)
    pts = result.path.points_m
    ax0.plot(np.r_[pts[:, 0], pts[0, 0]], np.r_[pts[:, 1], pts[0, 1]], "k--", lw=1.2, label="desired")
    colors = {"none": "tab:red", "exponential": "tab:blue", "irls": "tab:green"}
    last = len(rep["mean_tracking_error_m"]["none"]) - 1
    for method, laps in result.trajectories.items():
        for lap, style in ((0, ":"), (last, "-")):
            if len(laps[lap]):
                ax0.plot(laps[lap][:, 0], laps[lap][:, 1], style, color=colors[method], lw=1,
                         label=f"{method} lap {lap + 1}")
    ax0.set_xlabel("x (m)")
    ax0.set_ylabel("y (m)")
    ax0.set_aspect("equal")
    ax0.set_title("Robot 1: desired path, first and last lap")
    ax0.legend(fontsize=7, loc="upper right")
    for method, errs in rep["mean_tracking_error_m"].items():
        ax1.plot(np.arange(1, len(errs) + 1), errs, "o-", color=colors[method], label=method)
    ax1.set_xticks(np.arange(1, len(rep["mean_tracking_error_m"]["none"]) + 1))
    ax1.set_xlabel("lap")
    ax1.set_ylabel("mean tracking error (m)")
    ax1.set_title(f"Average tracking error across laps ({cfg['n_robots']} robots)")
    ax1.grid(alpha=0.3)
    ax1.legend()
    fig.tight_layout()
    out_png = Path(out_png)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return out_png


def write_report(result: ExperimentResult, out_json: str | Path) -> tuple[Path, Path]:
    """Write the JSON report and the PNG figure next to it (same stem)."""
    out_json = Path(out_json)
    out_json.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(result.report, indent=2, sort_keys=True))
    png = plot_experiment(result, out_json.with_suffix(".png"))
    return out_json, png
