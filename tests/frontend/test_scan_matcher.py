"""The scan matcher on synthetic scans: recovery from a poor guess, covariance
consistency, degenerate and empty input."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.stats import chi2

from bsslam.errors import ConfigError
from bsslam.frontend import FrontendConfig, ReferenceMap, match_scan, scan_points
from bsslam.frontend.scan_matcher import (LikelihoodField, _distinct_maxima, _kdtree, _offset_axis, _offset_grid,
                                          _search_grid, transform_points, weak_prior_share)
from bsslam.scan.laser_scan import LaserScan
from bsslam.se2 import between
from bsslam.sim import Arc, Segment, SimConfig, WallSet, get_world, simulate

from .cases import ANGLES, cast_scan, corridor, perturbation, pose_error, room

CFG = FrontendConfig()


def _room_pair(rng, motion=(0.4, 0.15, math.radians(12.0)), sigma=0.005):
    walls = room()
    a = np.array([-1.0, -0.5, 0.3])
    b = np.array([a[0] + motion[0], a[1] + motion[1], a[2] + motion[2]])
    ref = scan_points(cast_scan(walls, a, rng, sigma), None, CFG)
    cur = scan_points(cast_scan(walls, b, rng, sigma), None, CFG)
    return ref, cur, between(a, b)


@pytest.mark.parametrize("seed", range(5))
def test_recovers_transform_from_a_poor_guess_in_a_room(seed):
    rng = np.random.default_rng(seed)
    ref, cur, true = _room_pair(rng)
    result = match_scan(ref, cur, true + perturbation(rng, 0.3, 20.0))
    assert result.ok and result.reason == "ok" and not result.degenerate
    err = pose_error(result.pose, true)
    assert np.hypot(err[0], err[1]) < 0.005
    assert abs(err[2]) < 0.003
    assert result.score > 0.8


def test_recovers_simulated_motion_from_a_poor_guess():
    data = simulate(get_world("mixed"), SimConfig(), seed=1, steps=30)
    frames, gt = list(data), data.ground_truth.poses
    rng = np.random.default_rng(7)
    for k in range(0, 29, 4):
        ref = ReferenceMap(scan_points(frames[k].scan, frames[k].laser_offset, CFG))
        true = between(gt[k], gt[k + 1])
        result = ref.match(scan_points(frames[k + 1].scan, frames[k + 1].laser_offset, CFG),
                           true + perturbation(rng, 0.3, 20.0))
        err = pose_error(result.pose, true)
        assert result.ok
        assert np.hypot(err[0], err[1]) < 0.01 and abs(err[2]) < 0.004, (k, err)


def test_laser_offset_is_applied():
    offset = np.array([0.2, -0.1, 0.1])
    scan = LaserScan(0.0, np.array([0.0, 0.5]), np.array([1.0, 2.0]), 30.0)
    pts = scan_points(scan, offset, CFG)
    expected = transform_points(offset, np.array([[1.0, 0.0], [2 * math.cos(0.5), 2 * math.sin(0.5)]]))
    np.testing.assert_allclose(pts, expected, atol=1e-12)


def _nees_samples(config, sigma, seeds=range(4), per_seed=10):
    nees = []
    for seed in seeds:
        data = simulate(get_world("mixed"), SimConfig(sigma_range_m=sigma), seed=seed, steps=per_seed + 1)
        frames, gt = list(data), data.ground_truth.poses
        rng = np.random.default_rng(100 + seed)
        for k in range(per_seed):
            true = between(gt[k], gt[k + 1])
            result = ReferenceMap(scan_points(frames[k].scan, None, config), config).match(
                scan_points(frames[k + 1].scan, None, config), true + perturbation(rng, 0.2, 10.0))
            assert result.ok
            e = pose_error(result.pose, true)
            nees.append(e @ np.linalg.solve(result.covariance, e))
    return np.array(nees)


def test_gauss_newton_covariance_is_consistent_without_inflation():
    """With independent range noise, no inflation and no floors, the NEES of the matches
    over seeds lies in the two-sided 99.9 % χ² band of its mean (3 dof each)."""
    config = FrontendConfig(covariance_inflation=1.0, range_sigma_m=0.001, min_sigma_xy_m=0.0, min_sigma_rad=0.0)
    nees = _nees_samples(config, sigma=0.01)
    n = nees.shape[0]
    lo, hi = chi2.ppf([0.0005, 0.9995], 3 * n) / n
    assert lo < nees.mean() < hi, nees.mean()


def test_default_covariance_is_not_overconfident():
    """The default (inflated for real scans) covariance bounds the simulated errors."""
    nees = _nees_samples(CFG, sigma=0.01, seeds=range(2))
    assert nees.mean() < chi2.ppf(0.999, 3 * nees.shape[0]) / nees.shape[0]
    assert np.all(nees < chi2.ppf(0.999, 3))


def _corridor_pair():
    """Reference and current scans (robot frame) down the long corridor, the pose of the
    reference's (along world x), and the true relative pose."""
    rng = np.random.default_rng(3)
    walls = corridor()
    a, b = np.array([0.0, 0.1, 0.05]), np.array([0.5, 0.0, 0.15])
    ref = scan_points(cast_scan(walls, a, rng, 0.005, max_range=8.0), None, CFG)
    cur = scan_points(cast_scan(walls, b, rng, 0.005, max_range=8.0), None, CFG)
    return ref, cur, a, between(a, b)


