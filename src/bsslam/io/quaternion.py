"""Planar headings to and from unit quaternions (x, y, z, w), as TUM files and ROS use."""

from __future__ import annotations

import numpy as np


def yaw_from_quaternion(qx, qy, qz, qw):
    """Heading (rad, in (−π, π]) of quaternion(s): the rotation about z, i.e. the ZYX yaw.
    Valid for any, also non-planar or unnormalised, quaternion. Accepts scalars or arrays."""
    return np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def quaternion_from_yaw(yaw) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w) of rotations by ``yaw`` (rad) about z."""
    half = 0.5 * np.asarray(yaw, dtype=float)
    zeros = np.zeros_like(half)
    return np.stack([zeros, zeros, np.sin(half), np.cos(half)], axis=-1)
