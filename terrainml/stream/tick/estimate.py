"""The estimation stage of a tick: the EKF warmed up before serving, its row read per wheel.

:func:`warm_up` loads the EKF's compiled kernels before the first tick; :class:`WheelRow` reads
an estimator (EST) row into the typed :class:`WheelEstimate` a message serves per wheel (slip,
dynamic state, longitudinal speed) and completes the row with the raw columns the model's
windows read.
"""

from __future__ import annotations

import logging
import math
from typing import Any, Mapping, NamedTuple, Sequence

from terrainml.estimation.online import OnlineEstimator
from terrainml.robot import RobotSpec
from terrainml.schema import WHEEL_STATES, est_wheel_col, wheel_col

__all__ = ["WheelEstimate", "WheelRow", "warm_up"]

log = logging.getLogger("terrainml.stream")

#: EKF states that must be finite for a healthy tick
STATE_VARS = ("ekf_vx_mps", "ekf_vy_mps", "ekf_yaw_rate_radps")


def warm_up(robot: RobotSpec, preset: str = "robust") -> None:
    """Run a throwaway OnlineEstimator at rest, so the first real tick is not slow.

    The EKF's compiled kernels load on first use (about 0.2 s); doing that before serving keeps
    the first served tick inside its deadline. Nothing of the predictor is touched.
    """
    sample: dict[str, Any] = {"t_s": 0.0, "imu_ax_mps2": 0.0, "imu_ay_mps2": 0.0,
                              "imu_az_mps2": 9.81, "imu_yaw_rate_radps": 0.0,
                              "cam_vx_mps": 0.0, "cam_vy_mps": 0.0, "cam_yaw_rate_radps": 0.0,
                              "cam_yaw_rad": 0.0}
    for i in range(1, robot.n_wheels + 1):
        sample.update({wheel_col(kind, i): 0.0 for kind in ("omega", "steer", "current")})
    try:
        est = OnlineEstimator(robot, preset)
        est.step(sample)
        est.step({**sample, "t_s": 0.01})
    except Exception as exc:  # noqa: BLE001 - warm-up is an optimisation only
        log.debug("warm-up skipped: %s", exc)


class WheelRow:
    """Per-wheel fields of an EST row, for N wheels.

    Parameters
    ----------
    n_wheels : N.
    raw_columns : run-table columns the model's windows read that the estimator may not pass
        through (e.g. gyro rates of side channels; the classifier's ``raw_columns``).
    """

    def __init__(self, n_wheels: int, raw_columns: Sequence[str] = ()):
        self.n = int(n_wheels)
        self.raw_columns = tuple(raw_columns)
        self._slip_keys = [est_wheel_col("slip", i) for i in range(1, self.n + 1)]
        self._state_keys = [est_wheel_col("state", i) for i in range(1, self.n + 1)]
        self._vlong_keys = [est_wheel_col("v_long", i) for i in range(1, self.n + 1)]

    def complete(self, row: dict, clean: dict) -> None:
        """Copy into ``row`` the raw columns of the (sanitised) sample it lacks (NaN if absent)."""
        for k in self.raw_columns:
            if k not in row:
                row[k] = clean.get(k, math.nan)

    def idle(self) -> "WheelEstimate":
        """Slip 0, state ``idle``, v_long 0 m/s on every wheel (a tick without a usable row)."""
        return WheelEstimate(False, [0.0] * self.n, ["idle"] * self.n, [0.0] * self.n)

    def read(self, row: Mapping[str, Any]) -> "WheelEstimate":
        """The per-wheel estimate of an EST row; ``finite`` False if an EKF state is not finite.

        Non-finite slip becomes 0 (e.g. no camera: slip unavailable); a wheel with a non-finite
        v_long is served as idle at 0 m/s; an unknown state as idle. Raises TypeError or
        ValueError on a value that is not a number.
        """
        ok = True
        for k in STATE_VARS:
            v = row.get(k, 0.0)
            if v is None or not math.isfinite(float(v)):
                ok = False
        slips, states, v_long = [0.0] * self.n, ["idle"] * self.n, [0.0] * self.n
        for i in range(self.n):
            s = row.get(self._slip_keys[i])
            slips[i] = float(s) if s is not None and math.isfinite(float(s)) else 0.0
            st = row.get(self._state_keys[i], "idle")
            v = row.get(self._vlong_keys[i], 0.0)
            v = float(v) if v is not None and math.isfinite(float(v)) else math.nan
            if math.isnan(v):
                st, v = "idle", 0.0
            states[i] = st if st in WHEEL_STATES else "idle"
            v_long[i] = v
        return WheelEstimate(ok, slips, states, v_long)


class WheelEstimate(NamedTuple):
    """What a tick serves per wheel from its estimator (EST) row (N wheels).

    Attributes
    ----------
    finite : the EKF's body states (``ekf_vx_mps``, ``ekf_vy_mps``, ``ekf_yaw_rate_radps``) are finite.
    slip : (N,) measured slip (EST ``slip{i}``), 0 where not finite.
    state : (N,) dynamic state (EST ``state{i}``), one of ``schema.WHEEL_STATES``.
    v_long_mps : (N,) longitudinal wheel-centre speed, m/s (EST ``v_long{i}_mps``).
    """

    finite: bool
    slip: list[float]
    state: list[str]
    v_long_mps: list[float]
