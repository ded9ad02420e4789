"""Batched curve operations against the one-curve functions, on random curves of degrees 1–4
mixed in one batch; the batched ray intersection is the tests' oracle
(``ray_oracle.py``), the form the filter's compiled linearisation is checked against."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from closest_oracle import closest_point
from ray_oracle import basis_at, intersect_rays_batch
from spline_cases import batch_of, corner_between, curves, params_in, wall_curves

from bsslam.errors import SplineError
from bsslam.spline import BSplineCurve, basis_functions, clamped_knots, intersect_rays
from bsslam.spline.batch import closest_points_batch

SETTINGS = settings(max_examples=40, deadline=None)
# Beams within this of the tangent are grazing (the filter drops them): there the global
# search may see two nearby roots differently at rounding level, so they are not compared.
GRAZING_TAN = np.tan(np.radians(87.0))


@SETTINGS
@given(cs=st.lists(curves(), min_size=1, max_size=5), seed=st.integers(0, 2**32 - 1))
def test_evaluate_and_basis_match_each_curve(cs, seed):
    rng = np.random.default_rng(seed)
    batch = batch_of(cs)
    which = rng.integers(0, len(cs), 60)
    t = params_in(cs, which, rng)
    # the domain ends and out-of-domain parameters (clamped) too
    t[:len(cs)] = [cs[c].domain[1] for c in which[:len(cs)]]
    t[len(cs):2 * len(cs)] = [cs[c].domain[0] - 1.0 for c in which[len(cs):2 * len(cs)]]
    got = batch.evaluate(which, t, 2)
    table = batch.table
    piece, u, t_clamped = table.locate(which, t)
    piece_at, beta = basis_at(table, which, t)
    np.testing.assert_array_equal(piece_at, piece)
    for c, curve in enumerate(cs):
        sel = which == c
        if not sel.any():
            continue
        np.testing.assert_allclose(got[:, sel], curve.derivatives(t[sel], 2), rtol=1e-9, atol=1e-9)
        span, values = basis_functions(curve.knots, curve.degree, t_clamped[sel])
        np.testing.assert_allclose(beta[sel][:, : curve.degree + 1], values[0], atol=1e-12)
        np.testing.assert_array_equal(beta[sel][:, curve.degree + 1:], 0.0)
        # each piece's window: the span's control points, padding repeating the last one
        first = table.cp_start[c] + span - curve.degree
        window = table.window[piece[sel]]
        np.testing.assert_array_equal(window[:, : curve.degree + 1], first[:, None] + np.arange(curve.degree + 1))
        assert np.all(window[:, curve.degree:] == window[:, curve.degree:curve.degree + 1])
        assert np.all(table.real[piece[sel]] == (np.arange(table.p + 1) <= curve.degree))


def _compare_hits(one, batched):
    clear = ~(np.abs(one.r) > GRAZING_TAN) & ~(np.abs(batched.r) > GRAZING_TAN)
    np.testing.assert_array_equal(one.hit[clear], batched.hit[clear])
    both = clear & one.hit
    np.testing.assert_allclose(batched.range[both], one.range[both], rtol=0, atol=1e-9)
    np.testing.assert_allclose(batched.t[both], one.t[both], rtol=0, atol=1e-7)
    np.testing.assert_allclose(batched.r[both], one.r[both], rtol=1e-6, atol=1e-9)


@SETTINGS
@given(cs=st.lists(wall_curves(), min_size=1, max_size=4), seed=st.integers(0, 2**32 - 1),
       max_range=st.sampled_from([np.inf, 6.0]))
def test_ray_intersection_matches_each_curve(cs, seed, max_range):
    rng = np.random.default_rng(seed)
    batch = batch_of(cs)
    origin = rng.uniform(-4.0, 4.0, 2)
    which = rng.integers(0, len(cs), 80)
    angles = rng.uniform(-np.pi, np.pi, 80)
    guess = params_in(cs, which, rng)
    guess[::5] = np.nan  # no guess: the global search
    for t0 in (None, guess):
        hits = intersect_rays_batch(batch, which, origin, angles, t0=t0, max_range=max_range)
        for c, curve in enumerate(cs):
            sel = which == c
            if sel.any():
                one = intersect_rays(curve, origin, angles[sel], t0=None if t0 is None else t0[sel],
                                     max_range=max_range)
                _compare_hits(one, _take(hits, sel))


def _take(hits, sel):
    return type(hits)(t=hits.t[sel], range=hits.range[sel], r=hits.r[sel], hit=hits.hit[sel])


@SETTINGS
@given(cs=st.lists(curves(), min_size=1, max_size=5), seed=st.integers(0, 2**32 - 1))
def test_closest_points_match_each_curve(cs, seed):
    rng = np.random.default_rng(seed)
    batch = batch_of(cs)
    which = rng.integers(0, len(cs), 40)
    queries = rng.uniform(-8.0, 8.0, (40, 2))
    guess = params_in(cs, which, rng)
    guess[::3] = np.nan
    for t0 in (None, guess):
        t, points, distance = closest_points_batch(batch, which, queries, t0=t0)
        np.testing.assert_allclose(points, batch.evaluate(which, t)[0], atol=1e-12)
        for c, curve in enumerate(cs):
            sel = which == c
            if sel.any():
                t_one, p_one, d_one = closest_point(curve, queries[sel], t0=None if t0 is None else t0[sel])
                # equal to rounding; at a corner (knot of multiplicity ≥ degree), or with one
                # between the start and the result, Newton need not converge, and its best
                # iterate then differs by up to the step size (seed 1, degree 4: 2e-6 m)
                start = np.full(t_one.shape, np.nan) if t0 is None else t0[sel]
                smooth = ~(corner_between(curve, start, t[sel]) | corner_between(curve, start, t_one))
                np.testing.assert_allclose(distance[sel][smooth], d_one[smooth], rtol=0, atol=1e-6)
                lo, hi = curve.domain
                assert np.all((t[sel] >= lo) & (t[sel] <= hi))


def test_bad_inputs_raise():
    curve = BSplineCurve(np.array([[0.0, 0.0], [1.0, 0.5], [2.0, 0.0], [3.0, 1.0]]), clamped_knots(3.0, 3.0, 3), 3)
    batch = batch_of([curve])
    with pytest.raises(SplineError):
        batch.table.with_control_points(np.zeros((3, 2)))
    with pytest.raises(SplineError):
        intersect_rays_batch(batch, np.zeros(2, dtype=int), np.zeros(2), np.zeros(3))
    with pytest.raises(SplineError):
        closest_points_batch(batch, np.zeros(1, dtype=int), np.zeros((2, 2)))


def test_degenerate_newton_steps_match_each_curve():
    """Divisions by zero inside the compiled Newton loops behave as numpy's (±inf, NaN),
    not as Python's ZeroDivisionError: a ray along a straight curve (ỹ' = 0 at every t),
    and closest points on a curve collapsed to one point (s' = 0, f/f' = 0/0)."""
    line = BSplineCurve(np.array([[0.0, 1.0], [2.0, 1.0], [4.0, 1.0]]), clamped_knots(4.0, 2.0, 1), 1)
    dot = BSplineCurve(np.tile([[1.0, -2.0]], (4, 1)), clamped_knots(3.0, 3.0, 3), 3)
    batch = batch_of([line, dot])
    origins, angles, guess = np.array([-1.0, 1.0]), np.array([0.0, np.pi]), np.array([1.0, 3.0])
    hits = intersect_rays_batch(batch, np.zeros(2, dtype=int), origins, angles, t0=guess)
    one = intersect_rays(line, origins, angles, t0=guess)
    _compare_hits(one, hits)
    queries = np.array([[0.0, 0.0], [5.0, 5.0]])
    t, points, distance = closest_points_batch(batch, np.ones(2, dtype=int), queries, t0=np.array([0.5, 2.0]))
    np.testing.assert_array_equal(points, [[1.0, -2.0], [1.0, -2.0]])
    np.testing.assert_allclose(distance, np.linalg.norm(queries - [1.0, -2.0], axis=1), rtol=1e-15)
    t_one, _, d_one = closest_point(dot, queries, t0=np.array([0.5, 2.0]))
    np.testing.assert_array_equal(t, t_one)