def test_corridor_is_flagged_degenerate_and_keeps_the_guess_along_it():
    ref, cur, a, true = _corridor_pair()
    guess = true + np.array([0.2, 0.1, math.radians(5.0)])
    prior = np.diag([0.1 ** 2, 0.1 ** 2, math.radians(5.0) ** 2])
    result = ReferenceMap(ref).match(cur, guess, prior)
    assert result.ok and result.degenerate
    # Across the corridor and in rotation the scan decides …
    c, s = math.cos(a[2]), math.sin(a[2])
    across = np.array([s, c])            # world y (across the corridor) in the frame of pose a
    along = np.array([c, -s])            # world x (along it)
    err = pose_error(result.pose, true)
    assert abs(err[:2] @ across) < 0.01 and abs(err[2]) < 0.005
    # … along it the prior (guess) does, and the covariance says it is unknown there.
    assert abs((result.pose[:2] - guess[:2]) @ along) < 0.02
    sigma_along = math.sqrt(along @ result.covariance[:2, :2] @ along)
    sigma_across = math.sqrt(across @ result.covariance[:2, :2] @ across)
    assert sigma_along > 0.05 and sigma_along > 5 * sigma_across


def test_a_weak_prior_decides_a_corridor_along_itself_and_nothing_else():
    """A degenerate match is refined again with the weak prior: along the corridor its
    covariance is then the weak prior's (the scan adds nothing there) while across it and
    in rotation the scan still decides, as with the wide prior alone."""
    ref, cur, a, true = _corridor_pair()
    guess = true + np.array([0.02, 0.02, math.radians(1.0)])     # within the weak prior's σ
    wide = np.diag([0.25 ** 2, 0.25 ** 2, math.radians(5.0) ** 2])
    weak = np.diag([0.03 ** 2, 0.03 ** 2, math.radians(5.0) ** 2])
    reference = ReferenceMap(ref)
    alone, helped = reference.match(cur, guess, wide), reference.match(cur, guess, wide, weak)
    assert alone.degenerate and helped.degenerate
    assert alone.weak_prior_weight == 0.0 and helped.weak_prior_weight == 1.0
    c, s = math.cos(a[2]), math.sin(a[2])
    across, along = np.array([s, c]), np.array([c, -s])
    floor = CFG.min_sigma_xy_m ** 2
    assert along @ helped.covariance[:2, :2] @ along == pytest.approx(0.03 ** 2 + floor, rel=0.05)
    assert 0.5 * 0.25 ** 2 < along @ alone.covariance[:2, :2] @ along <= 0.25 ** 2 + floor
    # across the corridor and in rotation the scan decides alike (the corridor test above),
    # within a σ of the match alone
    change = pose_error(helped.pose, alone.pose)
    assert abs(change[:2] @ across) < math.sqrt(across @ alone.covariance[:2, :2] @ across)
    assert abs(change[2]) < math.sqrt(alone.covariance[2, 2])
    assert abs((helped.pose[:2] - guess[:2]) @ along) < 0.005


