"""Figures of mission-suite reports (design §12, docs/missions.md).

* :func:`plot_mission` (one per traced mission): top, the route seen from above over its terrain
  patches, waypoints marked; middle, true slip per wheel over the distance travelled (spin
  threshold 0.8 dashed); bottom, sinkage per wheel over distance (belly clearance dashed).
* :func:`plot_policies` (one per call): success rate and median battery energy per metre per policy
  and family, from one report per policy.

Traces come from the report's sidecar ``.npz`` (``terrainml mission run --traces``): arrays named
``"{index}/{field}"`` of :class:`terrainml.experiments.mission_metrics.MissionLog`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from terrainml._figures import save_figure  # noqa: E402
from terrainml.experiments.mission_metrics import SPIN_SLIP  # noqa: E402

__all__ = ["load_traces", "plot_mission", "plot_policies"]

_SOIL_COLORS = {"pavement": "#bbbbbb", "compacted_dirt": "#d8c3a5", "short_grass": "#9bc57a",
                "gravel_on_firm_soil": "#a89f91", "tall_damp_grass": "#5f8f4a",
                "tilled_loam": "#8b6b4a", "dry_sand": "#f2d98c", "wet_mud": "#6b4f3a"}


def load_traces(npz_path: str | Path) -> dict[int, dict[str, np.ndarray]]:
    """Traces of a report's sidecar: {mission index: {field: array}}."""
    out: dict[int, dict[str, np.ndarray]] = {}
    with np.load(npz_path) as z:
        for key in z.files:
            i, name = key.split("/", 1)
            out.setdefault(int(i), {})[name] = z[key]
    return out


def plot_mission(row: dict[str, Any], trace: dict[str, np.ndarray], out_png: str | Path) -> Path:
    """Route over patches, slip and sinkage over distance of one mission; returns the PNG path."""
    fig, (ax0, ax1, ax2) = plt.subplots(3, 1, figsize=(10, 8), sharex=True,
                                        gridspec_kw={"height_ratios": [1.2, 1, 1]})
    x_end = max(row["route_m"], float(np.max(trace["x_m"]))) + 0.5
    ax0.axvspan(-0.5, x_end, color=_SOIL_COLORS.get(row["base"], "#dddddd"), alpha=0.5,
                label=row["base"])
    seen = {row["base"]}
    for x0, x1, cls in row["patches"]:
        ax0.axvspan(x0, x1, color=_SOIL_COLORS.get(cls, "#999999"), alpha=0.9,
                    label=None if cls in seen else cls)
        seen.add(cls)
    ax0.plot(trace["x_m"], trace["y_m"], "k-", lw=1.5, label="path (true)")
    wx = np.asarray(row["waypoints_x_m"])
    ax0.plot(wx, np.zeros_like(wx), "rv", ms=7, label="waypoints")
    ax0.set_ylim(-0.6, 0.6)
    ax0.set_ylabel("y, m")
    ok = "success" if row["success"] else "FAILED"
    ax0.set_title(f"{row['family']} / {row['terrain']} / seed {row['seed']} / {row['policy']}: {ok}, "
                  f"{row['time_s']:.1f} s (nominal {row['nominal_time_s']:.1f}), "
                  f"demand {row['demand_ratio']:.2f}", fontsize=9)
    ax0.legend(fontsize=7, ncol=5, loc="upper left")
    dist = np.concatenate([[0.0], np.cumsum(np.abs(trace["speed_mps"][1:]) * np.diff(trace["t_s"]))])
    slip = np.atleast_2d(trace["slip"].T).T
    for i in range(slip.shape[1]):
        ax1.plot(dist, slip[:, i], lw=0.8, label=f"wheel {i + 1}")
    ax1.axhline(SPIN_SLIP, color="r", ls="--", lw=0.8, label="spinning")
    ax1.set_ylim(-0.2, 1.05)
    ax1.set_ylabel("true slip")
    ax1.legend(fontsize=7, ncol=4)
    z = np.atleast_2d(trace["sinkage_m"].T).T
    for i in range(z.shape[1]):
        ax2.plot(dist, 1000 * z[:, i], lw=0.8, label=f"wheel {i + 1}")
    ax2.axhline(1000 * row["clearance_m"], color="r", ls="--", lw=0.8, label="clearance")
    ax2.set_ylabel("sinkage, mm")
    ax2.set_xlabel("distance travelled, m (slip, sinkage); x, m (route)")
    ax2.legend(fontsize=7, ncol=4)
    return save_figure(fig, out_png)


def plot_policies(reports: list[dict[str, Any]], out_png: str | Path) -> Path:
    """Success rate and median energy per metre per policy (bars per family); returns the path."""
    fams = sorted({r["family"] for rep in reports for r in rep["missions"]})
    labels = [rep.get("policy", f"report {k}") for k, rep in enumerate(reports)]
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4))
    width = 0.8 / max(len(reports), 1)
    for k, rep in enumerate(reports):
        succ, energy = [], []
        for f in fams:
            rows = [r for r in rep["missions"] if r["family"] == f]
            succ.append(100 * np.mean([r["success"] for r in rows]) if rows else np.nan)
            e = [r["energy_j_per_m"] for r in rows if r["energy_j_per_m"] is not None]
            energy.append(np.median(e) if e else np.nan)
        pos = np.arange(len(fams)) + (k - (len(reports) - 1) / 2) * width
        ax0.bar(pos, succ, width, label=labels[k])
        ax1.bar(pos, energy, width, label=labels[k])
    for ax, title in ((ax0, "success, %"), (ax1, "median battery energy, J/m")):
        ax.set_xticks(np.arange(len(fams)), fams)
        ax.set_title(title)
    ax0.set_ylim(0, 105)
    ax0.legend(fontsize=8)
    return save_figure(fig, out_png)
