"""The submap backend end to end in simulation (exact ground truth) and its parts:
bounded state and memory, loop closure that closes the map, rigid transforms of splines
with their covariance, surfaces shared between submaps."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

import bsslam.submaps.backend as backend
from bsslam.config import SLAMConfig, SubmapConfig
from bsslam.experiments.consistency import simulation_config
from bsslam.mapper import Mapper
from bsslam.pipeline import run_dataset
from bsslam.se2 import between, compose
from bsslam.sim import SimConfig, get_world, simulate
from bsslam.slam import MapSpline
from bsslam.slam.state import JointState
from bsslam.spline import BSplineCurve
from bsslam.submaps.backend import (SURFACE_SPACING_M, SubmapSLAM, _edge, _proper, mark_surfaces, matching_shape,
                                    seam_covariance, search_window, transform_spline, vouched_by_graph, window_covers)
from bsslam.submaps.loop_closure import LoopMatch
from bsslam.submaps.pose_graph import _check_covariance
from bsslam.submaps.loop_support import chain


def _config(**submaps) -> SLAMConfig:
    base = simulation_config(SLAMConfig(), SimConfig())
    return base.replace(backend="submaps", relocalize=True,
                        submaps=dataclasses.replace(SubmapConfig(), **{"max_distance_m": 8.0, **submaps}))


def _run_double_loop(seed: int):
    """The rounded room's whole double loop (two laps: the second revisits the first's
    walls) with noise draw ``seed``: (data, result, (steps, 2) live bytes and state size)."""
    data = simulate(get_world("rounded-room"), SimConfig(), seed=seed)
    mapper = Mapper(_config())
    live = []
    for frame in data:
        mapper.add_frame(frame)
        live.append((mapper.slam.nbytes, mapper.slam.state_size))
    return data, mapper.finish(ground_truth=data.ground_truth), np.array(live)


def _final_pose_nees(result, truth) -> float:
    """The final pose's error in the map frame, weighed by its reported covariance."""
    est = result.trajectory
    e_world = est.poses[-1] - truth.poses[-1]
    e_world[2] = between(truth.poses[-1], est.poses[-1])[2]
    return float(e_world @ np.linalg.solve(est.covariances[-1], e_world))


@pytest.fixture(scope="module")
def double_loop():
    return _run_double_loop(3)


def test_many_submaps_each_of_bounded_state(double_loop):
    data, result, live = double_loop
    cfg = _config().submaps
    assert result.totals["submaps"] >= 5
    # a submap is frozen once it reaches max_state_size: one scan's growth beyond it at most
    assert live[:, 1].max() < cfg.max_state_size + 150
    assert result.submaps is not None and len(result.submaps.frozen) == result.totals["submaps"]


def test_the_second_lap_closes_loops_and_the_map(double_loop):
    """Loop closures are found on the second lap and the final pose is where the ground
    truth is, within 3σ of the reported global covariance (χ²(3) at 99.73 %)."""
    data, result, _ = double_loop
    assert result.totals["loop_closures"] >= 2
    # every accepted loop closure is right: its relative pose is the true one between the
    # two submaps' bases (a base is the pose of the scan that ended the previous submap)
    bases = _true_bases(data, result)
    for loop in result.submaps.loops:
        error = between(bases[loop.reference], bases[loop.query]) - loop.relative
        error[2] = np.remainder(error[2] + np.pi, 2 * np.pi) - np.pi
        assert np.hypot(error[0], error[1]) < 0.2 and abs(error[2]) < 0.02, (loop, error)
    nees = _final_pose_nees(result, data.ground_truth)
    assert nees < chi2.ppf(0.9973, 3), nees


@pytest.mark.parametrize("seed", [4, 5, 7, 8])
def test_the_final_pose_is_within_its_covariance_on_other_noise_draws(seed):
    """The property of :func:`test_the_second_lap_closes_loops_and_the_map` on other noise
    draws. Seed 4 failed (final NEES ~39: an extension of the top wall bent at its joint by
    parameters taken from the association at the predicted pose) until extensions were
    placed by their own geometry (2.7)."""
    data, result, _ = _run_double_loop(seed)
    nees = _final_pose_nees(result, data.ground_truth)
    assert nees < chi2.ppf(0.9973, 3), nees