@pytest.mark.parametrize("seed", range(3))
def test_a_weak_prior_leaves_a_well_constrained_match_alone(seed):
    rng = np.random.default_rng(seed)
    ref, cur, true = _room_pair(rng)
    guess = true + perturbation(rng, 0.2, 10.0)
    wide = np.diag([0.25 ** 2, 0.25 ** 2, math.radians(10.0) ** 2])
    reference = ReferenceMap(ref)
    alone = reference.match(cur, guess, wide)
    helped = reference.match(cur, guess, wide, np.diag([0.01 ** 2, 0.01 ** 2, math.radians(10.0) ** 2]))
    assert helped.weak_prior_weight == 0.0 and not helped.degenerate
    assert helped.weakness == alone.weakness >= 2 * CFG.degenerate_ratio   # the scan's, with or without the offer
    np.testing.assert_array_equal(helped.pose, alone.pose)
    np.testing.assert_array_equal(helped.covariance, alone.covariance)


def test_the_weak_prior_s_share_falls_continuously_with_the_constraint():
    """1 up to ``degenerate_ratio``, 0 from twice it, linear in the log of the ratio
    between: no ratio where an ulp flips the prior."""
    limit = CFG.degenerate_ratio

    def share(ratio):
        return weak_prior_share(ReferenceMap._weakness(np.diag([1.0, ratio, 1.0])), limit)

    assert share(0.0) == 1.0 and share(limit) == 1.0 and share(2 * limit) == 0.0 and share(0.5) == 0.0
    assert share(limit * math.sqrt(2.0)) == pytest.approx(0.5)
    ratios = np.linspace(0.5 * limit, 2.5 * limit, 2001)
    shares = np.array([share(r) for r in ratios])
    assert np.all(np.diff(shares) <= 0) and np.max(np.abs(np.diff(shares))) < 2e-3


def test_empty_and_tiny_inputs_fall_back_cleanly():
    rng = np.random.default_rng(0)
    ref, cur, true = _room_pair(rng)
    guess = true + np.array([0.1, 0.0, 0.05])
    prior = np.diag([0.01, 0.01, 0.001])
    empty = match_scan(ref, np.zeros((0, 2)), guess, prior_covariance=prior)
    assert not empty.ok and empty.reason == "too_few_scan_points"
    np.testing.assert_array_equal(empty.pose, guess)
    np.testing.assert_array_equal(empty.covariance, prior)
    few = match_scan(ref, cur[:10], guess)
    assert not few.ok and few.reason == "too_few_scan_points"
    for reference in (np.zeros((0, 2)), ref[:5]):
        r = match_scan(reference, cur, guess, prior_covariance=prior)
        assert not r.ok and r.reason == "too_few_reference_points"
        np.testing.assert_array_equal(r.pose, guess)


def test_unrelated_scan_is_not_trusted():
    """A scan of a different place (a round room against a square one) is rejected, not
    forced. (Two straight walls against a square room can fit well enough to pass: the
    trust test is a floor on the inlier fraction, not a place recogniser.)"""
    rng = np.random.default_rng(2)
    ref, _, _ = _room_pair(rng)
    round_room = WallSet((Arc((0.0, 0.0), 2.5, 0.0, 2 * math.pi),))
    other = scan_points(cast_scan(round_room, np.array([0.5, 0.0, 0.7]), rng, 0.005), None, CFG)
    result = match_scan(ref, other, np.zeros(3))
    assert not result.ok and result.reason in ("poor_score", "too_few_correspondences")


