"""The laser/odometry simulator: exact ground truth, noise with the configured σ,
determinism, and the Dataset protocol."""

import math

import numpy as np
import pytest

from bsslam.config import MotionNoiseConfig
from bsslam.dataset import Frame
from bsslam.errors import ConfigError
from bsslam.scan.laser_scan import LaserScan
from bsslam.sim.simulator import (
    SimConfig,
    compose_increments,
    relative_increments,
    simulate,
)
from bsslam.sim.worlds import get_world
from bsslam.slam.motion import motion_sigmas

ROOM = get_world("rounded-room")


def test_default_laser_is_the_papers():
    cfg = SimConfig()
    angles = cfg.beam_angles()
    assert angles.shape == (181,)
    assert angles[0] == pytest.approx(-math.pi / 2) and angles[-1] == pytest.approx(math.pi / 2)
    assert cfg.max_range_m == 8.0 and cfg.sigma_range_m == 0.005
    full = SimConfig(fov_rad=2 * math.pi, resolution_rad=math.radians(2.0)).beam_angles()
    assert full.shape == (180,)  # no duplicate beam at +π


def test_invalid_settings_are_refused():
    for bad in ({"fov_rad": 0.0}, {"resolution_rad": -1.0}, {"max_range_m": 0.0}, {"sigma_range_m": -0.1}):
        with pytest.raises(ConfigError):
            SimConfig(**bad)
    with pytest.raises(ConfigError):
        simulate(ROOM, SimConfig(), seed=0, steps=0)


def test_frames_follow_the_dataset_protocol():
    data = simulate(ROOM, SimConfig(), seed=4, steps=30)
    frames = list(data)
    assert len(frames) == len(data) == 30
    assert data.ground_truth.poses.shape == (30, 3) and data.skipped.total == 0
    assert data.name.startswith("sim:rounded-room")
    assert all(isinstance(f, Frame) and isinstance(f.scan, LaserScan) for f in frames)
    assert np.all(np.diff([f.stamp for f in frames]) > 0)
    assert frames[0].scan.ranges.shape == (181,) and frames[0].scan.max_range == 8.0
    np.testing.assert_array_equal(frames[7].odometry, data.odometry_poses[7])
    np.testing.assert_array_equal(frames[0].odometry, data.ground_truth.poses[0])


def test_first_frame_has_zero_increment_and_odometry_integrates_the_noisy_increments():
    data = simulate(ROOM, SimConfig(), seed=5)
    assert np.all(data.true_increments[0] == 0) and np.all(data.odometry_increments[0] == 0)
    # Re-deriving the increments from the odometry poses gives back what was reported.
    np.testing.assert_allclose(relative_increments(data.odometry_poses), data.odometry_increments, atol=1e-9)
    # And the true increments rebuild the exact ground truth.
    gt = data.ground_truth.poses
    rebuilt = compose_increments(gt[0], data.true_increments[1:])
    np.testing.assert_allclose(rebuilt[:, :2], gt[1:, :2], atol=1e-9)
    np.testing.assert_allclose(np.cos(rebuilt[:, 2] - gt[1:, 2]), 1.0, atol=1e-12)


def test_true_increments_are_a_step_forward_in_the_robot_frame():
    data = simulate(ROOM, SimConfig(step_m=0.25), seed=0, steps=50)
    inc = data.true_increments[1:]
    np.testing.assert_allclose(np.hypot(inc[:, 0], inc[:, 1]), 0.25, rtol=0.05)
    assert np.all(inc[:, 0] > 0.2)


def test_odometry_noise_has_the_configured_sigma():
    motion = MotionNoiseConfig(a_xy_m=0.002, b_xy=0.05, a_phi_rad=0.01, b_phi=0.1)
    cfg = SimConfig(motion=motion)
    residuals = []
    for seed in range(8):
        data = simulate(ROOM, cfg, seed=seed)
        sigma = motion_sigmas(data.true_increments[1:], motion)
        residuals.append((data.odometry_increments[1:] - data.true_increments[1:]) / sigma)
    z = np.vstack(residuals)  # standard normal if σ is right
    n = z.shape[0]
    assert n > 2000
    np.testing.assert_array_less(np.abs(z.mean(axis=0)), 5 / math.sqrt(n))
    np.testing.assert_array_less(np.abs(z.std(axis=0) - 1.0), 5 / math.sqrt(2 * n))


