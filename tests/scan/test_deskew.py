"""De-skewing a scan taken while the robot moved: exact ground truth in a world of lines.

The scans are ray-cast beam by beam, each from the laser's pose at its own time under the
constant-velocity motion :func:`bsslam.scan.deskew` inverts, so the de-skewed returns must
lie on the walls to rounding, while the skewed ones, read as if taken at one instant, miss
them by millimetres.
"""

import dataclasses
import pickle

import numpy as np
import pytest

from bsslam.dataset import Frame
from bsslam.deskewed_dataset import DeskewedDataset, odometry_velocity
from bsslam.input_limits import InputLimits
from bsslam.mapper import Mapper
from bsslam.scan import LaserScan, deskew
from bsslam.se2 import compose

# a 10 × 6 m room with a pillar: (start, end) of each wall (m)
WALLS = np.array([[[-4, -3], [6, -3]], [[6, -3], [6, 3]], [[6, 3], [-4, 3]], [[-4, 3], [-4, -3]],
                  [[2, 0.5], [3, 1.5]], [[3, 1.5], [2, 2.5]]], dtype=float)
MAX_RANGE = 50.0
LIMITS = InputLimits()


def cast(origin: np.ndarray, bearing: float) -> float:
    """Range from ``origin`` (x, y) along ``bearing`` (rad, world) to the nearest wall."""
    d = np.array([np.cos(bearing), np.sin(bearing)])
    best = np.inf
    for a, b in WALLS:
        e = b - a
        m = np.array([[d[0], -e[0]], [d[1], -e[1]]])
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        t, s = np.linalg.solve(m, a - origin)
        if t > 1e-9 and -1e-12 <= s <= 1 + 1e-12:
            best = min(best, t)
    return best


def skewed_scan(middle, velocity, sweep, offset, n=181, blocked=()):
    """A scan whose beam i is measured at τᵢ = (i/(n−1) − ½)·sweep from the middle of the
    sweep (in order of decreasing bearing when ``sweep`` < 0), the robot at
    middle ∘ (v τ, ω τ); the beams in ``blocked`` see nothing."""
    angles = np.linspace(-np.pi / 2, np.pi / 2, n)
    tau = (np.arange(n) / (n - 1) - 0.5) * sweep
    ranges = np.empty(n)
    for i in range(n):
        robot = compose(middle, np.asarray(velocity) * tau[i])
        laser = compose(robot, offset)
        ranges[i] = np.inf if i in blocked else cast(laser[:2], laser[2] + angles[i])
    return LaserScan(0.0, angles, ranges, MAX_RANGE, sweep)


def wall_distance(points: np.ndarray) -> np.ndarray:
    """(k,) distance of each point (k, 2) to the nearest wall segment (m)."""
    out = np.full(points.shape[0], np.inf)
    for a, b in WALLS:
        e = b - a
        s = np.clip((points - a) @ e / (e @ e), 0.0, 1.0)
        out = np.minimum(out, np.hypot(*(points - (a + s[:, None] * e)).T))
    return out


def world_points(scan: LaserScan, middle, offset) -> np.ndarray:
    laser = compose(middle, offset)
    hit = np.isfinite(scan.ranges)
    bearing = laser[2] + scan.angles[hit]
    return laser[:2] + scan.ranges[hit, None] * np.c_[np.cos(bearing), np.sin(bearing)]


@pytest.mark.parametrize("sweep", [0.05, -0.05])
@pytest.mark.parametrize("offset", [np.zeros(3), np.array([0.3, -0.1, 0.2])])
def test_deskewed_returns_lie_on_the_walls(sweep, offset):
    middle = np.array([0.5, -0.4, 0.3])
    velocity = np.array([1.2, 0.1, 0.8])      # m/s, m/s, rad/s; over 50 ms a few centimetres
    scan = skewed_scan(middle, velocity, sweep, offset)
    as_if_instant = wall_distance(world_points(scan, middle, offset))
    assert as_if_instant.max() > 5e-3          # the skew is there to undo
    fixed = deskew(scan, velocity, offset)
    assert fixed.sweep_time_s == 0.0 and fixed.stamp == scan.stamp and fixed.max_range == scan.max_range
    assert np.all(np.diff(fixed.angles) > 0)
    np.testing.assert_array_less(wall_distance(world_points(fixed, middle, offset)), 1e-9)


