"""Loop closure between submaps on simulated buildings with exact ground truth.

The walls are fitted once in the world frame (bsslam's spline fitting); a submap is the
walls within an x range, moved into the submap's own frame rigidly (affine invariance of
B-splines: the curves are the same, only expressed elsewhere).
"""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from bsslam.config import SubmapConfig
from bsslam.errors import ConfigError
from bsslam.se2 import between, compose, inverse
from bsslam.spline import BSplineCurve, fit_curve
from bsslam.frontend.scan_matcher import ReferenceMap
from bsslam.submaps.loop_closure import (LoopMatch, SubmapShape, match_submaps, matched_walls_covariance,
                                         matcher_config, on_ridge, slide_covariance)
from bsslam.trajectory import wrap_angle

CONFIG = SubmapConfig()
SPACING = CONFIG.point_spacing_m


def _polyline(*corners: tuple[float, float], step: float = 0.02) -> np.ndarray:
    """Points every ~``step`` m along straight pieces through ``corners``."""
    c = np.asarray(corners, dtype=float)
    parts = []
    for a, b in zip(c[:-1], c[1:]):
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / step)))
        parts.append(a + np.linspace(0.0, 1.0, n, endpoint=False)[:, None] * (b - a))
    return np.concatenate(parts + [c[-1:]])


def _arc(center: tuple[float, float], radius: float, start_deg: float, end_deg: float) -> np.ndarray:
    phi = np.radians(np.linspace(start_deg, end_deg, int(abs(end_deg - start_deg) * radius / 1.2) + 2))
    return np.asarray(center) + radius * np.column_stack((np.cos(phi), np.sin(phi)))


#: A 24 m × 12 m building: outer walls, two partitions with doors, a curved wall, an L, short walls.
BUILDING = [
    _polyline((0, 0), (24, 0)), _polyline((0, 12), (24, 12)), _polyline((0, 0.5), (0, 11.5)),
    _polyline((24, 0.5), (24, 11.5)), _polyline((8, 0.3), (8, 5)), _polyline((8, 7), (8, 11.7)),
    _polyline((16, 0.3), (16, 4)), _arc((12, 8), 2.5, 200, 340), _polyline((18, 8), (21, 8), (21, 10)),
    _polyline((4, 9), (5.5, 9)), _polyline((3, 3), (3, 4.5)), _polyline((18.5, 2.5), (20, 4)),
    _polyline((11, 2), (13, 2), (13, 3)),
]


def _submap(walls: list[np.ndarray], x_lo: float, x_hi: float, frame: np.ndarray,
            rng: np.random.Generator | None = None, noise_m: float = 0.0) -> list[BSplineCurve]:
    """Curves of the walls' pieces with x in [x_lo, x_hi] (world), expressed in the frame
    whose world pose is ``frame`` (3,); fitted to points with Gaussian noise of
    ``noise_m`` (m) when given (each submap its own noise, as two visits see a wall)."""
    inv = inverse(np.asarray(frame, dtype=float))
    curves = []
    for pts in walls:
        if noise_m:
            pts = pts + rng.normal(0.0, noise_m, pts.shape)
        keep = (pts[:, 0] >= x_lo) & (pts[:, 0] <= x_hi)
        # Split at gaps so that each contiguous run is one curve.
        breaks = np.flatnonzero(np.diff(keep.astype(int)) != 0) + 1
        for run in np.split(np.arange(pts.shape[0]), breaks):
            if keep[run[0]] and run.shape[0] >= 20:
                curve = fit_curve(pts[run], 3, 0.5).curve
                curves.append(curve.transformed(float(inv[2]), inv[:2]))
    return curves


def _shape(walls, x_lo, x_hi, frame, rng=None, noise_m=0.0) -> SubmapShape:
    return SubmapShape.from_curves(_submap(walls, x_lo, x_hi, frame, rng, noise_m), SPACING)


REF_FRAME = np.array([2.0, 3.0, 0.3])
QUERY_FRAME = np.array([14.0, 6.0, -1.1])
TRUE = between(REF_FRAME, QUERY_FRAME)
GUESS_COV = np.diag([1.0, 1.0, math.radians(10.0) ** 2])


def _error(match: LoopMatch, truth: np.ndarray) -> tuple[float, float]:
    d = match.relative - truth
    return float(np.hypot(d[0], d[1])), abs(float(wrap_angle(d[2])))


