"""Slip-map benchmark: the lap experiment (IRLS paper Fig. 3-4) and the cost of the exact merge.

Records the experiment's wall time (acceptance: <= 3 minutes on 2 cores) and its per-lap table, and
compares the distributed merge of five robots' statistics (ours) with refitting all their samples
centrally by IRLS (reference).
"""

from __future__ import annotations

import time

import numpy as np

from terrainml.experiments.slipmap_laps import ExperimentConfig, run_experiment
from terrainml.slipmap import SlipMap, SlipMapConfig, merge_maps


def _merge_vs_central(n_robots: int = 5, n_per_robot: int = 4000) -> tuple[float, float, float]:
    rng = np.random.default_rng(0)
    cfg = SlipMapConfig(input_scale_radps=8.0)
    data = []
    for _ in range(n_robots):
        x = rng.uniform(2, 10, (n_per_robot, 2))
        y = np.c_[0.01 * x[:, 0], 0.01 * x[:, 1], 0.01 * (x[:, 0] - x[:, 1])] + rng.normal(0, 0.01, (n_per_robot, 3))
        data.append((x, y))
    msgs = [SlipMap(cfg, f"r{k}").fit_patch("p", x, y).to_json() for k, (x, y) in enumerate(data)]
    t0 = time.perf_counter()
    merge_maps([SlipMap.from_json(m) for m in msgs]).coef("p")
    t_merge = time.perf_counter() - t0
    t0 = time.perf_counter()
    SlipMap(cfg, "central").fit_patch("p", np.vstack([d[0] for d in data]), np.vstack([d[1] for d in data]))
    t_central = time.perf_counter() - t0
    return t_merge, t_central, float(np.mean([len(m) for m in msgs]))


def run(quick: bool = False) -> str:
    robots, laps = (3, 3) if quick else (5, 5)
    t0 = time.perf_counter()
    res = run_experiment(ExperimentConfig(n_robots=robots, n_laps=laps, seed=0))
    wall = time.perf_counter() - t0
    errs = res.report["mean_tracking_error_m"]
    lines = ["## Slip maps (IRLS paper lap experiment)", "",
             f"`terrainml slipmap experiment --robots {robots} --laps {laps} --seed 0`: "
             f"**{wall:.1f} s** wall (budget 180 s), {res.report['irls_refits']} local IRLS refits.", "",
             "| method | " + " | ".join(f"lap {i + 1}" for i in range(laps)) + " |",
             "|---|" + "---:|" * laps]
    for m, e in errs.items():
        lines.append(f"| {m} | " + " | ".join(f"{v:.4f}" for v in e) + " |")
    lines += ["", "Mean cross-track error (m) per lap, averaged over the robots.", ""]
    t_merge, t_central, msg_bytes = _merge_vs_central()
    lines += ["| step (5 robots x 4000 samples) | time (ms) |", "|---|---:|",
              f"| reference: central IRLS refit of all samples | {1e3 * t_central:.1f} |",
              f"| ours: parse 5 JSON messages + exact merge + solve | {1e3 * t_merge:.1f} |",
              f"| ratio (reference / ours) | {t_central / max(t_merge, 1e-9):.1f} x |", "",
              f"Mean message size per robot (one entry, three targets): {msg_bytes / 1024:.1f} KiB."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(run())
