"""The one place where headings become quaternions and back, against scipy's Rotation."""

import numpy as np
from scipy.spatial.transform import Rotation

from bsslam.io.quaternion import quaternion_from_yaw, yaw_from_quaternion


def test_yaw_of_any_quaternion_is_scipys_zyx_yaw():
    rng = np.random.default_rng(3)
    q = rng.normal(size=(200, 4)) * rng.uniform(0.2, 5.0, size=(200, 1))  # not unit, not planar
    expected = Rotation.from_quat(q).as_euler("ZYX")[:, 0]
    np.testing.assert_allclose(yaw_from_quaternion(*q.T), expected, atol=1e-12)


def test_quaternion_of_a_yaw_is_scipys_rotation_about_z_and_reads_back():
    yaw = np.linspace(-np.pi + 1e-9, np.pi, 101)
    q = quaternion_from_yaw(yaw)
    expected = Rotation.from_euler("z", yaw[:, None]).as_quat()  # (x, y, z, w), w ≥ 0
    np.testing.assert_allclose(q * np.sign(q[:, 3:]), expected, atol=1e-15)
    np.testing.assert_allclose(yaw_from_quaternion(*q.T), yaw, atol=1e-15)