def test_matching_the_growing_submap_ties_the_online_pose_to_the_old_map(double_loop):
    """With ``online_match_m`` (5 m here; off by default) the growing submap is matched
    against the old ones on the second lap and the online pose is conditioned on the
    matches: its covariance tighter and its error smaller than without, the last online
    pose within its covariance (χ²(3) at 99.73 %); the matches never enter the graph, so the
    final trajectory and map are those of a run without them, to the last bit."""
    data, without, _ = double_loop
    assert without.totals["online_matches"] == 0
    mapper = Mapper(_config(online_match_m=5.0))
    for frame in data:
        mapper.add_frame(frame)
    result = mapper.finish(ground_truth=data.ground_truth)
    assert result.totals["online_matches"] >= 5
    np.testing.assert_array_equal(result.trajectory.poses, without.trajectory.poses)
    assert [s.curve.control_points.tolist() for s in result.map] == [s.curve.control_points.tolist() for s in without.map]
    truth = data.ground_truth.poses
    second = slice(len(truth) // 2, None)

    def position_rms_and_sigma(run):
        err = run.estimate.poses[second, :2] - truth[second, :2]
        sigma = np.sqrt(np.trace(run.estimate.covariances[second, :2, :2], axis1=1, axis2=2))
        return np.sqrt(np.mean(np.sum(err ** 2, axis=1))), np.mean(sigma)

    (rms, sigma), (rms_without, sigma_without) = position_rms_and_sigma(result), position_rms_and_sigma(without)
    assert sigma < 0.9 * sigma_without and rms < rms_without, (sigma, sigma_without, rms, rms_without)
    e = result.estimate.poses[-1] - truth[-1]
    e[2] = between(truth[-1], result.estimate.poses[-1])[2]
    assert e @ np.linalg.solve(result.estimate.covariances[-1], e) < chi2.ppf(0.9973, 3)


def _true_bases(data, result) -> list[np.ndarray]:
    """Each submap's true base pose: the true pose of the scan that ended the one before."""
    gt, sub = data.ground_truth.poses, result.step_submaps
    return [gt[0]] + [gt[np.flatnonzero(sub == k - 1)[-1]] for k in range(1, sub.max() + 1)]


def test_the_end_of_run_sweep_adds_the_loop_closures_the_online_matching_missed():
    """With one candidate per newly frozen submap the online matching ties few pairs of the
    double loop's submaps; the sweep at the end (``loop_sweep``) matches each submap again,
    against as many older ones it overlaps and is not tied to, with the final graph's
    guess and window, and adds the verified matches: each within its
    own covariance of the truth (χ²(3) at 99.9 %), no pair tied twice, the online ones
    kept, and the final pose within 3σ. Without the sweep the loop closures are the online
    ones alone."""
    data = simulate(get_world("rounded-room"), SimConfig(), seed=3)
    results = {}
    for sweep in (True, False):
        mapper = Mapper(_config(loop_max_candidates=1, loop_sweep=sweep))
        for frame in data:
            mapper.add_frame(frame)
        results[sweep] = mapper.finish(ground_truth=data.ground_truth)
    swept, online = results[True], results[False]
    assert online.totals["loop_sweep_closures"] == 0 and online.totals["loop_sweep_candidates"] == 0
    added = swept.totals["loop_sweep_closures"]
    assert added >= 3, swept.totals
    assert swept.totals["loop_closures"] == online.totals["loop_closures"] + added
    pairs = [(loop.reference, loop.query) for loop in swept.submaps.loops]
    assert len(set(pairs)) == len(pairs)
    assert {(loop.reference, loop.query) for loop in online.submaps.loops} <= set(pairs)
    bases = _true_bases(data, swept)
    for loop in swept.submaps.loops:
        error = between(bases[loop.reference], bases[loop.query]) - loop.relative
        error[2] = np.remainder(error[2] + np.pi, 2 * np.pi) - np.pi
        assert error @ np.linalg.solve(loop.covariance, error) < chi2.ppf(0.999, 3), (loop, error)
    assert _final_pose_nees(swept, data.ground_truth) < chi2.ppf(0.9973, 3)


@pytest.mark.parametrize("clipped", [False, True])
def test_the_sweep_refuses_a_match_the_graph_can_judge_and_does_not_expect(monkeypatch, clipped):
    """Every match of the end-of-run sweep moved 3 m off (verified, as a repeated wall can
    make it) and outside the graph's 99 % region: where the search window covered the
    graph's region the graph can judge, and with no later submaps to vote the sweep refuses
    each (counted as ``sweep_unexpected``), keeping the online loop closures alone; a match
    found in a window clipped short of the region is taken as before."""
    data = simulate(get_world("rounded-room"), SimConfig(), seed=3)
    mapper = Mapper(_config(loop_max_candidates=1))
    for frame in data:
        mapper.add_frame(frame)
    online = len(mapper.slam.loops)
    real = backend.match_submaps

    def wrong(*args):
        match = real(*args)
        return dataclasses.replace(match, relative=match.relative + np.array([3.0, 0.0, 0.0]), expected=False)

    monkeypatch.setattr(backend, "match_submaps", wrong)
    monkeypatch.setattr(backend, "window_covers", lambda *args: not clipped)
    result = mapper.finish(ground_truth=data.ground_truth)
    refused = result.totals.get("loop_rejected_sweep_unexpected", 0)
    if clipped:
        assert refused == 0 and result.totals["loop_sweep_closures"] >= 3
    else:
        assert refused >= 3 and result.totals["loop_sweep_closures"] == 0
        assert len(result.submaps.loops) == online


def test_live_memory_is_counted_and_within_the_budget(double_loop):
    """The live bytes are the local filter's buffers plus the frozen submaps' arrays; the
    local's are bounded by max_state_size whatever the length of the run."""
    data, result, live = double_loop
    slam = result.submaps
    assert slam.nbytes == slam.local.state.nbytes + sum(f.nbytes for f in slam.frozen)
    assert live[:, 0].max() <= SLAMConfig().max_memory_mb * 2 ** 20
    assert max(f.nbytes for f in slam.frozen) < 2 ** 20
    # the state's capacity doubles from 64: max_state_size 400 + one scan fits in 512, so
    # the local buffers never reach those of a 1024 capacity
    assert live[:, 0].max() - sum(f.nbytes for f in slam.frozen) < JointState(np.zeros(3), np.zeros((3, 3)),
                                                                               capacity=1024).nbytes


def test_a_budget_too_small_stops_the_run_with_its_results():
    """Past max_memory_mb a run stops cleanly with the scans so far and the reason —
    counted from the estimator's own buffers, before allocating, never a MemoryError."""
    data = simulate(get_world("rounded-room"), SimConfig(), seed=3, steps=150)
    # the global EKF's state passes 256 (433 at the end): its buffers for 512 (3.0 MB, and
    # 1.2 MB for 256 while copying) do not fit
    ekf = _config().replace(backend="ekf", max_memory_mb=3.5)
    result = run_dataset(data, ekf)
    assert result.interrupted and 0 < result.steps < 150
    assert "max_memory_mb" in result.stop_reason
    assert len(result.map) > 0 and np.all(np.isfinite(result.trajectory.poses))
    # the submaps keep the same run within a budget the global EKF cannot keep
    assert not run_dataset(data, _config(max_state_size=200).replace(max_memory_mb=3.5)).interrupted


def _line(x0, y0, x1, y1, n=6) -> BSplineCurve:
    t = np.linspace(0.0, 1.0, n)
    pts = np.column_stack([x0 + (x1 - x0) * t, y0 + (y1 - y0) * t])
    length = float(np.hypot(x1 - x0, y1 - y0))
    knots = np.r_[[0.0] * 3, np.linspace(0.0, length, n - 2), [length] * 3]
    return BSplineCurve(pts, knots, 3)


def test_transform_spline_moves_the_covariance_with_the_points():
    """The covariance of the moved control points is J Σ Jᵀ with J the transform's
    Jacobian, here from finite differences of the transform itself."""
    rng = np.random.default_rng(1)
    curve = _line(0.0, 0.0, 3.0, 1.0)
    n = curve.control_points.shape[0]
    A = rng.normal(size=(2 * n, 2 * n))
    cov = A @ A.T * 1e-4
    pose = np.array([2.0, -1.0, 0.7])
    moved = transform_spline(MapSpline(0, curve, cov), pose, submap=4)

    def flat(points):
        c = BSplineCurve(points.reshape(2, n).T, curve.knots, 3).transformed(pose[2], pose[:2])
        return np.r_[c.control_points[:, 0], c.control_points[:, 1]]

    x0 = np.r_[curve.control_points[:, 0], curve.control_points[:, 1]]
    J = np.column_stack([(flat(x0 + 1e-6 * e) - flat(x0 - 1e-6 * e)) / 2e-6 for e in np.eye(2 * n)])
    np.testing.assert_allclose(moved.covariance, J @ cov @ J.T, atol=1e-12)
    np.testing.assert_allclose(flat(x0), np.r_[moved.curve.control_points[:, 0], moved.curve.control_points[:, 1]])
    assert moved.submap == 4


def test_surfaces_join_the_same_wall_of_two_submaps_only():
    cov = np.zeros((12, 12))
    wall = _line(0.0, 0.0, 4.0, 0.0)
    same_wall_again = _line(0.5, 0.02, 4.5, 0.02)      # 2 cm beside it, mostly overlapping
    other_wall = _line(0.0, 1.0, 4.0, 1.0)
    splines = [MapSpline(0, wall, cov, submap=0), MapSpline(1, same_wall_again, cov, submap=1),
               MapSpline(2, other_wall, cov, submap=1), MapSpline(3, _line(0.0, 0.05, 4.0, 0.05), cov, submap=0)]
    for spacing in (0.05, SURFACE_SPACING_M):     # the matching's and the map's sampling
        s = mark_surfaces(splines, spacing)
        assert s[0].surface == s[1].surface == 0
        assert s[2].surface == 2
        # two splines of one submap are never joined directly (the filter keeps them apart
        # on purpose); here spline 3 joins through spline 1 of the other submap
        assert s[3].surface == 0
        assert mark_surfaces(splines[:1] + splines[2:3], spacing)[1].surface == 1


def test_the_configured_guard_against_wrong_loop_closures_reaches_the_graph():
    slam = SubmapSLAM(_config(loop_outliers="gnc", loop_inlier_probability=0.95))
    assert slam.graph.loop_outliers == "gnc" and slam.graph.loop_inlier_probability == 0.95
    assert SubmapSLAM(_config(robust_kernel_width=2.0)).graph.robust_kernel_width == 2.0


def test_a_surprising_match_waits_for_a_neighbour_that_agrees(double_loop):
    """A verified match beyond the graph's 99 % region enters the graph only once a
    neighbouring match closes a consistent cycle with it; alone it is dropped as
    ``unsupported`` once no later query can vote on it."""
    _, result, _ = double_loop
    slam = copy.deepcopy(result.submaps)
    reach = 3
    # cycles vote when their 99 % region is within 1 m and 20°: the invariant EKF's seams
    # keep the heading σ the paper's EKF shrank, and the cycles here reach 0.7–1.0 m at
    # 99 %, so at the default 0.5 m none would be precise enough to vote
    slam.config = slam.config.replace(submaps=dataclasses.replace(
        slam.config.submaps, loop_support_submaps=reach, loop_distinct_m=1.0, loop_distinct_rad=np.radians(20.0)))
    loop = [loop for loop in slam.loops if loop.reference >= 1][-1]     # its reference has a predecessor
    last = slam.submap_index
    before = slam.graph.loop_count

    # a copy of the last loop closure's walls 2 m away, alone (made up here, with no
    # search behind it: no rival, so the distinct thresholds above decide which cycles vote)
    wrong = dataclasses.replace(loop, reference=loop.reference - 1, loop_id=-1, rival=None,
                                relative=compose(chain(_edges(slam), loop.reference - 1, loop.reference)[0],
                                                 compose(loop.relative, np.array([2.0, 0.0, 0.0]))))
    assert not slam._admit(last, [(wrong, 5.0, True)])
    assert slam.graph.loop_count == before
    slam._expire_pending(last + reach)
    assert slam.stats.loop_rejections["unsupported"] >= 1 and slam.graph.loop_count == before

    # the same pair of submaps matched where the loop closure beside it says: it agrees
    right = dataclasses.replace(wrong, relative=compose(chain(_edges(slam), loop.reference - 1, loop.reference)[0],
                                                        loop.relative))
    assert slam._admit(last, [(right, 5.0, True)])
    assert slam.graph.loop_count == before + 1


def _edges(slam):
    return [(f.end_pose, f.end_covariance) for f in slam.frozen]


def test_loop_closures_keep_their_rivals_for_the_vote(double_loop):
    """Each loop closure carries its match's runner-up alignment (what the vote asks a
    cycle to tell it from): in the rounded room, a copy slid about half a metre along a
    wall; the vote's edges carry it too."""
    _, result, _ = double_loop
    loops = result.submaps.loops
    rivals = [loop for loop in loops if loop.rival is not None]
    assert rivals, "no loop closure kept a rival"
    for loop in rivals:
        assert loop.rival.shape == (3,) and np.all(np.isfinite(loop.rival))
        assert not np.allclose(loop.rival, loop.relative)
        assert _edge(loop).rival is loop.rival


def test_slides_along_the_corridor_walls_are_kept_within_their_covariance():
    """With ``loop_slides`` (the default) the corridor loop's straight walls give loop
    closures the ambiguity test would refuse, each a slide: the true relative pose of its two
    bases within the 99 % region of its widened covariance, and counted in the run's totals.
    Off, no loop closure is a slide and the totals do not count them."""
    data = simulate(get_world("corridor-loop"), SimConfig(), seed=1)
    runs = {}
    for slides in (False, True):
        mapper = Mapper(_config(loop_slides=slides))
        for frame in data:
            mapper.add_frame(frame)
        runs[slides] = mapper.finish(ground_truth=data.ground_truth)
    assert "loop_slides" not in runs[False].totals and not any(loop.slide for loop in runs[False].submaps.loops)
    result = runs[True]
    slides = [loop for loop in result.submaps.loops if loop.slide]
    assert slides and result.totals["loop_slides"] == len(slides)
    bases = _true_bases(data, result)
    for loop in slides:
        d = loop.relative - between(bases[loop.reference], bases[loop.query])
        d[2] = (d[2] + np.pi) % (2 * np.pi) - np.pi
        assert d @ np.linalg.solve(loop.covariance, d) < chi2.ppf(0.99, 3), loop


def test_a_spline_position_sigma_is_the_median_control_point_sigma():
    """Against numpy's eigenvalues of each control point's 2 × 2 block."""
    rng = np.random.default_rng(2)
    n = 7
    A = rng.normal(size=(2 * n, 2 * n))
    cov = A @ A.T * 0.01
    curve = BSplineCurve(rng.normal(size=(n, 2)), np.r_[np.zeros(3), np.arange(n - 2), np.full(3, n - 3)], 3)
    spline = MapSpline(0, curve, cov)
    blocks = [cov[np.ix_([i, n + i], [i, n + i])] for i in range(n)]
    expected = np.median([np.sqrt(np.linalg.eigvalsh(b)[-1]) for b in blocks])
    assert spline.position_sigma == pytest.approx(expected, rel=1e-12)


def test_walls_a_lost_filter_mapped_take_no_part_in_loop_closure(double_loop):
    """With ``loop_max_wall_sigma_m`` a submap's walls whose place is known to worse than
    it stay in the map but are not sampled for matching; at 0 (default) every wall is."""
    _, result, _ = double_loop
    default = result.submaps.config.submaps
    cfg = dataclasses.replace(default, loop_max_wall_sigma_m=0.5)
    splines = result.submaps.local_map(3)
    assert len(splines) > 2 and all(s.position_sigma <= 0.5 for s in splines)
    full = matching_shape(splines, cfg)
    np.testing.assert_array_equal(full.points, result.submaps.frozen[3].shape.points)
    lost = [dataclasses.replace(s, covariance=s.covariance + np.eye(s.covariance.shape[0])) for s in splines[:2]]
    shape = matching_shape(lost + splines[2:], cfg)
    np.testing.assert_array_equal(shape.points, matching_shape(splines[2:], cfg).points)
    assert 0 < shape.points.shape[0] < full.points.shape[0]
    np.testing.assert_array_equal(matching_shape(lost + splines[2:], default).points, full.points)


def test_a_clamped_loop_covariance_is_exactly_symmetric():
    """A loop closure between walls known to tens of metres (a filter that lost itself) has
    its x-y variance clamped to the search window's: two equal eigenvalues whose vectors
    are arbitrary, and V diag(w) Vᵀ came out asymmetric in the last bits, which the graph
    refuses (the Freiburg campus with 1 mm of range noise stopped on it)."""
    rng = np.random.default_rng(1)
    for _ in range(200):
        a = rng.normal(size=(3, 3)) * 1e-3
        cov = _proper(np.diag([400.0, 400.0, 0.44]) + a @ a.T, 12.0)
        np.testing.assert_array_equal(cov, cov.T)
        _check_covariance(cov, "loop covariance")
        np.testing.assert_allclose(np.linalg.eigvalsh(cov)[1:], 144.0)


def test_the_seam_covariance_adds_drift_linear_in_the_distance():
    """The constraint between two bases: the filter's covariance plus (rate × distance)²,
    x and y from the metric rate, heading from the angular one; nothing with rates 0."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 3)) * 0.01
    filt = a @ a.T
    cfg = SubmapConfig(seam_drift_m_per_m=0.02, seam_drift_rad_per_m=0.003)
    np.testing.assert_allclose(seam_covariance(filt, 10.0, cfg) - filt, np.diag([0.04, 0.04, 0.0009]), atol=1e-15)
    np.testing.assert_allclose(seam_covariance(filt, 20.0, cfg) - filt, np.diag([0.16, 0.16, 0.0036]), atol=1e-15)
    off = SubmapConfig(seam_drift_m_per_m=0.0, seam_drift_rad_per_m=0.0)
    np.testing.assert_array_equal(seam_covariance(filt, 10.0, off), filt)


def test_a_frozen_submap_keeps_the_seam_covariance(double_loop):
    """What the frozen submap keeps (and the graph is given) carries the drift: without it
    the first submap's end σ is a few mm (simulated walls), far below the drift bound."""
    data, result, _ = double_loop
    slam = result.submaps
    cfg = slam.config.submaps
    first = slam.frozen[0]
    # the first submap's end covariance is the filter's plus at least the drift of max_distance_m
    assert first.end_covariance[0, 0] >= (cfg.seam_drift_m_per_m * cfg.max_distance_m) ** 2
    assert first.end_covariance[2, 2] >= (cfg.seam_drift_rad_per_m * cfg.max_distance_m) ** 2


def test_each_seam_reaches_the_graph_with_the_distance_travelled_in_its_submap(double_loop):
    """The shared drift rate turns each seam by rate × distance: the distances the graph is
    given are the odometry's path in each submap, the last (still open) one aside."""
    data, result, _ = double_loop
    slam = result.submaps
    given = slam.graph.distances
    assert len(given) == len(slam.frozen)
    path = np.hypot(*np.diff(data.ground_truth.poses[:, :2], axis=0).T).sum()
    assert np.all(given <= slam.config.submaps.max_distance_m + 1.0)   # one step past the bound
    assert given.sum() == pytest.approx(path, rel=0.1)     # odometry's path, not the truth's


def test_a_run_with_the_shared_drift_rate_reports_it():
    """``drift_rate_sigma_rad_per_m`` > 0: the graph holds the rate, summary.json reports it
    (°/100 m) with its σ, and in simulation, where nothing drifts the same way throughout,
    it is within 3σ of zero."""
    from bsslam.outputs import summarize
    data = simulate(get_world("rounded-room"), SimConfig(), seed=3, steps=120)
    result = run_dataset(data, _config(drift_rate_sigma_rad_per_m=0.001))
    rate, sigma = result.submaps.graph.drift_rate()
    assert 0 < sigma < 0.001 and abs(rate) < 3 * sigma
    summary = summarize(result)
    assert summary["drift_rate_deg_per_100m"] == pytest.approx(np.degrees(rate) * 100, abs=1e-4)
    assert summary["drift_rate_sigma_deg_per_100m"] == pytest.approx(np.degrees(sigma) * 100, abs=1e-4)
    assert "drift_rate_deg_per_100m" not in summarize(run_dataset(data, _config()))


def test_the_graph_vouches_only_for_matches_whose_window_covered_its_region():
    """A search window covers ``loop_sigmas`` σ of the graph's relative pose unless
    :func:`search_window` clipped it at its maximum; a heading window of π covers every
    heading. An expected match found in a clipped window is not vouched for (it must wait
    for its neighbours, as a surprising one); nor is an unexpected one in any window."""
    cfg = SubmapConfig()
    def window(sigma_m, sigma_rad):
        cov = np.diag([sigma_m ** 2, (0.5 * sigma_m) ** 2, sigma_rad ** 2])
        return cov, *search_window(cov, cfg)
    top = cfg.loop_max_window_m / cfg.loop_sigmas        # the largest σ a window covers
    for sigma_m, sigma_rad, covers in ((0.1, 0.01, True), (top, 0.01, True), (top * (1 + 1e-9), 0.01, False),
                                       (70.0, 0.01, False), (1.0, 5.0, True)):
        cov, window_m, window_rad = window(sigma_m, sigma_rad)
        assert window_covers(cov, window_m, window_rad, cfg) is covers, (sigma_m, sigma_rad)
        for expected in (True, False):
            match = LoopMatch(True, "ok", np.zeros(3), np.eye(3), expected=expected)
            assert vouched_by_graph(match, cov, window_m, window_rad, cfg) is (covers and expected)
    # a heading window short of π that does not reach 3 σ
    narrow = dataclasses.replace(cfg, loop_max_window_rad=1.0)
    cov = np.diag([0.01, 0.01, 0.5 ** 2])
    window_m, window_rad = search_window(cov, narrow)
    assert window_rad == 1.0 and not window_covers(cov, window_m, window_rad, narrow)