@pytest.fixture(scope="module")
def overlapping() -> tuple[SubmapShape, SubmapShape]:
    return _shape(BUILDING, -1, 15, REF_FRAME), _shape(BUILDING, 7, 25, QUERY_FRAME)


def test_shape_samples_the_curves_at_the_spacing():
    curves = _submap(BUILDING, -1, 25, np.zeros(3))
    shape = SubmapShape.from_curves(curves, 0.1)
    # Consecutive points of one curve are one spacing of arc length apart (chords ≤ it).
    same = np.diff(shape.curve_index) == 0
    chords = np.hypot(*np.diff(shape.points, axis=0)[same].T)
    assert np.all(chords <= 0.1 * (1 + 1e-3)) and np.median(chords) > 0.0999
    assert shape.length_m == pytest.approx(sum(c.length() for c in curves), rel=1e-4)
    # Normals: unit, perpendicular to the sampled walls (the bottom wall y = 0: ±y).
    assert np.allclose(np.hypot(*shape.normals.T), 1.0)
    bottom = (np.abs(shape.points[:, 1]) < 1e-6) & (shape.points[:, 0] > 1) & (shape.points[:, 0] < 23)
    assert bottom.sum() > 200 and np.allclose(np.abs(shape.normals[bottom, 1]), 1.0)
    # The arc's curvature is 1 / 2.5 m in magnitude away from its ends.
    arc = np.hypot(shape.points[:, 0] - 12, shape.points[:, 1] - 8)
    on_arc = np.abs(arc - 2.5) < 1e-3
    assert np.median(np.abs(shape.curvature[on_arc])) == pytest.approx(0.4, rel=0.02)
    assert np.all(np.hypot(*(shape.points - shape.center).T) <= shape.radius + 1e-9)


def test_recovers_the_true_relative_pose(overlapping):
    reference, query = overlapping
    guess = compose(TRUE, np.array([1.2, -0.9, math.radians(15.0)]))        # 1.5 m and 15° off
    match = match_submaps(reference, query, guess, GUESS_COV, 3.0, math.radians(30.0), CONFIG)
    assert match.ok, match
    dist, turn = _error(match, TRUE)
    assert dist < 0.03 and turn < math.radians(1.0)
    e = match.relative - TRUE
    e[2] = wrap_angle(e[2])
    assert float(e @ np.linalg.solve(match.covariance, e)) < 3.0 ** 2 * 3
    assert match.inlier_fraction >= CONFIG.loop_min_inlier_fraction and match.overlap_m >= CONFIG.loop_min_overlap_m
    assert match.curves_agreeing >= 2 and match.ambiguity <= CONFIG.loop_max_ambiguity


@pytest.mark.parametrize("seed", range(3))
def test_noisy_submaps_recover_the_pose_within_the_covariance(seed):
    """Each submap's splines fitted to its own noisy wall points (2 cm): the curves differ
    by their fit errors, as two visits' maps do; the error stays within the covariance."""
    rng = np.random.default_rng(seed)
    reference = _shape(BUILDING, -1, 15, REF_FRAME, rng, 0.02)
    query = _shape(BUILDING, 7, 25, QUERY_FRAME, rng, 0.02)
    guess = compose(TRUE, np.array([-1.0, 1.1, math.radians(-15.0)]))
    match = match_submaps(reference, query, guess, GUESS_COV, 3.0, math.radians(30.0), CONFIG)
    assert match.ok, match
    dist, turn = _error(match, TRUE)
    assert dist < 0.03 and turn < math.radians(0.5)
    e = match.relative - TRUE
    e[2] = wrap_angle(e[2])
    assert float(e @ np.linalg.solve(match.covariance, e)) < chi2.ppf(0.999, 3)


def _with_sigma(shape: SubmapShape, sigma_m: float) -> SubmapShape:
    return dataclasses.replace(shape, sigma=np.full(shape.points.shape[0], sigma_m))


