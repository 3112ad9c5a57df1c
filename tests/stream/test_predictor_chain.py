"""The predictor over the real online estimator (EKF + slip + dynamic state)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from stream_fakes import FakeClassifier, FakeTable

from terrainml.testing import kinematic_run
from terrainml.stream.tick.predictor import Predictor
from terrainml.stream.transports.sources import iter_table_samples


@pytest.fixture(scope="module")
def run_with_dropout():
    from terrainml.robot import load_robot

    robot = load_robot()
    # 1 m/s cruise with 0.12 true slip on every wheel; the camera is silent 8.0-8.5 s
    table = kinematic_run(robot, duration_s=12.0, slip=0.12, terrain=4, seed=3,
                          cam_dropouts=((8.0, 8.5),))
    return robot, table


def test_real_estimator_serves_measured_slip_and_terrain(run_with_dropout):
    robot, table = run_with_dropout
    pred = Predictor(robot, FakeTable(), FakeClassifier())
    out = [pred.step(s) for s in iter_table_samples(table)]
    assert len(out) == len(table) and all(m is not None for m in out)
    cruise = [m for m in out if 5.0 <= m.t_s < 7.9]
    meas = np.array([m.slip_measured for m in cruise])
    assert np.abs(meas - 0.12).mean() < 0.02  # against the synthetic truth
    assert all(not m.fallback and m.terrain_class == 4 for m in cruise)
    # steady wheels moving forward: desired = + steady target of class 4 (FakeTable: 0.045)
    steady = [m for m in cruise if m.wheel_state == ["steady"] * 3]
    assert steady and all(m.slip_desired == pytest.approx([0.045] * 3) for m in steady)


def test_camera_silence_gives_unhealthy_and_fallback_within_0p2s(run_with_dropout):
    robot, table = run_with_dropout
    pred = Predictor(robot, FakeTable(), FakeClassifier())
    out = [pred.step(s) for s in iter_table_samples(table)]
    silent = [m for m in out if 8.0 <= m.t_s < 8.5]
    first_bad = next(m for m in silent if not m.estimator_ok)
    assert first_bad.t_s <= 8.0 + 0.2 + 1e-9
    assert all(m.fallback and m.fallback_reason == "estimator_unhealthy"
               for m in silent if m.t_s >= 8.2)
    for m in out:
        assert all(math.isfinite(v) for v in m.slip_desired + m.slip_measured)
    assert all(m.estimator_ok for m in out if 8.6 <= m.t_s)
