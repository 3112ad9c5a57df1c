"""Per-run terrain realisations for the simulator: layouts, force tables, roughness (design §6).

Every force curve comes from :mod:`terrainml.lookup.terramechanics` (the one source of truth); this
module only tabulates it, per terrain cell of a run, on a (load x slip) grid so the compiled physics
kernel can interpolate values and slopes cheaply.

Layouts
-------
A :class:`TerrainLayout` is a grid of class ids over the ``world`` plane: one cell for a single-terrain
run, a row of cells along x for a mixed-terrain course, 3 x 3 cells of 3 m for the 9 x 9 m patch map.
Positions outside the grid take the nearest cell. Each cell may carry a surface slope
(``slope_x_rad``, ``slope_y_rad``: the angle of the ground along world +x and +y, positive when it
rises; design §6); the physics reads the cell under the body origin.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from terrainml.classes import class_id as _class_id
from terrainml.lookup import terramechanics as tm

SLIP_GRID = np.linspace(-1.0, 1.0, 801)              # table slip points
LOAD_FACTORS = np.array([0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 3.0])   # x static wheel load
ALPHA_GRID = np.linspace(-np.pi / 2, np.pi / 2, 361)  # slip angle points (rad)
N_ROUGH = 6                                         # sinusoids per roughness profile


@dataclass(frozen=True)
class TerrainLayout:
    """Class ids on a world grid: ``grid[ix, iy]`` covers x in [x0 + ix*cell, x0 + (ix+1)*cell)."""

    grid: np.ndarray                      # (nx, ny) int class ids
    cell_m: float = 1e6
    origin_xy_m: tuple[float, float] = (-5e5, -5e5)
    slope_x_rad: np.ndarray | float | None = None   # scalar or (nx, ny): ground angle along world x
    slope_y_rad: np.ndarray | float | None = None   # ... along world y (rad, > 0 rising)

    def slopes(self) -> tuple[np.ndarray, np.ndarray]:
        """(nx, ny) slope grids along world x and y (rad; zeros when none given)."""
        out = []
        for s in (self.slope_x_rad, self.slope_y_rad):
            a = np.zeros(self.grid.shape) if s is None else np.broadcast_to(np.asarray(s, float), self.grid.shape)
            if np.any(np.abs(a) >= np.pi / 2):
                raise ValueError("TerrainLayout: slopes must be in (-pi/2, pi/2) rad")
            out.append(np.array(a, dtype=float))
        return out[0], out[1]

    def with_grade(self, slope_x_rad=0.0, slope_y_rad=0.0) -> "TerrainLayout":
        """A copy with slopes (scalar or (nx, ny) grids, rad) along world x and y."""
        return replace(self, slope_x_rad=slope_x_rad, slope_y_rad=slope_y_rad)

    def grade_at(self, x_m, y_m) -> tuple[np.ndarray, np.ndarray]:
        """Slopes (rad) along world x and y of the cells under world points."""
        sx, sy = self.slopes()
        c = self.cell_index(x_m, y_m)
        return sx.reshape(-1)[c], sy.reshape(-1)[c]

    @classmethod
    def uniform(cls, terrain: int | str) -> "TerrainLayout":
        return cls(np.array([[_class_id(terrain)]], dtype=np.int64))

    @classmethod
    def course(cls, terrains, segment_m: float, start_x_m: float = -1.0) -> "TerrainLayout":
        """Segments along world x, each ``segment_m`` long (first one starts at ``start_x_m``)."""
        ids = np.array([[_class_id(t)] for t in terrains], dtype=np.int64)
        return cls(ids, float(segment_m), (float(start_x_m), -5e5 + 0.0))

    @classmethod
    def patches(cls, grid, cell_m: float = 3.0, origin_xy_m=(0.0, 0.0)) -> "TerrainLayout":
        g = np.array([[_class_id(v) for v in row] for row in grid], dtype=np.int64)
        return cls(g, float(cell_m), (float(origin_xy_m[0]), float(origin_xy_m[1])))

    def cell_index(self, x_m, y_m) -> np.ndarray:
        """Flat cell index (ix * ny + iy) of world points (clamped to the grid)."""
        nx, ny = self.grid.shape
        cell_y = self.cell_m if ny > 1 or self.cell_m < 1e5 else 1e6
        ix = np.clip(np.floor((np.asarray(x_m) - self.origin_xy_m[0]) / self.cell_m), 0, nx - 1).astype(np.int64)
        iy = np.clip(np.floor((np.asarray(y_m) - self.origin_xy_m[1]) / cell_y), 0, ny - 1).astype(np.int64)
        return ix * ny + iy

    def class_at(self, x_m, y_m) -> np.ndarray:
        return self.grid.reshape(-1)[self.cell_index(x_m, y_m)]


@dataclass
class TerrainRealisation:
    """One run's terrain: parameters and force tables per layout cell (flat cell order)."""

    layout: TerrainLayout
    params: list[tm.TerrainParams]
    h_coef: np.ndarray          # (n_cells, n_loads, n_slip) H / W_static
    r_coef: np.ndarray          # (n_cells, n_loads, n_slip) R / W_static
    y_coef: np.ndarray          # (n_cells, n_alpha) F_y / W
    hmax_coef: np.ndarray       # (n_cells, n_loads) max |H| / W_static
    rough_amp_m: np.ndarray     # (n_cells, N_ROUGH)
    rough_k_radpm: np.ndarray   # (n_cells, N_ROUGH): each cell's class has its own wavelength band
    rough_phase: np.ndarray     # (n_wheels, N_ROUGH)
    load_ref_n: float
    extra: dict = field(default_factory=dict)
    z_tab_m: np.ndarray | None = None        # (n_cells, n_loads, n_slip) slip sinkage z(s, W)
    len_tab_m: np.ndarray | None = None      # (n_cells, n_loads) contact length at zero slip

    @property
    def cell_class(self) -> np.ndarray:
        return self.layout.grid.reshape(-1).astype(np.int64)


