"""Patch map with per-patch track slippage: the terrain of the tracked-robot model (design §13).

A square map is cut into square patches (:class:`PatchGrid`); each patch gets a terrain class and
a true slippage law for a skid-steer (tracked) robot (:class:`PatchSlipModel`). The law is a
seeded nonlinear function of the left and right track speeds ``v_i = R omega_i`` (m/s):

- longitudinal (traction) slip of each track ``s1 v_i (0.5 + 0.5 v_i^2)`` (m/s, odd in v_i), with
  ``s1`` the steady slip at 1 m/s of the patch's terrain class (:data:`CLASS_SLIP_AT_1MPS`, the
  design §6.1 calibration targets) jittered by +-``jitter``;
- skid-steer turning slip ``+- c_turn d/2 (1 + k_turn |d|)``, ``d = v_R - v_L``: the outer track
  slips (beta > 0), the inner one skids (beta < 0), so the robot turns less than kinematics says;
- lateral slip angle ``alpha = -alpha_max tanh(v omega_kin / a_ref)``: the body drifts out of turns.

``c_turn`` and ``alpha_max`` grow with ``s1`` (softer ground slips more in turns). The class
calibration targets give per-class slip magnitudes directly, so this model does not go through
:mod:`terrainml.lookup.terramechanics`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CLASS_SLIP_AT_1MPS", "PatchGrid", "PatchSlipModel"]

# steady longitudinal slip ratio at 1 m/s per terrain class id (design §6.1 calibration targets,
# mid-range); a patch's true slippage scales with it.
CLASS_SLIP_AT_1MPS = {0: 0.01, 1: 0.035, 2: 0.125, 3: 0.134, 4: 0.19, 5: 0.20, 6: 0.30, 7: 0.42}


@dataclass(frozen=True)
class PatchGrid:
    """Square map of side ``map_size_m`` cut into square patches of side ``patch_size_m`` (m).

    Patches are numbered row-major from the map origin: ``i = row * n_side + col``, row along y,
    column along x (world frame, m). Positions outside the map belong to the nearest edge patch.
    """

    map_size_m: float = 9.0
    patch_size_m: float = 3.0

    @property
    def n_side(self) -> int:
        return int(round(self.map_size_m / self.patch_size_m))

    @property
    def n_patches(self) -> int:
        return self.n_side * self.n_side

    def index(self, xy_m: np.ndarray) -> np.ndarray:
        """Patch number of each position, ``xy_m`` shape (n, 2) -> int array shape (n,)."""
        n = self.n_side
        col = np.clip(np.floor(xy_m[:, 0] / self.patch_size_m).astype(int), 0, n - 1)
        row = np.clip(np.floor(xy_m[:, 1] / self.patch_size_m).astype(int), 0, n - 1)
        return row * n + col

    def key(self, i: int) -> str:
        """Name of patch ``i``: ``"r<row>c<col>"``."""
        return f"r{i // self.n_side}c{i % self.n_side}"

    def keys(self) -> np.ndarray:
        """Names of all patches (object array, shape (n_patches,)), indexable by :meth:`index`."""
        return np.array([self.key(i) for i in range(self.n_patches)], dtype=object)


@dataclass
class PatchSlipModel:
    """True slippage parameters of the patches (arrays of shape (n_patches,))."""

    class_id: np.ndarray
    s1: np.ndarray  # steady slip ratio at 1 m/s
    c_turn: np.ndarray  # share of the track speed difference lost to skid-steer slip
    k_turn_spmps: np.ndarray  # growth of c_turn with |d| (s/m)
    alpha_max_rad: np.ndarray
    a_ref_mps2: np.ndarray

    @classmethod
    def draw(cls, n_patches: int, rng: np.random.Generator, jitter: float = 0.15) -> "PatchSlipModel":
        """Terrain classes and jittered parameters for ``n_patches`` patches (seeded by ``rng``).

        The first eight patches (in a random order) cover every class once; the rest are drawn
        uniformly.
        """
        ids = np.r_[rng.permutation(8), rng.integers(0, 8, size=max(n_patches - 8, 0))][:n_patches]
        s1 = np.array([CLASS_SLIP_AT_1MPS[int(i)] for i in ids]) * rng.uniform(1 - jitter, 1 + jitter, n_patches)
        return cls.from_s1(ids, s1)

    @classmethod
    def from_s1(cls, ids, s1) -> "PatchSlipModel":
        """Patches of classes ``ids`` with steady slip ``s1`` at 1 m/s; the rest follows from s1."""
        s1 = np.asarray(s1, float)
        n = len(s1)
        return cls(class_id=np.asarray(ids, int), s1=s1, c_turn=0.10 + 0.30 * s1,
                   k_turn_spmps=np.full(n, 0.2), alpha_max_rad=0.03 + 0.20 * s1,
                   a_ref_mps2=np.full(n, 0.3))

    def slippage(self, patch, omega_l_radps, omega_r_radps, radius_m: float, track_m: float):
        """True slippage on patch ``patch`` at the given sprocket speeds.

        Parameters
        ----------
        patch : int array, shape (n,)  patch of each robot
        omega_l_radps, omega_r_radps : arrays, shape (n,)  left and right sprocket speeds (rad/s)
        radius_m, track_m : sprocket radius R and track width B (m)

        Returns
        -------
        (beta_left_mps, beta_right_mps, alpha_rad) : arrays, shape (n,)
        """
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