def test_the_matched_walls_sigma_is_added_to_the_alignment_covariance(overlapping):
    """The loop closure's covariance is the alignment's plus the matched walls' σ² of both
    submaps (x and y) and the same over the lever arm (heading); with the option off, the
    alignment's alone; the alignment itself does not change."""
    reference, query = overlapping
    guess = compose(TRUE, np.array([0.5, -0.4, math.radians(5.0)]))
    args = (guess, GUESS_COV, 3.0, math.radians(30.0))
    off = match_submaps(_with_sigma(reference, 0.03), _with_sigma(query, 0.04), *args,
                        dataclasses.replace(CONFIG, loop_wall_covariance=False))
    on = match_submaps(_with_sigma(reference, 0.03), _with_sigma(query, 0.04), *args, CONFIG)
    assert on.ok and off.ok
    np.testing.assert_array_equal(on.relative, off.relative)
    added = on.covariance - off.covariance
    np.testing.assert_allclose(added[:2, :2], (0.03 ** 2 + 0.04 ** 2) * np.eye(2), rtol=1e-9, atol=1e-15)
    lever = math.sqrt((0.03 ** 2 + 0.04 ** 2) / added[2, 2])          # RMS radius of the matched points (m)
    assert 2.0 < lever < 12.0                       # the overlap is ~8 × 12 m
    np.testing.assert_allclose(added[[0, 0, 1, 1], [1, 2, 0, 2]], 0.0, atol=1e-15)


def test_matched_walls_covariance_of_nothing_is_zero_and_the_lever_at_least_a_metre():
    assert not matched_walls_covariance(np.zeros(0), np.zeros(0), np.zeros((0, 2))).any()
    near = matched_walls_covariance(np.full(3, 0.1), np.zeros(3), np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1]]))
    np.testing.assert_allclose(np.diag(near), [0.01, 0.01, 0.01])


def test_drifted_walls_stay_within_the_loop_closures_covariance():
    """The query submap's walls all displaced by one drift drawn from N(0, σ² I) (a filter
    that drifted while it mapped them), its walls saying σ: over 20 draws the loop closures'
    position errors, weighed by their covariance, are χ²(2) (the sum within its 99.8 %
    interval); without the walls' σ the same errors are far outside it."""
    sigma, draws = 0.08, 20
    rng = np.random.default_rng(7)
    reference = _shape(BUILDING, -1, 15, REF_FRAME)
    curves = _submap(BUILDING, 7, 25, QUERY_FRAME)
    with_walls, alignment_only = 0.0, 0.0
    for _ in range(draws):
        drift = rng.normal(0.0, sigma, 2)
        query = SubmapShape.from_curves([c.transformed(0.0, drift) for c in curves], SPACING,
                                        np.full(len(curves), sigma))
        # the walls drifted by ``drift`` in the query frame: the match finds the base moved by −drift
        truth = compose(TRUE, np.r_[-drift, 0.0])
        on = match_submaps(reference, query, TRUE, GUESS_COV, 2.0, math.radians(20.0), CONFIG)
        off = match_submaps(reference, query, TRUE, GUESS_COV, 2.0, math.radians(20.0),
                            dataclasses.replace(CONFIG, loop_wall_covariance=False))
        assert on.ok and off.ok
        e = (on.relative - TRUE)[:2]
        with_walls += float(e @ np.linalg.solve(on.covariance[:2, :2], e))
        alignment_only += float(e @ np.linalg.solve(off.covariance[:2, :2], e))
        assert np.hypot(*(on.relative - truth)[:2]) < 0.01
    assert chi2.ppf(0.001, 2 * draws) < with_walls < chi2.ppf(0.999, 2 * draws)
    assert alignment_only > 10 * chi2.ppf(0.999, 2 * draws)


def test_non_overlapping_submaps_are_rejected():
    reference = _shape(BUILDING, -1, 7, REF_FRAME)
    query = _shape(BUILDING, 15, 25, QUERY_FRAME)
    for offset in ([0.0, 0.0, 0.0], [2.0, -1.5, 0.3]):
        guess = compose(TRUE, np.array(offset))
        match = match_submaps(reference, query, guess, GUESS_COV, 3.0, math.radians(30.0), CONFIG)
        assert not match.ok and match.reason == "too_little_overlap", match


def test_a_match_carried_by_one_curve_is_rejected():
    """One L-shaped curve fixes the pose (nearly) on its own, but one wall is no joint evidence."""
    reference = _shape(BUILDING, -1, 25, REF_FRAME)
    query = SubmapShape.from_curves(_submap([BUILDING[8]], -1, 25, QUERY_FRAME), SPACING)
    # The other checks relaxed so that the vote alone decides.
    config = dataclasses.replace(CONFIG, loop_min_overlap_m=3.0, loop_min_information_ratio=0.0, loop_max_ambiguity=1.0)
    guess = compose(TRUE, np.array([0.3, -0.2, 0.05]))
    match = match_submaps(reference, query, guess, GUESS_COV, 1.0, math.radians(10.0), config)
    assert not match.ok and match.reason == "incompatible", match
    assert match.curves_agreeing == 1
    dist, turn = _error(match, TRUE)
    assert dist < 0.05 and turn < math.radians(1.0)           # the alignment itself was right


