"""Closest point on a curve against brute-force dense sampling."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from spline_cases import curves, dense_samples, wall_curves

from bsslam.spline import BSplineCurve, clamped_knots
from bsslam.spline.closest import closest_point

SETTINGS = settings(max_examples=25, deadline=None)


def _brute_force(curve: BSplineCurve, queries: np.ndarray) -> np.ndarray:
    """(q,) distance to the nearest of 50 001 curve samples (≥ the true distance)."""
    _, pts = dense_samples(curve, 50_001)
    return np.sqrt(np.min(np.sum((pts[None, :, :] - queries[:, None, :]) ** 2, axis=2), axis=1))


def _check_against_brute_force(curve, queries):
    t, points, distance = closest_point(curve, queries)
    brute = _brute_force(curve, queries)
    lo, hi = curve.domain
    assert np.all((t >= lo) & (t <= hi))
    np.testing.assert_allclose(points, curve.evaluate(t), rtol=0, atol=1e-12)
    np.testing.assert_allclose(distance, np.hypot(*(points - queries).T), rtol=0, atol=1e-12)
    # Never worse than the dense samples, and not better than they allow.
    assert np.all(distance <= brute + 1e-12)
    assert np.all(brute - distance < 1e-3)


@SETTINGS
@given(curve=wall_curves(), seed=st.integers(0, 2**32 - 1))
def test_wall_curves_match_brute_force(curve, seed):
    rng = np.random.default_rng(seed)
    box = curve.bbox()
    queries = rng.uniform(box[:2] - 3.0, box[2:] + 3.0, size=(30, 2))
    _check_against_brute_force(curve, queries)


@settings(max_examples=25, deadline=None)
@given(curve=curves(), seed=st.integers(0, 2**32 - 1))
def test_random_curves_within_the_documented_bound_and_at_a_stationary_point(curve, seed):
    """Wild random curves (speed varying tenfold along a span) may hide a basin between
    coarse samples: the result is then within sample_step_m (0.1 m) of the brute-force
    distance, and still a genuine local minimum or an end of the curve."""
    queries = np.random.default_rng(seed).uniform(-8.0, 8.0, size=(20, 2))
    t, points, distance = closest_point(curve, queries)
    assert np.all(distance <= _brute_force(curve, queries) + 0.1)
    s, ds = curve.derivatives(t, 1)
    f = np.sum((s - queries) * ds, axis=1)
    lo, hi = curve.domain
    at_end = ((t == lo) & (f >= 0)) | ((t == hi) & (f <= 0))
    interior_knot = np.isin(t, curve.knots)  # a corner of a curve with repeated knots
    scale = np.linalg.norm(ds, axis=1) * np.maximum(distance, 1.0)
    assert np.all(at_end | interior_knot | (np.abs(f) <= 1e-9 * scale))


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_queries_beyond_the_ends_get_the_end_parameters(degree):
    knots = clamped_knots(4.0, 1.0, degree, start=1.0)
    x = np.linspace(0.0, 4.0, len(knots) - degree - 1)
    curve = BSplineCurve(np.column_stack([x, 0.2 * x**2]), knots, degree)
    start, end = curve.evaluate([1.0, 5.0])
    tangent_start, tangent_end = curve.evaluate([1.0, 5.0], der=1)
    queries = np.array([start - 2.0 * tangent_start, end + 2.0 * tangent_end])
    t, points, distance = closest_point(curve, queries)
    np.testing.assert_array_equal(t, [1.0, 5.0])
    np.testing.assert_allclose(points, [start, end], atol=1e-12)
    np.testing.assert_allclose(distance, np.hypot(*(2.0 * np.array([tangent_start, tangent_end])).T), rtol=1e-12)


def test_t0_refines_locally_to_a_stationary_point():
    # A U shape: a query between the arms has a local minimum on each arm.
    knots = clamped_knots(3.0, 1.0, 3)
    control = np.array([[0.0, 4.0], [0.0, 0.0], [1.0, -1.0], [2.0, 0.0], [2.0, 4.0]])
    curve = BSplineCurve(control, knots[:1] + np.concatenate([knots[:4], [1.5], knots[-4:]]), 3)
    query = np.array([[0.8, 3.0]])
    lo, hi = curve.domain
    t_left, _, d_left = closest_point(curve, query, t0=[lo])
    t_right, _, d_right = closest_point(curve, query, t0=[hi])
    s, ds = curve.derivatives(np.concatenate([t_left, t_right]), 1)
    np.testing.assert_allclose(np.sum((s - query) * ds, axis=1), 0.0, atol=1e-10)
    assert t_left[0] < t_right[0]
    t_global, _, d_global = closest_point(curve, query)
    assert d_global[0] == pytest.approx(min(d_left[0], d_right[0]), abs=1e-12)


def test_empty_queries():
    curve = BSplineCurve(np.zeros((4, 2)) + np.arange(4)[:, None], clamped_knots(1.0, 1.0, 3), 3)
    t, points, distance = closest_point(curve, np.zeros((0, 2)))
    assert t.shape == (0,) and points.shape == (0, 2) and distance.shape == (0,)


def test_nan_guesses_fall_back_to_the_global_search():
    curve = BSplineCurve(np.column_stack([np.arange(5.0), np.arange(5.0) ** 2 / 4]), clamped_knots(4.0, 2.0, 3), 3)
    queries = np.array([[1.0, 3.0], [3.5, 0.0], [0.0, -1.0]])
    t_global, _, d_global = closest_point(curve, queries)
    t_mixed, _, d_mixed = closest_point(curve, queries, t0=[np.nan, t_global[1] + 0.1, np.nan])
    np.testing.assert_allclose(t_mixed, t_global, atol=1e-9)
    np.testing.assert_allclose(d_mixed, d_global, atol=1e-12)


def test_closest_point_on_a_huge_curve_costs_bounded_memory():
    """A diverged estimate (control points 1e9 m apart) must not make the sampling explode."""
    from bsslam.spline import BSplineCurve, clamped_knots, closest_point

    cps = np.array([[0.0, 0.0], [1e9, 1.0], [2e9, -1.0], [3e9, 0.0]])
    curve = BSplineCurve(cps, clamped_knots(1.0, 1.0, 3), 3)
    t, pts, dist = closest_point(curve, np.array([[1e9, 5.0]]))
    assert np.isfinite(t).all() and np.isfinite(dist).all()
    # still a local minimum of the distance: the derivative of |s(t) − q|² vanishes or t is an end
    d = curve.evaluate(t, der=1)[0] @ (pts[0] - np.array([1e9, 5.0]))
    assert abs(d) <= 1e-6 * np.linalg.norm(curve.evaluate(t, der=1)[0]) * (dist[0] + 1) or t[0] in curve.domain
