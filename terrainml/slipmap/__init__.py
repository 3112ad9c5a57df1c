"""Slip maps (design §13, the IRLS paper): per-patch robust slippage estimators merged across robots.

- :mod:`terrainml.slipmap.irls`: :class:`IRLSRegressor` (polynomial features + statsmodels RLM) and
  local sufficient statistics.
- :mod:`terrainml.slipmap.slipmap`: :class:`SlipMap` (one estimator per patch or class), the exact
  merge :func:`merge_maps`, JSON messages.
- :mod:`terrainml.slipmap.kinematics`: paper eq. 5-8 (slippage, slip angle, compensation).
- :mod:`terrainml.slipmap.exponential`: the fixed exponential baseline.
- :mod:`terrainml.slipmap.tracker`: closed spline path and pure pursuit.
- :mod:`terrainml.experiments.slipmap_laps`: the lap experiment (paper Fig. 3-4).
- :mod:`terrainml.slipmap.fit`: fit a map from canonical run tables.
"""

from terrainml.slipmap.irls import IRLSRegressor, SufficientStats
from terrainml.slipmap.slipmap import TARGETS, SlipMap, SlipMapConfig, SlipMapError, merge_maps

__all__ = ["IRLSRegressor", "SufficientStats", "SlipMap", "SlipMapConfig", "SlipMapError", "merge_maps",
           "TARGETS"]
