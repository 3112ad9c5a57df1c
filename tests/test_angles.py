"""One angle convention, (-pi, pi] (design §4): the numpy function and the EKF kernel's compiled twin."""

import math

import numpy as np
import pytest

from terrainml.angles import wrap_angle
from terrainml.estimation._kernel import wrap_scalar


@pytest.mark.parametrize("a, want", [(0.0, 0.0), (math.pi, math.pi), (-math.pi, math.pi),
                                     (3 * math.pi / 2, -math.pi / 2), (-3 * math.pi / 2, math.pi / 2),
                                     (7 * math.pi, math.pi), (2 * math.pi + 0.25, 0.25)])
def test_hand_worked_angles(a, want):
    assert wrap_angle(a) == pytest.approx(want, abs=1e-12)
    assert wrap_scalar(a) == pytest.approx(want, abs=1e-12)


def test_numpy_and_compiled_wraps_agree_bit_for_bit():
    a = np.random.default_rng(0).uniform(-50.0, 50.0, 2000)
    a[:4] = (math.pi, -math.pi, 3 * math.pi, -3 * math.pi)
    got = wrap_angle(a)
    assert got.shape == a.shape and np.all(got > -math.pi) and np.all(got <= math.pi)
    np.testing.assert_array_equal(got, [wrap_scalar(float(x)) for x in a])
    np.testing.assert_allclose(np.cos(got), np.cos(a), atol=1e-12)
    np.testing.assert_allclose(np.sin(got), np.sin(a), atol=1e-12)
