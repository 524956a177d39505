"""headplod.angles.angle_between_deg: the one angle between directions, against closed forms."""
import math

import numpy as np
import pytest

from headplod.angles import angle_between_deg


@pytest.mark.parametrize("deg", [1e-7, 1e-3, 0.5, 10.0, 90.0, 135.0, 179.999])
def test_the_angle_of_a_rotated_vector_is_its_rotation(deg):
    a = math.radians(deg)
    u = np.array([3.0, 0.0, 0.0])                               # not unit: the length does not matter
    v = 0.25 * np.array([math.cos(a), math.sin(a), 0.0])
    assert float(angle_between_deg(u, v)) == pytest.approx(deg, rel=1e-9)


def test_small_angles_keep_their_digits_where_acos_loses_them():
    a = math.radians(1e-7)
    u, v = np.array([0.0, 0.0, 1.0]), np.array([math.sin(a), 0.0, math.cos(a)])
    assert float(angle_between_deg(u, v)) == pytest.approx(1e-7, rel=1e-6)
    assert math.degrees(math.acos(min(1.0, float(u @ v)))) == 0.0        # why not acos: it gives nothing here


def test_broadcasts_along_the_last_axis_and_a_zero_vector_gives_zero():
    u = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    got = angle_between_deg(u, np.array([1.0, 0.0, 0.0]))
    assert got.shape == (4,)
    np.testing.assert_allclose(got, [0.0, 90.0, 180.0, 0.0], atol=1e-12)
