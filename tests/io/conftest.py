"""Small hand-made logs for the io tests (seconds to write)."""

from __future__ import annotations

import numpy as np
import pytest

from terrainml.io.mcap_writer import RosMcapWriter

N_WHEELS = 3
R_WHEEL = 0.165


def write_log(path, *, seconds=3.0, rate=100.0, chunk_size=16 * 1024, camera=True, imu_bad=None,
              imu_type=None, wheel_times=None):
    """A hand-made 3-wheel log whose values are simple functions of time (ground truth for tests).

    IMU (IMU axes = body for the reference robot): accel (0.1 t, 0, 9.81), gyro z 0.2.
    Wheels: omega_i = i + t (rad/s), steer_i = 0.1 i. Currents 2 + i. Camera: straight at 1 m/s.
    Terrain label 3. Returns the number of messages written per topic.
    """
    from terrainml.io import t265, topics

    n = int(round(seconds * rate))
    counts = {}
    ts = np.arange(n) / rate
    with RosMcapWriter(path, N_WHEELS, chunk_size=chunk_size) as w:
        for k, t in enumerate(ts):
            if imu_type:
                w.write(topics.IMU, t, {"data": "not an imu"}, datatype=imu_type)
            else:
                acc = (0.1 * t, 0.0, 9.81)
                if imu_bad is not None and k in imu_bad:
                    acc = (np.nan, np.inf, 9.81)
                w.write_imu(t, acc, (0.0, 0.0, 0.2))
            counts[topics.IMU] = counts.get(topics.IMU, 0) + 1
            wt = t if wheel_times is None else None
            if wt is not None:
                w.write_wheel_joints(t, [i + t for i in range(1, 4)], [0.1 * i for i in range(1, 4)])
                counts[topics.WHEEL_JOINTS] = counts.get(topics.WHEEL_JOINTS, 0) + 1
            w.write_motor_current(t, [2.0 + i for i in range(1, 4)])
            counts[topics.MOTOR_CURRENT] = counts.get(topics.MOTOR_CURRENT, 0) + 1
            if camera:
                m = t265.body_to_t265_odometry(t * 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, (0.6685, -0.26875, 0.0))
                w.write_camera_odom(t, m["position_m"][0], m["orientation_xyzw"][0], m["linear_mps"][0],
                                    m["angular_radps"][0], confidence=3.0)
                counts[topics.CAMERA_ODOM] = counts.get(topics.CAMERA_ODOM, 0) + 1
            if k % 100 == 0:
                w.write_terrain_label(t, 3)
                counts[topics.TERRAIN_LABEL] = counts.get(topics.TERRAIN_LABEL, 0) + 1
        if wheel_times is not None:
            for t in wheel_times:
                w.write_wheel_joints(t, [i + t for i in range(1, 4)], [0.1 * i for i in range(1, 4)])
                counts[topics.WHEEL_JOINTS] = counts.get(topics.WHEEL_JOINTS, 0) + 1
    return counts


@pytest.fixture(scope="session")
def good_log(tmp_path_factory):
    path = tmp_path_factory.mktemp("logs") / "good_run.mcap"
    counts = write_log(path)
    return path, counts


@pytest.fixture
def make_log():
    """The :func:`write_log` factory (fixtures avoid importing conftest by name)."""
    return write_log
