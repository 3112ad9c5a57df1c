"""Closed spline path and a pure-pursuit tracker (world frame, metres, radians).

The IRLS paper drives its robots along "a closed trajectory with different radius of curvature ...
connecting a set of via-points with cubic splines" with a Lyapunov controller from its ref. [1].
Here the path is a periodic cubic spline (``scipy.interpolate.CubicSpline``, ``bc_type="periodic"``)
and the tracker is pure pursuit. The predicted lateral slip angle ``alpha`` enters the tracker's
heading (design §13): the robot's velocity points along ``theta + alpha``, so pure pursuit steers
that direction, not the body axis, towards the look-ahead point.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline


class ClosedSplinePath:
    """Periodic cubic spline through via-points, sampled densely by arc length.

    Parameters
    ----------
    via_points_m : array, shape (k, 2)  world (x, y) via-points, not repeating the first.
    spacing_m : approximate distance between dense samples.
    """

    def __init__(self, via_points_m, spacing_m: float = 0.01):
        p = np.asarray(via_points_m, dtype=float)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) < 3:
            raise ValueError("via_points_m must have shape (k >= 3, 2)")
        closed = np.vstack([p, p[:1]])
        chord = np.r_[0.0, np.cumsum(np.hypot(*np.diff(closed, axis=0).T))]
        spline = CubicSpline(chord, closed, bc_type="periodic")
        fine = np.linspace(0.0, chord[-1], 20 * len(p) * 50, endpoint=False)
        pts = spline(fine)
        seg = np.hypot(*np.diff(np.vstack([pts, pts[:1]]), axis=0).T)
        s = np.r_[0.0, np.cumsum(seg)]
        self.length_m = float(s[-1])
        n = max(int(self.length_m / spacing_m), 100)
        s_dense = np.linspace(0.0, self.length_m, n, endpoint=False)
        u = np.interp(s_dense, s, np.r_[fine, chord[-1]])
        self.points_m = spline(u)
        d1 = spline(u, 1)
        d2 = spline(u, 2)
        self.heading_rad = np.arctan2(d1[:, 1], d1[:, 0])
        self.curvature_per_m = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / np.hypot(*d1.T) ** 3
        self.s_m = s_dense
        self.n = n
        self.spacing_m = self.length_m / n

    def nearest(self, xy_m, hint_idx=None, window: int | None = None):
        """Index of the nearest dense point and the distance to it (cross-track error, m).

        Parameters
        ----------
        xy_m : array, shape (m, 2)
        hint_idx : array of int, shape (m,), optional  previous indices; the search is then limited
            to ``hint_idx - window/4 .. hint_idx + window`` (keeps progress monotonic at crossings).
        """
        xy = np.atleast_2d(np.asarray(xy_m, dtype=float))
        if hint_idx is None:
            d = np.hypot(xy[:, None, 0] - self.points_m[None, :, 0], xy[:, None, 1] - self.points_m[None, :, 1])
            idx = np.argmin(d, axis=1)
            return idx, d[np.arange(len(xy)), idx]
        window = window or max(int(1.0 / self.spacing_m), 10)
        offs = np.arange(-window // 4, window + 1)
        cand = (np.asarray(hint_idx)[:, None] + offs[None, :]) % self.n
        pc = self.points_m[cand]
        d = np.hypot(xy[:, None, 0] - pc[..., 0], xy[:, None, 1] - pc[..., 1])
        j = np.argmin(d, axis=1)
        return cand[np.arange(len(xy)), j], d[np.arange(len(xy)), j]


def path_following_yaw_rate(xy_m, yaw_rad, path: ClosedSplinePath, idx, speed_mps: float,
                            k_lateral_per_m2: float = 4.0, k_heading_radps: float = 2.0,
                            slip_angle_rad=0.0):
    """Path-following yaw-rate command (rad/s) in the path's Frenet frame.

    ``omega = v kappa - k_y v e_y - k_theta sin(theta + alpha - theta_path)``: curvature feed-forward,
    feedback on the lateral offset ``e_y`` (m, positive left of the path) and on the heading of the
    velocity ``theta + alpha``. The form mirrors the IRLS paper's Lyapunov law (eq. 3-4: feed-forward
    ``omega_d`` and ``-k_theta sin(e_theta + alpha)``); with no slip it tracks the path with zero
    steady-state error, so any remaining error is the slippage the compensation failed to remove.

    Parameters
    ----------
    xy_m : array, shape (m, 2); yaw_rad : array, shape (m,)
    path : the reference path; idx : array of int, shape (m,), nearest dense indices
    speed_mps : forward speed command
    k_lateral_per_m2, k_heading_radps : feedback gains
    slip_angle_rad : array or float, predicted lateral slip angle alpha (0: none)
    """
    xy = np.atleast_2d(xy_m)
    p = path.points_m[idx]
    th_p = path.heading_rad[idx]
    e_y = -(xy[:, 0] - p[:, 0]) * np.sin(th_p) + (xy[:, 1] - p[:, 1]) * np.cos(th_p)
    e_th = np.asarray(yaw_rad) + slip_angle_rad - th_p
    return (speed_mps * path.curvature_per_m[idx] - k_lateral_per_m2 * speed_mps * e_y
            - k_heading_radps * np.sin(e_th))
