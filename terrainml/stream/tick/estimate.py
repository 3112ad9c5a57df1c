"""The estimation stage of a tick: the EKF warmed up before serving, its row read per wheel.

:func:`warm_up` loads the EKF's compiled kernels before the first tick; :class:`WheelRow` reads
an estimator (EST) row (:class:`~terrainml.estimation.row.EstimatorRow`) into the typed
:class:`WheelEstimate` a message serves per wheel (slip, dynamic state, longitudinal speed) and
completes it (a new row) with the raw columns the model's windows read.
"""

from __future__ import annotations

import logging
import math
from typing import Any, Mapping, NamedTuple, Sequence

from terrainml.estimation.online import OnlineEstimator
from terrainml.estimation.row import EstimatorRow, RowLayout
from terrainml.robot import RobotSpec
from terrainml.schema import EST_VX, EST_VY, EST_YAW_RATE, WHEEL_STATES, est_wheel_col, wheel_col

__all__ = ["WheelEstimate", "WheelRow", "warm_up"]

log = logging.getLogger("terrainml.stream")

#: EKF states that must be finite for a healthy tick
STATE_VARS = (EST_VX, EST_VY, EST_YAW_RATE)


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
    """Per-wheel fields of an EST row (:class:`~terrainml.estimation.row.EstimatorRow`), for N wheels.

    Parameters
    ----------
    n_wheels : N.
    raw_columns : run-table columns the model's windows read that the estimator may not pass
        through (e.g. gyro rates of side channels; the classifier's ``raw_columns``).
    """

    def __init__(self, n_wheels: int, raw_columns: Sequence[str] = ()):
        self.n = int(n_wheels)
        self.raw_columns = tuple(raw_columns)
        self._keys = {kind: [est_wheel_col(kind, i) for i in range(1, self.n + 1)]
                      for kind in ("slip", "state", "v_long")}
        self._missing: dict[RowLayout, tuple[str, ...]] = {}

    def complete(self, row: EstimatorRow, clean: Mapping[str, Any]) -> EstimatorRow:
        """``row`` followed by the raw columns it lacks, from the (sanitised) sample (NaN if
        absent there); ``row`` itself when it lacks none."""
        missing = self._missing.get(row.layout)
        if missing is None:
            missing = self._missing[row.layout] = tuple(k for k in self.raw_columns if k not in row)
        if not missing:
            return row
        return row.with_columns(missing, tuple([clean.get(k, math.nan) for k in missing]))

    def idle(self) -> "WheelEstimate":
        """Slip 0, state ``idle``, v_long 0 m/s on every wheel (a tick without a usable row)."""
        return WheelEstimate(False, [0.0] * self.n, ["idle"] * self.n, [0.0] * self.n)

    def _wheels(self, row: EstimatorRow, kind: str, default: Any) -> Sequence[Any]:
        values = row.wheels(kind, self.n)
        return values if values is not None else [row.get(k, default) for k in self._keys[kind]]

    def read(self, row: EstimatorRow) -> "WheelEstimate":
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
        row_slip = self._wheels(row, "slip", None)
        row_state = self._wheels(row, "state", "idle")
        row_v = self._wheels(row, "v_long", 0.0)
        for i in range(self.n):
            s = row_slip[i]
            slips[i] = float(s) if s is not None and math.isfinite(float(s)) else 0.0
            st = row_state[i]
            v = row_v[i]
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