def test_all_headings_on_a_near_symmetric_building_never_match_wrongly(overlapping):
    """±π: the building turned round (x → 24 − x) lines up more wall than the truth (its
    outer walls and a partition); only the inner walls disagree. Found correctly or
    rejected, never accepted wrong."""
    reference, query = overlapping
    for offset in ([1.2, -0.9, math.radians(15.0)], [2.5, -2.5, 2.5]):
        guess = compose(TRUE, np.array(offset))
        match = match_submaps(reference, query, guess, GUESS_COV, 5.0, math.pi, CONFIG)
        if match.ok:
            dist, turn = _error(match, TRUE)
            assert dist < 0.03 and turn < math.radians(1.0), match
        else:
            assert match.reason in ("incompatible", "poor_inlier_fraction", "ambiguous"), match


def test_featureless_corridor_is_rejected():
    corridor = [_polyline((0, 0), (40, 0)), _polyline((0, 2.2), (40, 2.2))]
    ref_frame, query_frame = np.array([0.0, 1.0, 0.0]), np.array([12.0, 1.2, 0.05])
    reference = _shape(corridor, 0, 22, ref_frame)
    query = _shape(corridor, 9, 30, query_frame)
    truth = between(ref_frame, query_frame)
    guess = compose(truth, np.array([1.5, 0.2, math.radians(5.0)]))
    match = match_submaps(reference, query, guess, GUESS_COV, 3.0, math.radians(30.0), CONFIG)
    assert not match.ok and match.reason in ("degenerate", "ambiguous"), match


@pytest.mark.parametrize("slides", [False, True])
def test_repetitive_rooms_never_match_wrongly(slides):
    """Two identical rooms side by side; the query sees the second one only; the guess is
    halfway between the two alignments: rejected as ambiguous, or matched correctly — with
    ``loop_slides`` too: the two copies are not joined by a ridge (the wall between the rooms
    lies between them)."""
    room = [_polyline((0, 0), (6, 0), (6, 5)), _polyline((6, 5), (0, 5), (0, 2.5)), _polyline((0, 1.5), (0, 0.2)),
            _polyline((2, 3), (3.5, 3))]
    rooms = room + [w + np.array([7.0, 0.0]) for w in room]
    ref_frame, query_frame = np.array([0.0, 0.0, 0.0]), np.array([9.0, 2.0, 0.4])
    reference = _shape(rooms, -1, 14, ref_frame)
    query = _shape(rooms, 6.5, 14, query_frame)
    truth = between(ref_frame, query_frame)
    wrong = compose(np.array([-7.0, 0.0, 0.0]), truth)                      # the same room, the other copy
    guess = 0.5 * (truth + wrong)
    match = match_submaps(reference, query, guess, GUESS_COV, 4.0, math.radians(20.0),
                          dataclasses.replace(CONFIG, loop_slides=slides))
    assert not match.slide
    if match.ok:
        dist, turn = _error(match, truth)
        assert dist < 0.05 and turn < math.radians(1.0), match
    else:
        assert match.reason == "ambiguous", match
    assert match.ambiguity > 0.9
    # The runner-up is the other copy: 7 m away along x in the reference frame.
    found = {tuple(np.round(p[:2] - truth[:2])) for p in (match.relative, match.alternative)}
    assert found == {(0.0, 0.0), (-7.0, 0.0)}, (match.relative, match.alternative)


def _wall_field(points: np.ndarray) -> ReferenceMap:
    shape = SubmapShape.from_curves([fit_curve(points, 3, 0.5).curve], SPACING)
    cfg = matcher_config(3.0, math.radians(20.0), CONFIG)
    return ReferenceMap(shape.points, cfg, normals=shape.normals, linear=np.abs(shape.curvature) < 1.0)


