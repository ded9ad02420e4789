"""Planar headings to and from unit quaternions (x, y, z, w), as TUM files and ROS use."""

from __future__ import annotations

import numpy as np


def yaw_from_quaternion(qx, qy, qz, qw):
    """Heading (rad, in (−π, π]) of quaternion(s): the rotation about z, i.e. the ZYX yaw.
    Valid for any, also non-planar or unnormalised, quaternion. Accepts scalars or arrays."""
    # w² + x² − y² − z² is 1 − 2(y² + z²) for a unit quaternion; unlike the latter it scales
    # with |q|² as the numerator does, so the angle does not depend on the norm.
    return np.arctan2(2.0 * (qw * qz + qx * qy), qw * qw + qx * qx - qy * qy - qz * qz)


def quaternion_from_yaw(yaw) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w) of rotations by ``yaw`` (rad) about z."""
    half = 0.5 * np.asarray(yaw, dtype=float)
    zeros = np.zeros_like(half)
    return np.stack([zeros, zeros, np.sin(half), np.cos(half)], axis=-1)
