"""run_dataset with the laser-odometry front end and the filter's update schedule, on a
simulated run with exact ground truth."""

import dataclasses

import numpy as np
import pytest

from bsslam.config import SLAMConfig
from bsslam.eval import ate
from bsslam.frontend import LaserOdometry
from bsslam.pipeline import run_dataset
from bsslam.se2 import compose
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