def test_the_simulated_odometry_noise_is_the_papers_model():
    motion = MotionNoiseConfig(a_xy_m=0.001, b_xy=0.1, a_phi_rad=0.02, b_phi=0.1, b_phi_per_m_rad=0.5)
    sigma = motion_sigmas(np.array([[0.3, -0.4, -0.2]]), motion)
    np.testing.assert_allclose(sigma, [[0.031, 0.041, 0.02 + 0.02 + 0.25]])


def test_ranges_are_exact_geometry_plus_noise_of_the_configured_sigma():
    cfg = SimConfig(sigma_range_m=0.01)
    data = simulate(ROOM, cfg, seed=11, steps=60)
    gt = data.ground_truth.poses
    exact = np.vstack([ROOM.ray_cast(p[:2], p[2] + data.beam_angles, cfg.max_range_m) for p in gt])
    hit = np.isfinite(exact)
    z = (data.ranges[hit] - exact[hit]) / cfg.sigma_range_m
    assert abs(z.mean()) < 5 / math.sqrt(z.size)
    assert abs(z.std() - 1.0) < 5 / math.sqrt(2 * z.size)
    assert np.all(data.ranges[~hit] == cfg.max_range_m)


def test_beams_without_a_wall_in_range_report_max_range():
    cfg = SimConfig(max_range_m=2.0, sigma_range_m=0.0)
    data = simulate(get_world("corridor-loop"), cfg, seed=0, steps=20)
    no_return = data.ranges == 2.0
    assert no_return.any() and (~no_return).any()
    assert np.all(data.ranges[~no_return] < 2.0)


def test_static_sensor_sees_the_curved_wall_exactly_without_noise():
    data = simulate(get_world("curved-wall"), SimConfig(sigma_range_m=0.0), seed=0, steps=3)
    phi = data.ground_truth.poses[0, 2] + data.beam_angles
    np.testing.assert_allclose(data.ranges[2], 5.0 + 0.5 * np.sin(5.0 * phi), atol=1e-9)
    assert len(data) == 3 and np.all(data.true_increments == 0)


def test_same_seed_same_run_and_shorter_runs_are_prefixes():
    a = simulate(ROOM, SimConfig(), seed=21)
    b = simulate(ROOM, SimConfig(), seed=21)
    c = simulate(ROOM, SimConfig(), seed=22)
    short = simulate(ROOM, SimConfig(), seed=21, steps=40)
    np.testing.assert_array_equal(a.ranges, b.ranges)
    np.testing.assert_array_equal(a.odometry_poses, b.odometry_poses)
    assert not np.array_equal(a.odometry_increments, c.odometry_increments)
    assert not np.array_equal(a.ranges, c.ranges)
    np.testing.assert_array_equal(short.ranges, a.ranges[:40])
    np.testing.assert_array_equal(short.odometry_poses, a.odometry_poses[:40])


def test_full_run_is_the_double_loop_and_ends_at_the_start():
    data = simulate(ROOM, SimConfig(), seed=1)
    gt = data.ground_truth.poses
    assert len(data) == 2 * round(ROOM.path.length_m / 0.25) + 1
    np.testing.assert_allclose(gt[-1], gt[0], atol=1e-9)
    # Odometry drifts: with the paper's σ the dead-reckoned end is not the start.
    assert np.linalg.norm(data.odometry_poses[-1, :2] - gt[-1, :2]) > 1e-3


def test_simulator_and_filter_share_one_motion_model():
    """The simulator's vectorised increments agree with the filter's per-pose motion
    model (the noise is the filter's own ``motion_sigmas``), so a filter fed these odometry
    poses sees exactly the configured noise."""
    from bsslam.se2 import between as relative, compose

    motion = MotionNoiseConfig(b_phi_per_m_rad=0.05)
    data = simulate(ROOM, SimConfig(motion=motion), seed=3, steps=80)
    odo = data.odometry_poses
    for k in (1, 17, 55, 79):
        np.testing.assert_allclose(relative(odo[k - 1], odo[k]), data.odometry_increments[k], atol=1e-12)
        np.testing.assert_allclose(compose(odo[k - 1], data.odometry_increments[k]), odo[k], atol=1e-12)
