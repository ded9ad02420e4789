"""Which scans the filter processes: one after every ``distance`` metres or ``angle`` radians
of motion, as GMapping and Karto do, with the front end's increments in between compounded.

A robot that stands still or creeps along a corridor adds scans that tell the filter almost
nothing new yet cost it a full O(n²) update each; the front end has already registered them.
Between updates the pose is the filter's last pose composed with the compounded increment,
and its covariance grows by first-order propagation.

The motion that decides is the wheels' (the odometry increments compounded alongside), not
the scan matches': a decision on a threshold flips wherever the motion lands within noise
of it, and the matches move with every millimetre of range noise (on Edmonton, where a scan
comes every 0.7 m, one decision in ten lies within 1 cm of a threshold, and runs 1 mm of
range noise apart chose 30–44 different scans of about 230, from the 5th–13th scan on). The
odometry is the same however the ranges are perturbed, so which scans the filter sees is too.
"""

from __future__ import annotations

import numpy as np

from bsslam.se2 import compose, compose_with_covariance


class UpdateSchedule:
    """Compounds front-end increments until the robot has moved enough for a filter update.

    Args:
        distance_m: update once the compounded translation reaches this (m); 0 with
            ``angle_rad`` 0 updates on every scan.
        angle_rad: ... or once the compounded rotation reaches this (rad).
    """

    def __init__(self, distance_m: float, angle_rad: float) -> None:
        self.distance_m = float(distance_m)
        self.angle_rad = float(angle_rad)
        self.increment = np.zeros(3)
        self.covariance = np.zeros((3, 3))
        self.odometry = np.zeros(3)      # the wheels' increment over the same scans: it decides

    def add(self, increment: np.ndarray, covariance: np.ndarray, odometry: np.ndarray | None = None) -> bool:
        """Compound one robot-frame increment (3,) with its covariance (3, 3), and the
        odometry's increment (3,) over the same scan (``None``: ``increment`` itself);
        returns True when the odometry compounded since the last :meth:`take` has moved
        ``distance_m`` or turned ``angle_rad``, i.e. when the filter should now run."""
        increment = np.asarray(increment, dtype=float)
        self.increment, self.covariance = compose_with_covariance(
            self.increment, self.covariance, increment, np.asarray(covariance, dtype=float))
        self.odometry = compose(self.odometry, increment if odometry is None else np.asarray(odometry, dtype=float))
        moved = float(np.hypot(self.odometry[0], self.odometry[1]))
        return moved >= self.distance_m or abs(float(self.odometry[2])) >= self.angle_rad

    def take(self) -> tuple[np.ndarray, np.ndarray]:
        """The compounded increment (3,) and covariance (3, 3) since the last take; resets."""
        out = self.increment, self.covariance
        self.increment, self.covariance, self.odometry = np.zeros(3), np.zeros((3, 3)), np.zeros(3)
        return out

    def pose_between_updates(self, pose: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The current pose (3,) and covariance (3, 3) from the filter's last pose and the
        increments compounded since (the front end's registration of the skipped scans)."""
        return compose_with_covariance(pose, covariance, self.increment, self.covariance)
