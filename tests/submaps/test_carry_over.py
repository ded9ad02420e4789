"""carry_over: the walls near the robot enter a new submap in the robot's frame with their
covariance relative to the robot, as control points the estimator can pair (x's, then y's)."""

import numpy as np
import pytest

from bsslam.config import SLAMConfig
from bsslam.experiments.consistency import simulation_config
from bsslam.se2 import between
from bsslam.sim import SimConfig, get_world, simulate
from bsslam.slam import SplineSLAM
from bsslam.submaps.backend import carry_over


def previous_filter() -> SplineSLAM:
    sim = SimConfig()
    frames = list(simulate(get_world("rounded-room"), sim, seed=5, steps=12))
    slam = SplineSLAM(simulation_config(SLAMConfig(), sim), initial_pose=frames[0].odometry)
    prev = frames[0].odometry
    for frame in frames:
        slam.step(between(prev, frame.odometry), frame.scan)
        prev = frame.odometry
    return slam


def relative(previous: SplineSLAM, idx_x: np.ndarray, idx_y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A spline's control points in the robot's frame (n, 2) and their covariance (2n, 2n),
    [x's; y's], from the pose and the points by finite differences of p′ = R(φ)ᵀ (p − t)."""
    idx = np.concatenate([np.arange(3), idx_x, idx_y])
    z0 = previous.state.x[idx]
    n = idx_x.shape[0]

    def f(z):
        c, s = np.cos(z[2]), np.sin(z[2])
        dx, dy = z[3:3 + n] - z[0], z[3 + n:] - z[1]
        return np.concatenate([c * dx + s * dy, -s * dx + c * dy])

    J = np.column_stack([(f(z0 + h) - f(z0 - h)) / 2e-6 for h in np.eye(idx.shape[0]) * 1e-6])
    return f(z0), J @ previous.state.block(idx, idx) @ J.T


@pytest.mark.parametrize("estimator", ["ekf", "invariant"])
def test_carried_splines_are_the_old_ones_relative_to_the_robot(estimator):
    previous = previous_filter()
    local = SplineSLAM(SLAMConfig(estimator=estimator))
    copied = carry_over(previous, local, radius_m=50.0, max_state=10_000)
    assert copied == sum(f.in_state for f in previous.features.values()) >= 3
    old = [f for f in previous.features.values() if f.in_state]
    for g in local.features.values():
        values = local.state.x[np.concatenate([g.idx_x, g.idx_y])]
        matches = [f for f in old if f.idx_x.shape == g.idx_x.shape and np.array_equal(f.knots, g.knots)
                   and np.allclose(relative(previous, f.idx_x, f.idx_y)[0], values, atol=1e-9)]
        assert len(matches) == 1
        _, cov = relative(previous, matches[0].idx_x, matches[0].idx_y)
        idx = np.concatenate([g.idx_x, g.idx_y])
        np.testing.assert_allclose(local.state.block(idx, idx), cov, atol=1e-9 * np.abs(cov).max())
        if estimator == "invariant":   # each x is paired with its own y: J p = (−p_y, p_x)
            x = local.state.x
            np.testing.assert_array_equal(local.state.turn(x, g.idx_x), -x[g.idx_y])
            np.testing.assert_array_equal(local.state.turn(x, g.idx_y), x[g.idx_x])
