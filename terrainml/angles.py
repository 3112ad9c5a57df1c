"""Angle wrapping, one convention for the whole package: angles in rad, wrapped to (-pi, pi] (design §4).

``wrap_angle`` serves numpy code (scalars and arrays). The compiled EKF kernel has its own scalar
twin (``terrainml.estimation._kernel.wrap_scalar``, same formula and convention) because numba's
on-disk cache only watches the file that defines a compiled function; a test keeps the two equal.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["wrap_angle"]


def wrap_angle(a_rad: np.ndarray | float) -> np.ndarray | float:
    """Wrap angle(s) to (-pi, pi] (rad): pi stays pi, -pi becomes pi.

    Parameters
    ----------
    a_rad : float or array of any shape, rad.

    Returns
    -------
    float for a scalar input, otherwise an array of the input's shape.
    """
    w = np.mod(np.asarray(a_rad, dtype=float) + math.pi, 2.0 * math.pi) - math.pi
    w = np.where(w == -math.pi, math.pi, w)
    return float(w) if np.ndim(w) == 0 else w
