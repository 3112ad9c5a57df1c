"""Estimation (design §7): planar EKF, per-wheel slip, dynamic state, consistency.

Public API
----------
- :func:`terrainml.estimation.run.estimate_run` (offline, a whole run table -> EST table)
- :class:`terrainml.estimation.online.OnlineEstimator` (online, one sample -> one EST row)
- :mod:`terrainml.estimation.ekf` (model, presets ``thesis`` and ``robust``)
- :mod:`terrainml.estimation.slip`, :mod:`terrainml.estimation.dynamic_state`
- :mod:`terrainml.estimation.consistency` (NIS, innovation statistics, truth metrics)
"""