def _symmetric_room() -> WallSet:
    """A rectangular room with two pillars, the same after a half turn about the origin."""
    return WallSet((
        Segment((-4.0, -3.0), (4.0, -3.0)), Segment((4.0, -3.0), (4.0, 3.0)),
        Segment((4.0, 3.0), (-4.0, 3.0)), Segment((-4.0, 3.0), (-4.0, -3.0)),
        Segment((1.0, 1.0), (1.6, 1.0)), Segment((1.6, 1.0), (1.6, 1.5)), Segment((1.6, 1.5), (1.0, 1.5)),
        Segment((1.0, 1.5), (1.0, 1.0)),
        Segment((-1.0, -1.0), (-1.6, -1.0)), Segment((-1.6, -1.0), (-1.6, -1.5)),
        Segment((-1.6, -1.5), (-1.0, -1.5)), Segment((-1.0, -1.5), (-1.0, -1.0)),
    ))


@pytest.mark.parametrize("seed", range(3))
def test_a_correlative_start_in_a_twin_basin_loses_to_the_guess(seed):
    """In a room the same after a half turn, a scan fits its twin pose as well as its own;
    when the correlative search starts the refinement at the twin, the refinement from the
    guess explains the scan as well and agrees with the prior, so it wins."""
    rng = np.random.default_rng(seed)
    walls = _symmetric_room()
    around = np.radians(np.arange(0.0, 360.0, 0.5))
    ref = scan_points(cast_scan(walls, np.zeros(3), rng, 0.005, angles=around), None, CFG)
    truth = np.array([rng.uniform(-2.5, -2.0), rng.uniform(0.5, 1.5), rng.uniform(-1.0, 1.0)])
    cur = scan_points(cast_scan(walls, truth, rng, 0.005), None, CFG)
    twin = np.array([-truth[0], -truth[1], truth[2] + math.pi])

    class Fooled(ReferenceMap):
        def correlative(self, points, guess, coarse=None):
            return twin.copy(), 1.0

    fooled = Fooled(ref)
    guess = truth + np.array([0.05, -0.04, math.radians(2.0)])
    # the premise: from the twin, the refinement stays at the twin and fits as well
    prior_info = np.linalg.inv(np.diag([0.3 ** 2, 0.3 ** 2, math.radians(10.0) ** 2]))
    at_twin, _, r_twin, _, _ = fooled.refine(cur, twin, guess, prior_info)
    assert np.hypot(*(at_twin[:2] - twin[:2])) < 0.05
    result = fooled.match(cur, guess, np.linalg.inv(prior_info))
    assert result.ok
    err = pose_error(result.pose, truth)
    assert np.hypot(err[0], err[1]) < 0.01 and abs(err[2]) < 0.003


def test_the_truncated_cost_caps_each_point_and_charges_the_unmatched():
    reference = ReferenceMap(scan_points(cast_scan(room(), np.zeros(3), np.random.default_rng(0), 0.005), None, CFG))
    cap = CFG.inlier_distance_m
    sigma2 = CFG.range_sigma_m ** 2 * CFG.covariance_inflation
    residuals = np.array([0.01, -0.02, 0.5])
    pose, mean = np.array([0.1, 0.0, 0.2]), np.array([0.0, 0.0, 0.2 - 2 * math.pi])
    information = np.diag([4.0, 1.0, 9.0])
    expected = (0.01 ** 2 + 0.02 ** 2 + cap ** 2 + 2 * cap ** 2) / sigma2 + 4.0 * 0.1 ** 2
    assert reference.cost(5, residuals, pose, mean, information) == pytest.approx(expected, rel=1e-12)


def test_no_return_and_invalid_beams_are_dropped():
    ranges = np.full(ANGLES.shape, 3.0)
    ranges[:10] = np.nan
    ranges[10:20] = 30.0       # max range: no return
    ranges[20:25] = 0.01       # too close
    ranges[25:30] = 45.0       # beyond max_range_m
    pts = scan_points(LaserScan(0.0, ANGLES, ranges, 50.0), None, FrontendConfig(max_range_m=30.0))
    assert pts.shape == (ANGLES.shape[0] - 30, 2)


