"""mu_net(s) curves of every class with the chosen targets (like thesis Fig. 8.1)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from terrainml._figures import save_figure  # noqa: E402
from terrainml.lookup import terramechanics as tm  # noqa: E402
from terrainml.lookup.table import DesiredSlipTable, mu_net_curve, slip_grid  # noqa: E402
from terrainml.robot import RobotSpec, reference_robot  # noqa: E402

__all__ = ["plot_table"]


def plot_table(out: str | Path, robot: RobotSpec | None = None,
               table: DesiredSlipTable | None = None, dpi: int = 120) -> Path:
    """Draw mu_net(s), s in [-0.8, 0.8], per class, with traction (^), braking (v) and steady (o)
    targets, and save a PNG.

    Parameters
    ----------
    out : output path (.png).
    robot : robot spec (default the reference robot); wheel loads, radius and width.
    table : table to mark (default ``DesiredSlipTable.build(robot)``).

    Returns
    -------
    Path of the written figure.
    """
    robot = robot if robot is not None else reference_robot()
    table = table if table is not None else DesiredSlipTable.build(robot)
    s = slip_grid()
    fig, ax = plt.subplots(figsize=(9.0, 5.5))
    colors = plt.get_cmap("viridis")(np.linspace(0.0, 0.95, len(table.rows)))
    for row, col in zip(table.rows, colors):
        if row.traction_kind == "given":  # direct catalogue targets: no force curve to draw
            for x, marker in zip((row.traction, row.braking, row.steady), ("^", "v", "o")):
                ax.plot([x], [0.0], marker=marker, color=col, ms=8, mec="black", mew=0.8)
            ax.plot([], [], color=col, lw=1.6, label=f"{row.id} {row.name} (given targets)")
            continue
        p = tm.TerrainParams(**row.params) if row.params else tm.nominal_params(row.id)
        mu = mu_net_curve(p, robot, s)
        ax.plot(s, mu, color=col, lw=1.6, label=f"{row.id} {row.name}")
        pts = np.array([row.traction, row.braking, row.steady])
        mu_pts = mu_net_curve(p, robot, pts)
        for (x, y), marker in zip(zip(pts, mu_pts), ("^", "v", "o")):
            ax.plot([x], [y], marker=marker, color=col, ms=8, mec="black", mew=0.8)
    ax.axhline(0.0, color="0.4", lw=0.8)
    ax.axvline(0.0, color="0.4", lw=0.8)
    ax.set_xlim(s[0], s[-1])
    ax.set_xlabel("longitudinal slip s (SAE; < 0 braking)")
    ax.set_ylabel(r"net traction coefficient $\mu_{net} = (H - R) / W$")
    ax.set_title(f"Desired-slip targets for robot '{robot.name}' "
                 r"($\blacktriangle$ traction, $\blacktriangledown$ braking, $\bullet$ steady)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower right", fontsize=8, ncol=2)
    return save_figure(fig, out, dpi)
