"""Window channels: the EST column, validity columns and scale behind each channel (design §8).

Raw windows hold the channels ``slip_1..N, current_1..N, vx, vy, r, imu_ax, imu_ay, imu_az`` (a
robot without camera gets no slip channels). Channel sources and validity:

==============  =========================  ==================================================
channel         EST column                 valid when
==============  =========================  ==================================================
``slip_i``      ``slip{i}``                finite, ``wheels_valid``, ``cam_valid``, ``estimator_ok``
``current_i``   ``wheel{i}_current_a``     finite, ``current_valid``
``vx, vy, r``   ``ekf_vx_mps`` ...         finite, ``estimator_ok``
``imu_a*``      ``imu_a*_mps2``            finite, ``imu_valid``
==============  =========================  ==================================================

A missing ``*_valid`` / ``estimator_ok`` column counts as valid (finiteness still applies); a
missing data column makes its channel invalid everywhere.

Side channels of a skid-steer robot without camera or steering (design §8, BorealTC):
``imu_wx, imu_wy, imu_wz`` (``imu_{roll,pitch,yaw}_rate_radps``, ``imu_valid``),
``current_left/right`` (the current of the first left/right wheel, ``current_valid``) and
``speed_left/right_mps`` (that wheel's ``omega * R``, ``wheels_valid``); left is y > 0.
"""

from __future__ import annotations

from typing import Sequence

from terrainml.robot import RobotSpec
from terrainml.schema import EST_OK, EST_VX, EST_VY, EST_YAW_RATE, est_wheel_col, wheel_col

__all__ = ["BODY_CHANNELS", "IMU_CHANNELS", "SIDE_CHANNEL_NAMES", "SENSOR_GROUPS", "channel_sensor_group",
           "is_side_channel_set", "side_wheels", "default_channels", "channel_source", "channel_column",
           "groups_read"]

BODY_CHANNELS = ("vx", "vy", "r")
IMU_CHANNELS = ("imu_ax", "imu_ay", "imu_az")
#: side channels of a camera-less skid-steer robot (design §8): IMU, then per-side current and speed
SIDE_CHANNEL_NAMES = IMU_CHANNELS + ("imu_wx", "imu_wy", "imu_wz", "current_left", "current_right",
                                     "speed_left_mps", "speed_right_mps")
_GYRO_COLUMNS = {"imu_wx": "imu_roll_rate_radps", "imu_wy": "imu_pitch_rate_radps",
                 "imu_wz": "imu_yaw_rate_radps"}
#: sensor groups a window channel (and a model) may need: wheel speeds, motor currents, IMU, camera
SENSOR_GROUPS = ("wheels", "currents", "imu", "cam")


def channel_sensor_group(channel: str) -> str:
    """Sensor group a channel needs: ``wheels``, ``currents``, ``imu``, ``cam`` or ``estimator``."""
    if channel.startswith("slip_"):
        return "cam"
    if channel.startswith("current_"):
        return "currents"
    if channel.startswith("speed_"):
        return "wheels"
    if channel.startswith("imu_"):
        return "imu"
    return "estimator"


def groups_read(sensors: Sequence[str], robot: RobotSpec) -> set[str]:
    """The channel groups (:func:`channel_sensor_group`) a model on the sensor groups ``sensors``
    reads: those, the wheels', and the estimator's body channels (``vx, vy, r``) unless the robot
    has a camera the model does without. The camera is the EKF's velocity reference: without it
    the body velocity is slip-compensated wheel odometry, not the signal a model trained on the
    camera-aided estimate has seen."""
    keep = set(sensors) | {"wheels"}
    if "cam" in keep or robot.camera is None:
        keep.add("estimator")
    return keep


def is_side_channel_set(channels: Sequence[str]) -> bool:
    """True when every channel is a side channel (the side-channel feature family applies)."""
    return bool(channels) and all(c in SIDE_CHANNEL_NAMES for c in channels)


def side_wheels(robot: RobotSpec) -> tuple[int, int]:
    """1-based indices of the first left (y > 0) and first right (y < 0) wheel (1, 2 if unclear)."""
    left = next((i for i, w in enumerate(robot.wheels, 1) if w.y_m > 0), 1)
    right = next((i for i, w in enumerate(robot.wheels, 1) if w.y_m < 0), min(2, robot.n_wheels))
    return left, right


def default_channels(robot: RobotSpec) -> tuple[str, ...]:
    """Raw-window channels for a robot: slips (only with a camera), currents, body, IMU."""
    n = robot.n_wheels
    slips = tuple(f"slip_{i}" for i in range(1, n + 1)) if robot.camera is not None else ()
    currents = tuple(f"current_{i}" for i in range(1, n + 1))
    return slips + currents + BODY_CHANNELS + IMU_CHANNELS


def channel_source(channel: str) -> tuple[str, tuple[str, ...]]:
    """EST column and validity columns of a channel, e.g. ``("slip1", ("wheels_valid", ...))``."""
    if channel.startswith("slip_"):
        i = int(channel[5:])
        return est_wheel_col("slip", i), ("wheels_valid", "cam_valid", EST_OK)
    if channel.startswith("current_") and channel[8:].isdigit():
        i = int(channel[8:])
        return wheel_col("current", i), ("current_valid",)
    body = {"vx": EST_VX, "vy": EST_VY, "r": EST_YAW_RATE}
    if channel in body:
        return body[channel], (EST_OK,)
    if channel in IMU_CHANNELS:
        return f"{channel}_mps2", ("imu_valid",)
    if channel in _GYRO_COLUMNS:
        return _GYRO_COLUMNS[channel], ("imu_valid",)
    # side channels: the wheel index is resolved per robot in cut_windows (side_wheels); the
    # Husky convention (left wheel 1, right wheel 2) is the default
    sides = {"current_left": (wheel_col("current", 1), "current_valid"),
             "current_right": (wheel_col("current", 2), "current_valid"),
             "speed_left_mps": (wheel_col("omega", 1), "wheels_valid"),
             "speed_right_mps": (wheel_col("omega", 2), "wheels_valid")}
    if channel in sides:
        col, v = sides[channel]
        return col, (v,)
    raise ValueError(f"unknown window channel {channel!r}; expected slip_i, current_i, vx, vy, r, "
                     f"imu_ax, imu_ay, imu_az or a side channel {list(SIDE_CHANNEL_NAMES[3:])}")


def channel_column(channel: str, robot: RobotSpec) -> tuple[str, tuple[str, ...], float]:
    """EST/run-table column, validity columns and scale of a channel for ``robot``.

    Side channels take the robot's first left/right wheel; ``speed_*_mps`` scales the wheel's
    rad/s by the wheel radius (m), every other channel has scale 1.
    """
    col, vcols = channel_source(channel)
    if channel.endswith(("_left", "_left_mps", "_right", "_right_mps")) and channel not in IMU_CHANNELS:
        left, right = side_wheels(robot)
        i = left if "_left" in channel else right
        col = wheel_col("current" if channel.startswith("current_") else "omega", i)
        if channel.startswith("speed_"):
            return col, vcols, float(robot.wheel_radius_m)
    return col, vcols, 1.0