def test_likelihood_field_peaks_at_reference_points():
    points = np.array([[0.0, 0.0], [1.0, 0.5]])
    field = LikelihoodField.build(points, 0.05, 0.1, 0.5)
    at = field.values[field.cell_index(points + 0.01)]
    np.testing.assert_allclose(at, 1.0)
    far = field.values[field.cell_index(np.array([[0.0, 0.6], [3.0, 3.0]]))]
    assert np.all(far == 0.0)
    assert field.values.max() <= 1.0


def test_config_is_validated():
    with pytest.raises(ConfigError):
        FrontendConfig(search_window_m=0.0)
    with pytest.raises(ConfigError):
        FrontendConfig(fine_step_m=0.5)
    with pytest.raises(ConfigError):
        FrontendConfig(min_inlier_fraction=1.5)


@pytest.mark.parametrize("half, step", [(6, 2), (4, 1), (5, 2), (0, 1)])
def test_score_grid_equals_score_poses_on_the_offset_grid(half, step):
    """The sliding-window scorer gives the flat-index scorer's values to the bit (both sum
    exactly), offsets in the order of ``_offset_grid``, also for points clipped at the
    border of the field."""
    rng = np.random.default_rng(half * 10 + step)
    ref_pts = rng.uniform(-3.0, 3.0, size=(200, 2))
    field = LikelihoodField.build(ref_pts, 0.1, 0.15, 0.6)
    scan = rng.uniform(-4.0, 4.0, size=(60, 2))
    scan[:3] = [[50.0, 0.0], [0.0, -50.0], [-40.0, 40.0]]        # far outside: clipped
    poses = np.column_stack((rng.normal(0, 0.2, 7), rng.normal(0, 0.2, 7), rng.uniform(-0.5, 0.5, 7)))
    expected = field.score_poses(scan, poses, _offset_grid(half, step))
    got = field.score_grid(scan, poses, half, step)
    assert got.shape == expected.shape and got.dtype == np.float32
    np.testing.assert_array_equal(got, expected)
    # … and the float32 sum of the values up to float32 rounding.
    np.testing.assert_allclose(got, _float32_scores(field, scan, poses, _offset_grid(half, step)), rtol=1e-6)


def _distinct_maxima_by_sorting(score, k, *, rot_sep, off, off_sep):
    """The original full-sort implementation: the oracle of ``_distinct_maxima``."""
    order = np.argsort(score, axis=None)[::-1]
    r_all, t_all = np.unravel_index(order, score.shape)
    taken = []
    alive = np.ones(order.shape[0], dtype=bool)
    for _ in range(k):
        live = np.flatnonzero(alive)
        if live.shape[0] == 0:
            break
        j = live[0]
        r, t = int(r_all[j]), int(t_all[j])
        taken.append((r, t))
        near = (np.abs(r_all - r) < rot_sep) & (np.max(np.abs(off[t_all] - off[t]), axis=1) < off_sep)
        alive &= ~near
    return taken


@pytest.mark.parametrize("seed", range(6))
def test_distinct_maxima_matches_the_sorting_oracle(seed):
    rng = np.random.default_rng(seed)
    off = _offset_grid(6, 2)
    n_rot = [31, 3, 1, 9, 31, 2][seed]
    score = rng.random((n_rot, off.shape[0]))
    k = [4, 4, 10, 50, 1, 200][seed]          # also more than can be distinct
    expected = _distinct_maxima_by_sorting(score, k, rot_sep=2, off=off, off_sep=4)
    got = _distinct_maxima(score, k, rot_sep=2, axis=_offset_axis(6, 2), off_sep=4)
    assert got == expected
    score_copy = score.copy()
    _distinct_maxima(score, k, rot_sep=2, axis=_offset_axis(6, 2), off_sep=4)
    np.testing.assert_array_equal(score, score_copy)


