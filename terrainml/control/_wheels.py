"""Per-wheel argument checks shared by the vectorised controllers (design §12)."""

from __future__ import annotations

import numpy as np


def per_wheel(x, n_wheels: int, name: str) -> np.ndarray:
    """``x`` as an (n_wheels,) float array: a scalar is broadcast to every wheel, any other shape is refused."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        a = np.full(n_wheels, float(a))
    if a.shape != (n_wheels,):
        raise ValueError(f"{name}: expected shape ({n_wheels},), got {a.shape}")
    return a
