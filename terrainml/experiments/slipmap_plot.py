"""Figure of the slip-map lap experiment, like the IRLS paper's Fig. 3-4 (design §13).

Left: the patch map coloured by steady slip, the desired path and robot 1's first and last laps of
every method. Right: the mean cross-track error per lap of every method.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from terrainml._figures import save_figure  # noqa: E402

__all__ = ["plot_experiment"]

METHOD_COLORS = {"none": "tab:red", "exponential": "tab:blue", "irls": "tab:green"}


def plot_experiment(result, out_png: str | Path) -> Path:
    """Write the figure of ``result`` to ``out_png``; return its path.

    ``result``: a :class:`terrainml.experiments.slipmap_laps.ExperimentResult` (its report, path,
    true patch slippage and robot 1's per-lap trajectories).
    """
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
    last = len(rep["mean_tracking_error_m"]["none"]) - 1
    for method, laps in result.trajectories.items():
        for lap, style in ((0, ":"), (last, "-")):
            if len(laps[lap]):
                ax0.plot(laps[lap][:, 0], laps[lap][:, 1], style, color=METHOD_COLORS[method], lw=1,
                         label=f"{method} lap {lap + 1}")
    ax0.set_xlabel("x (m)")
    ax0.set_ylabel("y (m)")
    ax0.set_aspect("equal")
    ax0.set_title("Robot 1: desired path, first and last lap")
    ax0.legend(fontsize=7, loc="upper right")
    for method, errs in rep["mean_tracking_error_m"].items():
        ax1.plot(np.arange(1, len(errs) + 1), errs, "o-", color=METHOD_COLORS[method], label=method)
    ax1.set_xticks(np.arange(1, len(rep["mean_tracking_error_m"]["none"]) + 1))
    ax1.set_xlabel("lap")
    ax1.set_ylabel("mean tracking error (m)")
    ax1.set_title(f"Average tracking error across laps ({cfg['n_robots']} robots)")
    ax1.grid(alpha=0.3)
    ax1.legend()
    return save_figure(fig, out_png)