def test_search_grid_is_the_per_scan_grid():
    """The cached pose grids equal those the correlative search used to build per scan."""
    cfg = FrontendConfig()
    res_c, res_f = 0.5 * cfg.coarse_step_m, cfg.fine_step_m
    grid = _search_grid(cfg, res_c, res_f)
    assert _search_grid(cfg, res_c, res_f) is grid
    n_rot = int(np.floor(cfg.search_window_rad / cfg.coarse_step_rad + 1e-9))
    np.testing.assert_allclose(grid.rot_steps, cfg.coarse_step_rad * np.arange(-n_rot, n_rot + 1))
    assert grid.rot_steps.shape == (31,)
    offsets = _offset_grid(int(round(cfg.search_window_m / res_c)), 2)
    np.testing.assert_array_equal(grid.offsets, offsets)
    np.testing.assert_allclose(grid.offsets_m, offsets * res_c)
    penalty = cfg.search_prior_weight * (np.sum((offsets * res_c) ** 2, axis=1)[None, :] / (2 * cfg.search_window_m ** 2)
                                         + (grid.rot_steps ** 2)[:, None] / (2 * cfg.search_window_rad ** 2))
    np.testing.assert_allclose(grid.coarse_penalty, penalty)
    assert grid.coarse_penalty.max() == pytest.approx(cfg.search_prior_weight * 2.0 * 0.5 + cfg.search_prior_weight * 0.5)
    np.testing.assert_allclose(grid.fine_rot, cfg.fine_step_rad * np.arange(-4, 5))
    np.testing.assert_allclose(grid.fine_offsets_m, _offset_grid(4, 1) * res_f)


def test_residuals_match_the_elementwise_formulas():
    """_residuals (matrix form) against the per-component formulas, including points
    without a correspondence within the gate."""
    rng = np.random.default_rng(5)
    ref, cur, true = _room_pair(rng)
    reference = ReferenceMap(ref)
    x = true + np.array([0.02, -0.01, 0.01])
    cur = np.concatenate((cur, [[40.0, 40.0]]))                  # no reference point near
    r, J, w, found = reference._residuals(cur, x, 0.15)
    assert not found[-1] and found.sum() == r.shape[0] > 100
    c, s = math.cos(x[2]), math.sin(x[2])
    px, py = cur[found, 0], cur[found, 1]
    wx, wy = c * px - s * py + x[0], s * px + c * py + x[1]
    d2 = (wx[:, None] - reference.line_points[None, :, 0]) ** 2 + (wy[:, None] - reference.line_points[None, :, 1]) ** 2
    idx = np.argmin(d2, axis=1)
    q, n = reference.line_points[idx], reference.line_normals[idx]
    np.testing.assert_allclose(r, n[:, 0] * (wx - q[:, 0]) + n[:, 1] * (wy - q[:, 1]), atol=1e-12)
    J_expected = np.column_stack((n[:, 0], n[:, 1], n[:, 0] * (-s * px - c * py) + n[:, 1] * (c * px - s * py)))
    np.testing.assert_allclose(J, J_expected, atol=1e-12)
    a = np.abs(r)
    np.testing.assert_allclose(w, np.where(a <= CFG.huber_m, 1.0, CFG.huber_m / a), rtol=1e-15)


def test_kdtree_finds_the_brute_force_nearest_neighbours():
    rng = np.random.default_rng(11)
    pts = rng.uniform(-5.0, 5.0, size=(700, 2))
    queries = rng.uniform(-6.0, 6.0, size=(300, 2))
    d2 = np.sum((queries[:, None, :] - pts[None, :, :]) ** 2, axis=2)
    dist, idx = _kdtree(pts).query(queries, k=3)
    np.testing.assert_array_equal(idx, np.argsort(d2, axis=1)[:, :3])
    np.testing.assert_allclose(dist, np.sqrt(np.sort(d2, axis=1)[:, :3]), rtol=1e-12)
    dist, idx = _kdtree(pts).query(queries, distance_upper_bound=0.2)
    near = np.sqrt(d2.min(axis=1)) < 0.2
    np.testing.assert_array_equal(np.isfinite(dist), near)
    np.testing.assert_array_equal(idx[near], np.argmin(d2, axis=1)[near])


