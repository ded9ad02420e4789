"""Extending a map spline carries the covariance exactly: the old block becomes T P Tᵀ, its
cross-covariances T P, nothing else changes, and the state grows by exactly the new
control points."""

import numpy as np
import pytest

import bsslam.slam.filter as filter_module
from bsslam.config import SLAMConfig
from bsslam.scan import LaserScan, extract_splines
from bsslam.slam import SplineSLAM
from bsslam.spline import closest_point

HEADING = np.pi / 2  # the robot at the origin faces +y


def wall_scan(x_min: float, x_max: float) -> LaserScan:
    """The wall y = 3 between x_min and x_max, seen from the origin facing +y. Beams sweep
    from the robot's right (+x) to its left, so a spline's parameter grows towards −x."""
    angles = np.radians(np.arange(-90.0, 90.0, 1.0))
    mu = angles + HEADING
    sin_mu = np.sin(mu)
    r = np.divide(3.0, sin_mu, out=np.full_like(mu, np.inf), where=sin_mu > 0.05)
    x_hit = r * np.cos(mu)
    ranges = np.where(np.isfinite(r) & (x_hit >= x_min) & (x_hit <= x_max), r, 80.0)
    return LaserScan(0.0, angles, ranges, max_range=80.0)


@pytest.mark.parametrize("side", ["right", "left"])
def test_extension_carries_covariance_exactly(side, monkeypatch):
    config = SLAMConfig(initial_pose_sigma=(0.01, 0.01, 0.01))
    slam = SplineSLAM(config, initial_pose=(0.0, 0.0, HEADING))
    slam.step(None, wall_scan(-1.0, 1.0))
    (feature,) = slam.features.values()
    curve = feature.curve(slam.state.x)
    lo, hi = curve.domain
    # the same wall seen 2 m further on the chosen side: hi is at x = −1, lo at x = +1
    obs = extract_splines(wall_scan(-3.0, 1.0) if side == "right" else wall_scan(-1.0, 3.0), config).splines[0]
    obs_world = obs.curve.transformed(HEADING, np.zeros(2))
    u_end = closest_point(obs_world, curve.evaluate(np.array([hi if side == "right" else lo])))[0][0]
    sel = obs.params > u_end if side == "right" else obs.params < u_end
    assert sel.sum() > 20

    old_idx = feature.state_indices.copy()
    n_old = feature.idx_x.size
    P_before = slam.state.P.copy()
    size_before = slam.state_size
    captured = {}
    original = filter_module.extend_curve

    def spy(*args, **kwargs):
        captured["ext"] = original(*args, **kwargs)
        return captured["ext"]

    monkeypatch.setattr(filter_module, "extend_curve", spy)
    assert slam._extend_feature(feature, obs, side, sel, np.zeros(3))
    ext = captured["ext"]
    assert ext.n_added >= 1

    # exactly the new control points (x and y) were added
    assert slam.state_size == size_before + 2 * ext.n_added
    assert feature.idx_x.size == n_old + ext.n_added
    # the old block is T P Tᵀ, its cross-covariances T P, everything else untouched
    T = np.kron(np.eye(2), ext.T)  # the same T acts on the x and the y coordinates
    P = slam.state.P
    np.testing.assert_allclose(P[np.ix_(old_idx, old_idx)], T @ P_before[np.ix_(old_idx, old_idx)] @ T.T,
                               rtol=1e-12, atol=1e-16)
    others = np.setdiff1d(np.arange(size_before), old_idx)
    np.testing.assert_allclose(P[np.ix_(old_idx, others)], T @ P_before[np.ix_(old_idx, others)],
                               rtol=1e-12, atol=1e-16)
    np.testing.assert_array_equal(P[np.ix_(others, others)], P_before[np.ix_(others, others)])
    # the state holds the extended curve, which still fits the wall y = 3
    cps = feature.control_points(slam.state.x)
    np.testing.assert_allclose(cps, ext.curve.control_points, atol=1e-12)
    lo2, hi2 = ext.curve.domain
    assert np.abs(ext.curve.evaluate(np.linspace(lo2, hi2, 200))[:, 1] - 3.0).max() < 0.01
    assert np.all(np.linalg.eigvalsh(P) > -1e-12)


def test_removing_a_spline_keeps_everything_else():
    config = SLAMConfig(initial_pose_sigma=(0.01, 0.01, 0.01))
    slam = SplineSLAM(config, initial_pose=(0.0, 0.0, HEADING))
    scan = wall_scan(-3.0, 3.0)
    scan.ranges[85:95] = 80.0  # a gap: two splines
    slam.step(None, scan)
    assert len(slam.features) == 2
    gone, kept = slam.map
    kept_idx = slam.features[kept.id].state_indices.copy()
    P_kept = slam.state.P[np.ix_(np.r_[0:3, kept_idx], np.r_[0:3, kept_idx])].copy()
    size = slam.state_size
    slam.remove_feature(gone.id)
    assert slam.state_size == size - 2 * gone.curve.n_control
    (after,) = slam.map
    np.testing.assert_array_equal(after.curve.control_points, kept.curve.control_points)
    idx = slam.features[kept.id].state_indices
    np.testing.assert_array_equal(slam.state.P[np.ix_(np.r_[0:3, idx], np.r_[0:3, idx])], P_kept)