def test_no_return_beams_keep_their_range_and_turn_with_the_robot():
    velocity, sweep = np.array([0.5, 0.0, 1.0]), 0.04
    scan = skewed_scan(np.zeros(3), velocity, sweep, np.zeros(3), blocked={0, 90, 180})
    fixed = deskew(scan, velocity, np.zeros(3))
    assert len(fixed) == len(scan)
    np.testing.assert_array_equal(np.isinf(fixed.ranges), np.isinf(scan.ranges))
    tau = np.array([-0.5, 0.0, 0.5]) * sweep
    np.testing.assert_allclose(fixed.angles[[0, 90, 180]], scan.angles[[0, 90, 180]] + velocity[2] * tau, atol=1e-15)


def test_an_instantaneous_scan_or_a_robot_at_rest_is_left_as_it_is():
    scan = skewed_scan(np.zeros(3), np.zeros(3), 0.0, np.zeros(3))
    assert deskew(scan, np.array([1.0, 0.0, 0.5]), np.zeros(3)) is scan
    swept = dataclasses.replace(scan, sweep_time_s=0.02)
    at_rest = deskew(swept, np.zeros(3), np.zeros(3))
    assert at_rest.sweep_time_s == 0.0
    np.testing.assert_array_equal(at_rest.ranges, scan.ranges)
    np.testing.assert_array_equal(at_rest.angles, scan.angles)
    moving = deskew(swept, np.array([1.0, 0.0, 0.5]), np.zeros(3))
    assert deskew(moving, np.array([1.0, 0.0, 0.5]), np.zeros(3)) is moving     # once is enough


def _frames(sweep):
    """Three frames of a robot driving at 1 m/s and turning at 0.5 rad/s, 0.1 s apart."""
    velocity = np.array([1.0, 0.0, 0.5])
    poses = [np.array([-2.0, -1.0, 0.1])]
    for _ in range(2):
        poses.append(compose(poses[-1], velocity * 0.1))
    return [Frame(0.1 * k, pose, dataclasses.replace(skewed_scan(pose, velocity, sweep, np.zeros(3)), stamp=0.1 * k))
            for k, pose in enumerate(poses)], velocity


class _Frames:
    name, ground_truth, skipped = "frames", None, None

    def __init__(self, frames):
        self.frames = frames

    def __iter__(self):
        return iter(self.frames)


def test_the_dataset_takes_the_velocity_from_the_odometry_since_the_previous_frame():
    frames, velocity = _frames(0.05)
    out = list(DeskewedDataset(_Frames(frames)))
    assert out[0].scan.sweep_time_s == 0.0
    np.testing.assert_array_equal(out[0].scan.ranges, frames[0].scan.ranges)     # no velocity yet
    np.testing.assert_allclose(odometry_velocity(frames[0].odometry, 0.0, frames[1].odometry, 0.1, LIMITS), velocity,
                               atol=1e-12)
    for frame, fixed in zip(frames[1:], out[1:]):
        np.testing.assert_array_less(wall_distance(world_points(fixed.scan, frame.odometry, np.zeros(3))), 1e-9)
    assert pickle.loads(pickle.dumps(DeskewedDataset(_Frames(frames)))).name == "frames"   # it can be prefetched


def test_odometry_velocity_is_zero_without_a_previous_pose_or_time_or_a_plausible_step():
    pose = np.array([1.0, 2.0, 0.3])
    np.testing.assert_array_equal(odometry_velocity(None, None, pose, 1.0, LIMITS), np.zeros(3))
    np.testing.assert_array_equal(odometry_velocity(pose, 1.0, compose(pose, [0.1, 0, 0]), 1.0, LIMITS), np.zeros(3))
    np.testing.assert_allclose(odometry_velocity(pose, 1.0, compose(pose, [0.1, 0.0, 0.2]), 1.5, LIMITS), [0.2, 0.0, 0.4],
                               atol=1e-12)
    # 100 m in a second is no robot's velocity: the scan is left skewed, not thrown 30 cm off
    np.testing.assert_array_equal(odometry_velocity(pose, 1.0, compose(pose, [100.0, 0, 0]), 2.0, LIMITS), np.zeros(3))


def test_mapper_add_deskews_as_the_dataset_does():
    frames, _ = _frames(0.05)
    direct, ready = Mapper(), Mapper()
    for frame, fixed in zip(frames, DeskewedDataset(_Frames(frames))):
        a = direct.add(frame.scan, frame.odometry, frame.stamp)
        b = ready.add(fixed.scan, fixed.odometry, fixed.stamp)
        np.testing.assert_array_equal(a.pose, b.pose)
        np.testing.assert_array_equal(a.covariance, b.covariance)
