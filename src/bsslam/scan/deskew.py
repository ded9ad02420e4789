"""Undo the robot's motion during one laser sweep.

A scanning laser measures its beams one after another: a SICK LMS sweeps its 180° in
about 6.7 ms, a ROS driver says so in ``LaserScan.time_increment``. A robot that moves
meanwhile measures each beam from a slightly different pose, and treating the scan as
taken from one pose skews it. The skew is small (a few millimetres at 0.5 m/s) but always
the same way for a robot driving forward, so scan matching turns it into a heading drift
per metre travelled (docs/real_logs.md, "Where the seams' error comes from, scans skewed
by the robot's motion").
"""

from __future__ import annotations

import dataclasses

import numpy as np

from bsslam.scan.laser_scan import LaserScan
from bsslam.scan.segment import beam_points
from bsslam.se2 import between, compose
from bsslam.trajectory import wrap_angle


def deskew(scan: LaserScan, velocity: np.ndarray, laser_offset: np.ndarray) -> LaserScan:
    """``scan`` as if every beam had been measured at the middle of its sweep.

    The beams are taken evenly over ``scan.sweep_time_s`` (s), in order of increasing bearing
    (of decreasing bearing when it is negative); beam i of n at
    τᵢ = (i / (n − 1) − ½) · ``sweep_time_s`` from the middle. Over τ the robot moves
    by (vx τ, vy τ, ω τ) in its own frame (constant velocity; the sweep is milliseconds
    long). Each return is carried from the laser frame at τᵢ to the laser frame at the
    middle; a beam without a return (range ≥ ``max_range``, inf or NaN) keeps its range and
    turns with the robot. Bearings that come out out of order (a near return moved past
    its neighbour) are sorted.

    Args:
        scan: the scan as measured; its bearings in the laser frame (rad), increasing.
        velocity: (3,) the robot's velocity in its own frame at the scan (vx, vy m/s; ω rad/s).
        laser_offset: (3,) the laser's pose in the robot frame (x m, y m, φ rad).

    Returns:
        A :class:`LaserScan` with the same stamp, beam count and ``max_range`` and a sweep
        time of 0 (so that a second call changes nothing); ``scan`` itself when its sweep
        time is 0.
    """
    n = scan.angles.shape[0]
    v = np.asarray(velocity, dtype=float)
    if scan.sweep_time_s == 0.0:
        return scan
    if n < 2 or not np.any(v):
        return dataclasses.replace(scan, sweep_time_s=0.0)
    tau = (np.arange(n) / (n - 1) - 0.5) * scan.sweep_time_s
    ranges = scan.ranges
    hit = np.isfinite(ranges) & (ranges > 0) & (ranges < scan.max_range)
    offset = np.asarray(laser_offset, dtype=float)
    # each return as a pose (heading 0) in the laser frame at τ, carried to the robot frame
    # at τ, to the robot frame at the middle of the sweep, and to the laser frame there
    returns = np.zeros((n, 3))
    returns[:, :2] = beam_points(scan.angles, np.where(hit, ranges, 0.0))
    at_middle = between(offset, compose(v * tau[:, None], compose(offset, returns)))
    # a return's bearing moves by less than the turn plus a few milliradians: stay in the
    # scan's own convention of angles (it may run past ±π); a beam without one turns
    moved = wrap_angle(np.arctan2(at_middle[:, 1], at_middle[:, 0]) - scan.angles)
    angles = scan.angles + np.where(hit, moved, v[2] * tau)
    new_ranges = np.where(hit, np.hypot(at_middle[:, 0], at_middle[:, 1]), ranges)
    if np.any(np.diff(angles) <= 0):
        order = np.argsort(angles, kind="stable")
        angles, new_ranges = angles[order], new_ranges[order]
    return dataclasses.replace(scan, angles=angles, ranges=new_ranges, sweep_time_s=0.0)