def test_a_slide_along_a_wall_is_a_ridge_and_two_copies_are_not():
    """``on_ridge``: a query on a long straight wall slid 1.5 m along it scores as well all
    the way (one answer); two posts 3 m apart, the query one post, do not (the score falls
    between the copies)."""
    wall = _wall_field(_polyline((0.0, 0.0), (30.0, 0.0)))
    query = _polyline((10.0, 0.0), (16.0, 0.0))[::5]
    pose = np.zeros(3)
    best = float(wall.fine.score_poses(query, pose[None, :], np.zeros((1, 2), dtype=np.intp))[0, 0])
    assert on_ridge(wall, query, pose, np.array([1.5, 0.0, 0.0]), 0.9 * best)
    # off the wall's line by 0.3 m the points leave the wall's likelihood: no ridge to there
    assert not on_ridge(wall, query, pose, np.array([1.5, 0.3, 0.0]), 0.9 * best)
    posts = np.concatenate([_polyline((x, 0.0), (x + 0.6, 0.0), (x + 0.6, 0.6), (x, 0.6), (x, 0.0)) for x in (10.0, 13.0)])
    field = _wall_field(posts)
    one_post = _polyline((10.0, 0.0), (10.6, 0.0), (10.6, 0.6), (10.0, 0.6), (10.0, 0.0))[::3]
    best = float(field.fine.score_poses(one_post, pose[None, :], np.zeros((1, 2), dtype=np.intp))[0, 0])
    copy = float(field.fine.score_poses(one_post, np.array([[3.0, 0.0, 0.0]]), np.zeros((1, 2), dtype=np.intp))[0, 0])
    assert copy > 0.9 * best                      # the other post is as good a match …
    assert not on_ridge(field, one_post, pose, np.array([3.0, 0.0, 0.0]), 0.9 * best)   # … but not the same one
    # a square post turned a quarter about its centre fits itself again, but not on the way
    square = _polyline((-0.4, -0.4), (0.4, -0.4), (0.4, 0.4), (-0.4, 0.4), (-0.4, -0.4))
    field = _wall_field(square)
    best = float(field.fine.score_poses(square[::3], pose[None, :], np.zeros((1, 2), dtype=np.intp))[0, 0])
    turned = np.array([0.0, 0.0, math.pi / 2])
    assert float(field.fine.score_poses(square[::3], turned[None, :], np.zeros((1, 2), dtype=np.intp))[0, 0]) > 0.9 * best
    assert not on_ridge(field, square[::3], pose, turned, 0.9 * best)


def test_a_slide_widens_the_covariance_along_itself_only():
    """``slide_covariance``: σ² u uᵀ along the slide, σ the larger of its length and the
    window; nothing across it."""
    pose, rival = np.array([1.0, 2.0, 0.1]), np.array([1.0 + 2.0 * math.cos(0.3), 2.0 + 2.0 * math.sin(0.3), 0.1])
    added = slide_covariance(pose, rival, 3.0)
    u = np.array([math.cos(0.3), math.sin(0.3), 0.0])
    assert np.allclose(added, 9.0 * np.outer(u, u))
    assert np.allclose(slide_covariance(pose, rival, 1.0), 4.0 * np.outer(u, u))    # the slide longer than the window
    assert np.allclose(added @ np.array([-u[1], u[0], 0.0]), 0.0)
    assert np.allclose(slide_covariance(pose, pose, 3.0), 0.0)