def realise(layout: TerrainLayout, robot, rng: np.random.Generator, spread: float = 0.15,
            params: list[tm.TerrainParams] | None = None) -> TerrainRealisation:
    """Draw each cell's parameters (``sample_params``) and tabulate its force curves.

    ``params`` overrides the draw (e.g. nominal parameters for calibration).
    """
    classes = layout.grid.reshape(-1)
    if params is None:
        params = [tm.sample_params(int(c), rng, spread) for c in classes]
    if len(params) != len(classes):
        raise ValueError(f"params: expected {len(classes)} entries (one per layout cell), got {len(params)}")
    w_ref = float(np.mean(robot.static_wheel_loads_n()))
    loads = LOAD_FACTORS * w_ref
    n_c = len(params)
    h = np.empty((n_c, len(loads), len(SLIP_GRID)))
    r = np.empty_like(h)
    z = np.empty_like(h)
    length = np.empty((n_c, len(loads)))
    y = np.empty((n_c, len(ALPHA_GRID)))
    for c, p in enumerate(params):
        lw = np.maximum(loads, 1e-6)[:, None]
        h[c] = tm.gross_thrust_n(p, lw, SLIP_GRID[None, :], robot) / w_ref
        r[c] = tm.motion_resistance_n(p, lw, SLIP_GRID[None, :], robot) / w_ref
        y[c] = tm.lateral_force_n(p, 1.0, ALPHA_GRID, robot)
        z[c] = tm.sinkage_m(p, lw, SLIP_GRID[None, :], robot)
        length[c] = tm.contact_length_m(p, z[c, :, len(SLIP_GRID) // 2], robot)
    h[:, 0, :] = 0.0
    r[:, 0, :] = 0.0
    hmax = np.max(np.abs(h), axis=2)
    # roughness: N_ROUGH sinusoids spread over the class's wavelength band, random shares of
    # the class rms (the band is the class's vibration signature, see TerrainParams)
    k = np.empty((n_c, N_ROUGH))
    amp = np.empty((n_c, N_ROUGH))
    for c, p in enumerate(params):
        wavelengths = np.geomspace(p.roughness_wavelength_min_m, p.roughness_wavelength_max_m, N_ROUGH)
        k[c] = 2 * np.pi / wavelengths
        share = rng.uniform(0.5, 1.5, N_ROUGH)
        share = share / np.sqrt(np.sum(share ** 2) / 2.0)        # rms of sum of sines = rms_m
        amp[c] = p.roughness_rms_m * share
    phase = rng.uniform(0.0, 2 * np.pi, (robot.n_wheels, N_ROUGH))
    return TerrainRealisation(layout, list(params), h, r, y, hmax, amp, k, phase, w_ref,
                              z_tab_m=z, len_tab_m=length)
