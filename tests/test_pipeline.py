"""run_dataset with the laser-odometry front end and the filter's update schedule, on a
simulated run with exact ground truth."""

import dataclasses

import numpy as np
import pytest

from bsslam.config import SLAMConfig
from bsslam.eval import ate
from bsslam.frontend import LaserOdometry
from bsslam.pipeline import run_dataset
from bsslam.se2 import between, compose
from bsslam.sim import SimConfig, get_world, simulate


@pytest.fixture(scope="module")
def data():
    return simulate(get_world("mixed"), SimConfig(), seed=5, steps=80)


def frontend_config(**frontend):
    base = SLAMConfig()
    return base.replace(frontend=dataclasses.replace(base.frontend, **frontend))


def test_frontend_run_keeps_one_pose_per_scan_and_beats_odometry(data):
    result = run_dataset(data, frontend_config(update_distance_m=1.0, update_angle_rad=0.5), point_stride=0)
    assert result.steps == 80
    np.testing.assert_array_equal(result.estimate.stamps, [f.stamp for f in data])
    # the filter ran on a subset of the scans; the front end matched all of the others
    assert 1 < result.totals["filter_steps"] < 80
    assert result.totals.get("frontend_matched", 0) + result.totals.get("frontend_fallbacks", 0) == 79
    est, _, _ = ate(result.estimate, data.ground_truth)
    odo, _, _ = ate(result.odometry, data.ground_truth)
    assert est < 0.5 * odo, (est, odo)
    assert np.all(np.linalg.eigvalsh(result.estimate.covariances[1:]) > 0)


def test_scans_between_updates_get_the_filter_pose_moved_by_the_front_end(data):
    """Between two filter steps the reported pose moves exactly by the front end's
    increments, so consecutive reported poses differ by them."""
    result = run_dataset(data, frontend_config(update_distance_m=100.0, update_angle_rad=100.0), point_stride=0)
    assert result.totals["filter_steps"] == 1          # only the first scan reaches the filter
    lo = LaserOdometry(SLAMConfig().frontend)
    pose = None
    for k, frame in enumerate(data):
        step = lo.step(frame)
        pose = np.asarray(frame.odometry, float) if step.increment is None else compose(pose, step.increment)
        np.testing.assert_allclose(result.estimate.poses[k], pose, atol=1e-9)
    # covariance grows monotonically without updates
    traces = np.trace(result.estimate.covariances, axis1=1, axis2=2)
    assert np.all(np.diff(traces) >= -1e-15)


def test_every_scan_is_a_filter_step_without_the_frontend(data):
    base = SLAMConfig()
    result = run_dataset(data, base.replace(frontend=dataclasses.replace(base.frontend, enabled=False)), steps=10,
                         point_stride=0)
    assert result.totals["filter_steps"] == 10 and "frontend_matched" not in result.totals


@pytest.fixture(scope="module")
def two_passes(data):
    """One run with the second pass and one without, same data and configuration."""
    config = frontend_config(update_distance_m=1.0, update_angle_rad=0.5)
    with_pass = run_dataset(data, config, point_stride=0)
    without = run_dataset(data, config.replace(relocalize=False), point_stride=0)
    return with_pass, without


def test_second_pass_leaves_the_online_run_and_the_map_unchanged(two_passes):
    with_pass, without = two_passes
    assert without.relocalized is None and without.trajectory is without.estimate
    np.testing.assert_array_equal(with_pass.estimate.poses, without.estimate.poses)
    assert [m.curve.control_points.tolist() for m in with_pass.map] == [m.curve.control_points.tolist() for m in without.map]
    assert with_pass.trajectory is with_pass.relocalized
    assert with_pass.relocalize_time_s > 0


def test_relocalised_trajectory_agrees_with_the_final_map(two_passes, data):
    """One pose per scan at the scans' stamps; at the last scan both passes see the same
    map from the same place, so they agree within the online filter's own uncertainty;
    over the run the relocalised poses are as accurate as the online ones or better."""
    result, _ = two_passes
    reloc = result.relocalized
    np.testing.assert_array_equal(reloc.stamps, result.estimate.stamps)
    assert np.all(np.linalg.eigvalsh(reloc.covariances[1:]) > 0)
    d = reloc.poses[-1] - result.estimate.poses[-1]
    d[2] = np.angle(np.exp(1j * d[2]))
    P = result.estimate.covariances[-1] + reloc.covariances[-1]
    assert d @ np.linalg.solve(P, d) < 16.27            # χ²(3) at 99.9 %
    online, _, _ = ate(result.estimate, data.ground_truth)
    second, _, _ = ate(reloc, data.ground_truth)
    assert second < 0.05 and second <= online * 1.2, (second, online)


def test_a_filter_in_a_fixed_map_never_changes_it(two_passes, data):
    result, _ = two_passes
    from bsslam.slam import SplineSLAM

    first = next(iter(data))
    slam = SplineSLAM.in_fixed_map(result.map, SLAMConfig(), initial_pose=first.odometry)
    before = [m.curve.control_points.copy() for m in slam.map]
    prev, used = None, 0
    for k, frame in enumerate(data):
        if k == 10:
            break
        delta = None if prev is None else between(prev, frame.odometry)
        report = slam.step(delta, frame.scan, frame.laser_offset)
        prev = frame.odometry
        used += report.beams_used
        assert report.new_splines == report.extended_splines == report.pruned_splines == 0
    assert used > 100                                   # it did localise against the map
    assert slam.state_size == 3
    assert all(np.array_equal(a, m.curve.control_points) for a, m in zip(before, slam.map))
