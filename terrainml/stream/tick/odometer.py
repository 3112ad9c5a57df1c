"""Distance travelled by the robot, the clock of classification age and fusion (design §11).

The predictor ages its fused classification by distance, not time (a robot standing still keeps
its class): :class:`Odometer` integrates the EKF's body speed over the ticks.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

from terrainml.schema import EST_VX, EST_VY

__all__ = ["Odometer"]


class Odometer:
    """Integrate the EKF's body speed over the ticks.

    Parameters
    ----------
    lateral_observed : whether the EKF's lateral speed is observed (steered wheels or an IMU).
        Fixed wheels constrain only forward speed and yaw rate: without steering or an IMU the
        lateral speed drifts (180 m/s on a BorealTC run without IMU), so only |v_x| counts.
    """

    def __init__(self, lateral_observed: bool):
        self.lateral_observed = bool(lateral_observed)
        self.distance_m = 0.0
        self._t_prev: float | None = None

    def advance(self, t: float, row: Mapping[str, Any] | None) -> float | None:
        """Distance (m) covered since the previous tick, added to :attr:`distance_m`; or None.

        ``row``: the tick's EST row (``ekf_vx_mps``, ``ekf_vy_mps``, m/s).
        None for the first tick of a timeline, an unhealthy tick (``row`` None: its speed is not
        trusted), a speed that is not a finite number, or a step that is not forward in time
        (dt is bounded by the clock policy, <= max_clock_gap_s).
        """
        dt = 0.0 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        if row is None or not dt > 0:
            return None
        try:
            vx, vy = float(row.get(EST_VX, 0.0)), float(row.get(EST_VY, 0.0))
            v = math.hypot(vx, vy) if self.lateral_observed else abs(vx)
        except (TypeError, ValueError):
            return None
        if not math.isfinite(v):
            return None
        d = v * dt
        self.distance_m += d
        return d

    def reset(self) -> None:
        """A new timeline: the next tick has no predecessor (the distance is kept)."""
        self._t_prev = None