def test_a_rival_the_graph_rules_out_is_held_to_the_looser_ambiguity_bound():
    """Two identical rooms, a guess near the truth: with a graph covariance that rules the
    rival out, the match is held to ``loop_max_ambiguity``; with one that admits it, to
    the stricter ``loop_max_ambiguity_alone``."""
    room = [_polyline((0, 0), (6, 0), (6, 5)), _polyline((6, 5), (0, 5), (0, 2.5)), _polyline((0, 1.5), (0, 0.2)),
            _polyline((2, 3), (3.5, 3))]
    rooms = room + [w + np.array([7.0, 0.0]) for w in room]
    ref_frame, query_frame = np.array([0.0, 0.0, 0.0]), np.array([9.0, 2.0, 0.4])
    reference, query = _shape(rooms, -1, 14, ref_frame), _shape(rooms, 6.5, 14, query_frame)
    truth = between(ref_frame, query_frame)
    tight = np.diag([0.2 ** 2, 0.2 ** 2, math.radians(5.0) ** 2])        # rivals a metre off ruled out
    near_guess = compose(truth, np.array([0.3, -0.2, math.radians(2.0)]))
    loose = dataclasses.replace(CONFIG, loop_max_ambiguity=1.0, loop_max_ambiguity_alone=1.0)
    seen = match_submaps(reference, query, near_guess, tight, 4.0, math.radians(20.0), loose)
    assert seen.ok and np.hypot(*(seen.relative - truth)[:2]) < 0.05, seen
    a = seen.ambiguity
    assert 0.5 < a <= 1.0
    split = dataclasses.replace(CONFIG, loop_max_ambiguity=min(a + 0.01, 1.0), loop_max_ambiguity_alone=a - 0.01)
    told = match_submaps(reference, query, near_guess, tight, 4.0, math.radians(20.0), split)
    assert told.ok, told
    # the same guess with a graph covariance that admits the rival: the stricter bound
    wide = np.diag([5.0 ** 2, 5.0 ** 2, math.radians(10.0) ** 2])
    seen_wide = match_submaps(reference, query, near_guess, wide, 4.0, math.radians(20.0), loose)
    assert seen_wide.ok
    b = seen_wide.ambiguity
    strict = dataclasses.replace(CONFIG, loop_max_ambiguity=1.0, loop_max_ambiguity_alone=b - 0.01)
    alone = match_submaps(reference, query, near_guess, wide, 4.0, math.radians(20.0), strict)
    assert not alone.ok and alone.reason == "ambiguous", alone


@settings(max_examples=8, deadline=None)
@given(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0), st.floats(-0.45, 0.45), st.floats(-0.5, 0.5))
def test_random_offsets_within_the_window_are_recovered(overlapping, dx, dy, dphi, frame_turn):
    reference, _ = overlapping
    frame = np.array([14.0, 6.0, frame_turn])
    query = _shape(BUILDING, 7, 25, frame)
    truth = between(REF_FRAME, frame)
    guess = compose(truth, np.array([dx, dy, dphi]))
    match = match_submaps(reference, query, guess, GUESS_COV, 3.0, math.radians(30.0), CONFIG)
    assert match.ok, match
    dist, turn = _error(match, truth)
    assert dist < 0.03 and turn < math.radians(1.0)


@pytest.mark.parametrize("field, value", [("loop_max_window_m", 25.0), ("loop_max_window_m", 20.0),
                                          ("loop_inlier_distance_m", 2.0),
                                          ("loop_search_points", 10), ("loop_min_information_ratio", 1.5),
                                          ("loop_distinct_m", 0.0), ("loop_support_submaps", -1),
                                          ("loop_support_submaps", 2.5), ("loop_max_wall_sigma_m", -0.1)])
def test_config_bounds(field, value):
    """The window is the correlative search's (≤ 18 m: 90 coarse offsets of 0.2 m); the inlier
    gate within the overlap one."""
    with pytest.raises(ConfigError):
        SubmapConfig(**{field: value})


def test_a_window_that_covers_the_drift_finds_the_truth_beside_a_partial_copy():
    """The query sees a room; 8 m from it the reference holds a partial copy of the room
    (two of its walls: a facade seen again), and the drift has put the guess on the copy.
    A window that covers the drift holds both alignments, and the truth, which lays all
    the query's walls on walls, wins; a window too narrow for the drift cannot see the
    truth at all (campus: wrong loop closures 7–14 m off came from 5 m windows)."""
    room = [_polyline((0, 0), (6, 0), (6, 5)), _polyline((6, 5), (0, 5), (0, 2.5)), _polyline((0, 1.5), (0, 0.2)),
            _polyline((2, 3), (3.5, 3), (3.5, 4))]
    copy = [_polyline((8, 0), (14, 0), (14, 5))]                   # the room's first walls, 8 m along x
    ref_frame, query_frame = np.array([0.0, 0.0, 0.0]), np.array([3.0, 2.0, 0.3])
    reference = _shape(room + copy, -1, 15, ref_frame)
    query = _shape(room, -1, 7, query_frame)
    truth = between(ref_frame, query_frame)
    guess = compose(np.array([8.0, 0.0, 0.0]), compose(truth, np.array([0.3, -0.2, math.radians(2.0)])))
    match = match_submaps(reference, query, guess, GUESS_COV, 10.0, math.radians(20.0), CONFIG)
    assert match.ok, match
    dist, turn = _error(match, truth)
    assert dist < 0.03 and turn < math.radians(1.0), match
