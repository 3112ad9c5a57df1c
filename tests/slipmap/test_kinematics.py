"""Paper eq. 5-8 on hand-worked numbers."""

import numpy as np

from terrainml.slipmap.exponential import ExponentialSlipModel
from terrainml.slipmap.kinematics import (compensate_wheel_speed_radps, lateral_slip_angle_rad,
                                          longitudinal_slippage_mps, side_geometry)
from terrainml.robot import load_robot


def test_slippage_equations_hand_worked():
    # R = 0.1 m, B = 0.6 m; encoders 5 and 7 rad/s -> 0.5 and 0.7 m/s;
    # body vx 0.55 m/s, yaw rate 0.3 rad/s -> expected tracks 0.46 and 0.64 m/s
    bl, br = longitudinal_slippage_mps(5.0, 7.0, 0.55, 0.3, 0.1, 0.6)
    assert np.isclose(bl, 0.04) and np.isclose(br, 0.06)
    assert np.isclose(lateral_slip_angle_rad(1.0, -1.0), -np.pi / 4)
    assert np.isclose(compensate_wheel_speed_radps(5.0, 0.04, 0.1), 5.4)


def test_side_geometry_of_husky():
    left, right, track = side_geometry(load_robot("husky"))
    assert left == [1, 3] and right == [2, 4] and np.isclose(track, 0.5708)


def test_exponential_identifies_its_own_form():
    r = np.r_[np.geomspace(0.5, 10, 30), -np.geomspace(0.5, 10, 30)]
    v = np.full_like(r, 0.5)
    w = v / r
    true = ExponentialSlipModel(-0.1, -0.4, 0.08, -0.3, -0.05, -0.6)
    bl, br, al = true.predict(v, w)
    fit = ExponentialSlipModel.identify(v, w, bl, br, al)
    np.testing.assert_allclose(list(fit.to_dict().values()), list(true.to_dict().values()), rtol=1e-4)
