"""Segmentation of scans (spec §3): invalid beams, the direction/spacing/gap criteria, and
the invariants of the returned segments, on scans with exact geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scan_cases import cast_scan, on_line, pillar, room_walls

from bsslam.config import SegmentationConfig
from bsslam.errors import InputError
from bsslam.scan import LaserScan, beams_to_points, segment_points, segment_points_counted, valid_beams
from bsslam.sim.geometry import Arc, Segment

CFG = SegmentationConfig()


def segments_of(scan: LaserScan, config: SegmentationConfig = CFG, **kwargs):
    """(points of the valid beams, segments) of a scan."""
    mask, _ = valid_beams(scan, config)
    beam_index = np.flatnonzero(mask)
    points = beams_to_points(scan.angles[beam_index], scan.ranges[beam_index])
    return points, segment_points(points, config, beam_index=beam_index, **kwargs)


def polyline(vertices, spacing_m):
    """Points every ``spacing_m`` along a polyline (vertices included once), in order."""
    pieces = []
    for a, b in zip(vertices[:-1], vertices[1:]):
        a, b = np.asarray(a, float), np.asarray(b, float)
        n = round(np.linalg.norm(b - a) / spacing_m)
        pieces.append(a + np.outer(np.arange(n) / n, b - a))
    pieces.append(np.asarray(vertices[-1], float)[None])
    return np.concatenate(pieces)


# --- valid beams ---------------------------------------------------------------------------

def test_valid_beams_counts_each_reason_once():
    ranges = np.array([1.0, np.nan, np.inf, -np.inf, 8.0, 9.0, 0.05, 0.01, -1.0, 2.0])
    scan = LaserScan(0.0, np.linspace(-1, 1, ranges.size), ranges, max_range=8.0)
    mask, counts = valid_beams(scan, SegmentationConfig(min_range_m=0.05))
    assert mask.tolist() == [True, False, False, False, False, False, False, False, False, True]
    assert counts == {"beams": 10, "valid": 2, "nonfinite": 3, "no_return": 2, "too_close": 3}


def test_valid_beams_honours_a_no_return_threshold_below_max_range():
    scan = LaserScan(0.0, np.zeros(4), np.array([4.9, 5.0, 6.0, 81.83]), max_range=81.9)
    mask, counts = valid_beams(scan, SegmentationConfig(no_return_m=5.0))
    assert mask.tolist() == [True, False, False, False]
    assert counts["no_return"] == 3


def test_beams_to_points_matches_polar_coordinates():
    pts = beams_to_points(np.array([0.0, math.pi / 2, -math.pi / 4]), np.array([2.0, 3.0, math.sqrt(2)]))
    np.testing.assert_allclose(pts, [[2, 0], [0, 3], [1, -1]], atol=1e-15)
    with pytest.raises(InputError):
        beams_to_points(np.zeros(3), np.ones(2))


# --- the criteria ---------------------------------------------------------------------------

@pytest.mark.parametrize("distance_m", [0.5, 2.0, 5.0])
@pytest.mark.parametrize("sigma_m", [0.0, 0.005, 0.01])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_straight_wall_is_one_segment(distance_m, sigma_m, seed):
    scan = cast_scan([Segment((distance_m, -10.0), (distance_m, 10.0))], fov_deg=120, max_range=12.0,
                     sigma_m=sigma_m, seed=seed)
    points, segments = segments_of(scan)
    assert len(segments) == 1
    assert segments[0].tolist() == list(range(points.shape[0]))


@pytest.mark.parametrize("window_m", [0.0, 0.2])
@pytest.mark.parametrize("turn_deg, pieces", [(25.0, 1), (35.0, 2), (90.0, 2)])
def test_a_corner_splits_when_it_turns_more_than_alpha_max(window_m, turn_deg, pieces):
    # Two straight runs meeting at the origin; α_max = 30°. With exact, evenly spaced
    # points the turn seen at the corner is exactly the polyline's, for any window.
    turn = math.radians(turn_deg)
    points = polyline([(-1.0, 0.0), (0.0, 0.0), (math.cos(turn), math.sin(turn))], 0.02)
    segments = segment_points(points, CFG, window_m=window_m)
    assert len(segments) == pieces
    assert sum(s.shape[0] for s in segments) == points.shape[0]  # no point lost at a corner
    if pieces == 2:
        corner = int(np.flatnonzero(np.all(points == 0.0, axis=1))[0])
        assert segments[0][-1] in (corner - 1, corner)


@pytest.mark.parametrize("window_m, spacing_m", [(0.0, 0.02), (0.2, 0.1)])
@pytest.mark.parametrize("ratio, pieces", [(1.5, 1), (2.5, 2)])
def test_a_spacing_jump_beyond_eta_splits(window_m, spacing_m, ratio, pieces):
    # Collinear points whose spacing changes by `ratio` after 20 points; η = 2.
    near = np.column_stack((np.arange(20) * spacing_m, np.zeros(20)))
    far = near[-1] + np.column_stack((np.arange(1, 21) * spacing_m * ratio, np.zeros(20)))
    points = np.concatenate((near, far))
    segments = segment_points(points, CFG, window_m=window_m)
    assert len(segments) == pieces
    if pieces == 2:
        assert segments[0].tolist() == list(range(20))


@pytest.mark.parametrize("sigma_m", [0.0, 0.005])
def test_a_room_splits_into_its_walls(sigma_m):
    scan = cast_scan(room_walls(), sigma_m=sigma_m, seed=3)
    points, segments = segments_of(scan)
    assert len(segments) == 3
    walls = [((-1, -2), (3, -2)), ((3, -2), (3, 2)), ((3, 2), (-1, 2))]
    for rows, (a, b) in zip(segments, walls):
        assert np.all(on_line(points[rows], a, b, tol=1e-9 + 4 * sigma_m))
    assert sum(s.shape[0] for s in segments) >= 0.97 * points.shape[0]


def test_a_box_in_front_of_a_wall_splits_at_both_jumps():
    # The box face is 0.3 m in front of the wall: below max_gap_m, so the spacing test
    # (and the direction test) must find both jumps.
    walls = [Segment((3.0, -4.0), (3.0, 4.0)), Segment((2.7, -0.5), (2.7, 0.5))]
    points, segments = segments_of(cast_scan(walls, fov_deg=120, sigma_m=0.005, seed=1))
    assert len(segments) == 3
    for rows, x in zip(segments, (3.0, 2.7, 3.0)):
        assert np.all(np.abs(points[rows, 0] - x) < 0.03)


def test_a_doorway_without_returns_splits_but_dropouts_do_not():
    wall = [Segment((2.0, -6.0), (2.0, -0.6)), Segment((2.0, 0.6), (2.0, 6.0))]
    scan = cast_scan(wall, fov_deg=140, max_range=8.0)
    assert np.isinf(scan.ranges[70])  # beams through the 1.2 m doorway hit nothing
    _, segments = segments_of(scan)
    assert len(segments) == 2
    # Single missing beams on one wall: the beam steps keep the spacing test quiet.
    ranges = cast_scan([Segment((2.0, -6.0), (2.0, 6.0))], fov_deg=140).ranges.copy()
    ranges[[40, 60, 61, 95]] = np.nan
    points, segments = segments_of(LaserScan(0.0, scan.angles, ranges, 8.0))
    assert len(segments) == 1 and segments[0].shape[0] == points.shape[0]


def test_isolated_points_and_small_objects_are_dropped():
    walls = [pillar((1.5 + 0.4 * k, -1.5 + 0.75 * k), 0.02) for k in range(5)]
    walls.append(Segment((4.0, -0.3), (4.0, -0.2)))  # 10 cm of wall: too short
    scan = cast_scan(walls, step_deg=0.5)
    mask, _ = valid_beams(scan, CFG)
    assert 5 <= np.count_nonzero(mask) < 40
    points, segments = segments_of(scan)
    _, counts = segment_points_counted(points, CFG)
    assert segments == []
    assert counts["rejected_segments"] >= 6


@pytest.mark.parametrize("radius_m", [1.0, 2.0, 3.0])
@pytest.mark.parametrize("seed", [0, 1])
def test_smooth_curved_walls_are_not_split(radius_m, seed):
    # Inside a round room (concave), off-centre, and in front of a round pillar (convex).
    for walls, origin in (([Arc((0.3 * radius_m, 0.0), radius_m, 0.0, 2 * np.pi)], (0.0, 0.0)),
                          ([pillar((radius_m + 0.8, 0.0), radius_m)], (0.0, 0.0))):
        scan = cast_scan(walls, origin=origin, sigma_m=0.005, seed=seed)
        points, segments = segments_of(scan)
        assert len(segments) == 1
        # At most the grazing beams next to a convex wall's tangents (points far apart) go.
        assert segments[0].shape[0] >= 0.95 * points.shape[0]


def test_empty_and_tiny_inputs():
    assert segment_points(np.empty((0, 2)), CFG) == []
    segs = segment_points(np.array([[1.0, 0.0], [1.0, 0.1]]), SegmentationConfig(min_points=2, min_length_m=0))
    assert [s.tolist() for s in segs] == [[0, 1]]
    with pytest.raises(InputError):
        segment_points(np.zeros((3, 3)), CFG)
    with pytest.raises(InputError):
        segment_points(np.zeros((3, 2)), CFG, beam_index=np.array([0, 2, 2]))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 150), st.sampled_from([0.0, 0.1, 0.2, 0.5]))
def test_segments_are_ordered_disjoint_runs_that_meet_the_limits(seed, m, window_m):
    rng = np.random.default_rng(seed)
    # Random walks mixing smooth stretches, corners and jumps.
    steps = rng.normal(0.0, 1.0, (m, 2)) * rng.choice([0.01, 0.05, 0.6], size=(m, 1))
    points = np.cumsum(steps, axis=0) + np.array([2.0, 0.0])
    segments, counts = segment_points_counted(points, CFG, window_m=window_m)
    assert counts["segments"] == len(segments)
    last = -1
    for rows in segments:
        assert rows[0] > last and np.all(np.diff(rows) == 1)
        last = rows[-1]
        edges = np.linalg.norm(np.diff(points[rows], axis=0), axis=1)
        assert rows.shape[0] >= CFG.min_points
        assert edges.sum() >= CFG.min_length_m
        assert np.all(edges <= CFG.max_gap_m)


@settings(max_examples=60, deadline=None)
@given(m=st.integers(1, 60), t=st.integers(0, 30), seed=st.integers(0, 2**32 - 1))
def test_window_max_is_the_maximum_of_each_window(m, t, seed):
    from segment_oracle import _window_max

    rng = np.random.default_rng(seed)
    values = rng.uniform(0.0, 3.0, m)
    lo = rng.integers(0, m, t)
    hi = np.minimum(lo + rng.integers(0, 12, t), m - 1)
    want = np.array([values[a:b + 1].max() for a, b in zip(lo, hi)])
    np.testing.assert_array_equal(_window_max(values, lo, hi), want.reshape(t))


def _scan_like(rng, m):
    """(m, 2) points of a noisy scan: straight pieces turning at random corners, with
    jumps, repeated points and dense stretches; and (m,) increasing beam numbers with
    dropped beams."""
    turn = np.where(rng.random(m) < 0.06, rng.uniform(-2.0, 2.0, m), rng.normal(0.0, 0.02, m))
    heading = np.cumsum(turn)
    step = rng.exponential(0.02, m) * np.where(rng.random(m) < 0.04, 40.0, 1.0)
    step[rng.random(m) < 0.03] = 0.0
    pts = np.cumsum(step[:, None] * np.column_stack([np.cos(heading), np.sin(heading)]), axis=0)
    pts += rng.normal(0.0, 0.005, (m, 2))
    beams = np.cumsum(1 + (rng.random(m) < 0.1) * rng.integers(1, 5, m))
    return pts, beams


@settings(max_examples=150, deadline=None)
@given(m=st.integers(0, 400), window_m=st.sampled_from([0.0, 0.05, 0.2, 0.5]), beams=st.booleans(),
       seed=st.integers(0, 2**32 - 1))
def test_compiled_segmentation_is_the_numpy_segmentation(m, window_m, beams, seed):
    """The compiled shape tests (scan.segment_kernels) give the numpy form's runs and counts
    (the oracle), bit for bit: the same operations in the same order."""
    from segment_oracle import numpy_segment_bounds_counted

    from bsslam.scan.segment import segment_bounds_counted

    pts, beam_index = _scan_like(np.random.default_rng(seed), m)
    beam_index = beam_index if beams else None
    got = segment_bounds_counted(pts, CFG, beam_index=beam_index, window_m=window_m)
    want = numpy_segment_bounds_counted(pts, CFG, beam_index=beam_index, window_m=window_m)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert got[2] == want[2]


@settings(max_examples=100, deadline=None)
@given(n=st.integers(0, 200), no_return=st.sampled_from([None, 3.0, 10.0]), seed=st.integers(0, 2**32 - 1))
def test_compiled_beam_validity_is_the_numpy_one(n, no_return, seed):
    """valid_beams' compiled loop gives the numpy form's mask and counts (the oracle), with
    NaN, ±inf, negative ranges and ranges exactly at the thresholds."""
    from segment_oracle import numpy_valid_beams

    rng = np.random.default_rng(seed)
    config = SegmentationConfig(no_return_m=no_return)
    special = np.array([np.nan, np.inf, -np.inf, -1.0, 0.0, config.min_range_m, 3.0, 10.0, 20.0])
    ranges = np.where(rng.random(n) < 0.3, rng.choice(special, n), rng.uniform(-1.0, 25.0, n))
    scan = LaserScan(stamp=0.0, angles=np.linspace(-1.5, 1.5, n), ranges=ranges, max_range=20.0)
    mask, counts = valid_beams(scan, config)
    want_mask, want_counts = numpy_valid_beams(ranges, 20.0 if no_return is None else min(20.0, no_return),
                                               config.min_range_m)
    np.testing.assert_array_equal(mask, want_mask)
    assert counts == want_counts