def _float32_scores(field, scan, poses, offsets):
    """Mean field values as a float32 sum in numpy's order, independently of score_poses."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    wx = c[:, None] * scan[None, :, 0] - s[:, None] * scan[None, :, 1] + poses[:, 0:1]
    wy = s[:, None] * scan[None, :, 0] + c[:, None] * scan[None, :, 1] + poses[:, 1:2]
    base = field.cell_index(np.stack((wx, wy), axis=-1))
    idx = base[:, None, :] + (offsets[:, 0] * field.shape[1] + offsets[:, 1])[None, :, None]
    return field.values[idx].sum(axis=2, dtype=np.float32) / scan.shape[0]


def test_score_grid_follows_in_place_additions_and_pickles():
    import pickle

    rng = np.random.default_rng(8)
    field = LikelihoodField.build(rng.uniform(-3.0, 3.0, size=(100, 2)), 0.05, 0.07, 0.4)
    scan = rng.uniform(-2.0, 2.0, size=(40, 2))
    poses = np.zeros((2, 3))
    poses[1] = [0.1, -0.05, 0.2]
    before = field.score_grid(scan, poses, 4, 1)
    field.add(rng.uniform(-2.0, 2.0, size=(50, 2)))
    after = field.score_grid(scan, poses, 4, 1)
    assert np.all(after >= before) and np.any(after > before)
    np.testing.assert_array_equal(after, field.score_poses(scan, poses, _offset_grid(4, 1)))
    copy = pickle.loads(pickle.dumps(field))
    np.testing.assert_array_equal(copy.score_grid(scan, poses, 4, 1), after)


def test_scan_points_drops_the_beams_valid_beams_drops():
    """scan_points' two comparisons against valid_beams (plus the max_range_m cut), with
    NaN, ±inf, negative, zero and boundary ranges, with and without a laser offset."""
    from dataclasses import replace

    from bsslam.config import SegmentationConfig
    from bsslam.scan.segment import valid_beams

    rng = np.random.default_rng(2)
    cfg = replace(CFG, max_range_m=25.0)
    for max_range in (20.0, 30.0, 81.9):
        ranges = rng.uniform(-1.0, 40.0, 361)
        ranges[::17] = np.nan
        ranges[1::23] = np.inf
        ranges[2::29] = -np.inf
        ranges[3::31] = 0.0
        ranges[4::37] = cfg.min_range_m
        ranges[5::41] = max_range
        ranges[6::43] = cfg.max_range_m
        scan = LaserScan(0.0, np.radians(np.linspace(-90.0, 90.0, 361)), ranges, max_range)
        mask, _ = valid_beams(scan, SegmentationConfig(min_range_m=cfg.min_range_m))
        mask &= np.nan_to_num(scan.ranges, nan=np.inf) < cfg.max_range_m
        for offset in (None, np.array([0.1, -0.05, 0.02])):
            o = np.zeros(3) if offset is None else offset
            a, r = scan.angles[mask], scan.ranges[mask]
            expected = np.column_stack((o[0] + r * np.cos(o[2] + a), o[1] + r * np.sin(o[2] + a)))
            np.testing.assert_array_equal(scan_points(scan, offset, cfg), expected)


def _room_search(seed: int):
    """A room pair's reference map (no tie-break towards the guess), the current scan's
    points and a guess 0.3 m / 20° off the truth."""
    rng = np.random.default_rng(seed)
    ref, cur, true = _room_pair(rng)
    reference = ReferenceMap(ref, dataclasses.replace(CFG, search_prior_weight=0.0))
    return reference, cur, true + perturbation(rng, 0.3, 20.0)


@pytest.mark.parametrize("seed", range(3))
def test_alternative_is_the_correlative_search_without_the_best(seed):
    """With nothing excluded and no tie-break, the runner-up search is the correlative
    search itself; with the best excluded, it returns a distinct pose whose score is the
    fine field's at that pose."""
    reference, cur, guess = _room_search(seed)
    best, score = reference.correlative(cur, guess)
    same, same_score = reference.alternative(cur, guess, best, -1.0, -1.0)
    assert np.array_equal(same, best) and same_score == score
    alt, alt_score = reference.alternative(cur, guess, best, 0.3, math.radians(5.0))
    turn = abs(math.remainder(alt[2] - best[2], 2 * math.pi))
    assert math.hypot(alt[0] - best[0], alt[1] - best[1]) > 0.3 or turn > math.radians(5.0)
    oracle = reference.fine.score_poses(cur, alt[None, :], np.zeros((1, 2), dtype=np.int64))[0, 0]
    assert alt_score == pytest.approx(float(oracle), abs=1e-6) and alt_score <= score
    # the shared coarse level gives both searches exactly what they compute on their own
    coarse = reference.coarse_scores(cur, guess)
    assert not coarse.flags.writeable
    shared_best, shared_score = reference.correlative(cur, guess, coarse)
    assert np.array_equal(shared_best, best) and shared_score == score
    shared_alt, shared_alt_score = reference.alternative(cur, guess, best, 0.3, math.radians(5.0), coarse)
    assert np.array_equal(shared_alt, alt) and shared_alt_score == alt_score


@pytest.mark.parametrize("seed", range(3))
def test_alternative_lies_outside_the_admitted_region(seed):
    """A region the match's covariance admits is excluded as the best is: the runner-up
    then lies beyond it and scores no more than the runner-up that may lie inside it."""
    from bsslam.se2 import squared_mahalanobis

    reference, cur, guess = _room_search(seed)
    best, _ = reference.correlative(cur, guess)
    near, near_score = reference.alternative(cur, guess, best, 0.3, math.radians(5.0))
    # a region around the best wide enough to hold that runner-up
    d = near - best
    d[2] = math.remainder(d[2], 2 * math.pi)
    covariance = np.diag(np.square(np.maximum(np.abs(d), [0.05, 0.05, 0.01])))
    bound = 9.0
    assert squared_mahalanobis(near, best, covariance) <= bound
    far, far_score = reference.alternative(cur, guess, best, 0.3, math.radians(5.0),
                                           admitted=(best, np.linalg.inv(covariance), bound))
    assert squared_mahalanobis(far, best, covariance) > bound and far_score <= near_score
    oracle = reference.fine.score_poses(cur, far[None, :], np.zeros((1, 2), dtype=np.int64))[0, 0]
    assert far_score == pytest.approx(float(oracle), abs=1e-6)
    # an empty region changes nothing
    same, same_score = reference.alternative(cur, guess, best, 0.3, math.radians(5.0),
                                             admitted=(best, np.linalg.inv(covariance), -1.0))
    assert np.array_equal(same, near) and same_score == near_score


def _open_ground_scan(near_beams: int) -> LaserScan:
    """A 180° scan with an 80 m laser: ``near_beams`` returns at 5–6 m (a bush), the rest
    off buildings 40–60 m away."""
    angles = np.radians(np.arange(-90.0, 90.5, 1.0))
    ranges = 40.0 + 20.0 * np.abs(np.sin(3.0 * angles))
    ranges[:near_beams] = 5.0 + 0.01 * np.arange(near_beams)
    return LaserScan(0.0, angles, ranges, 80.0)


def test_a_sparse_scan_keeps_its_far_returns():
    """Fewer than min_points returns within max_range_m (counted per scan_voxel_m cell):
    every return up to the sensor's range is kept; with the option off, only the near ones."""
    sparse = _open_ground_scan(10)
    assert scan_points(sparse, None, CFG).shape == (181, 2)
    assert scan_points(sparse, None, dataclasses.replace(CFG, full_range_when_sparse=False)).shape == (10, 2)
    # enough near cells: the far returns stay out, as without the option
    dense = _open_ground_scan(60)
    assert scan_points(dense, None, CFG).shape == (60, 2)
    # a scan whose every return is near stays as it is
    near = LaserScan(0.0, np.radians([0.0, 1.0]), np.array([1.0, 2.0]), 80.0)
    assert scan_points(near, None, CFG).shape == (2, 2)
