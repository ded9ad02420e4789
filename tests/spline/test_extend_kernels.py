"""The compiled extension (bsslam.spline.extend_kernels) against its numpy form, kept in
``extend_oracle``: bit for bit, on random curves, data and knot vectors."""

from __future__ import annotations

import extend_oracle
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from spline_cases import curves, knot_vectors

from bsslam.errors import FitError
from bsslam.spline import collocation_matrix
from bsslam.spline import extend_kernels as kern
from bsslam.spline.extend import extend_curve
from bsslam.spline.fit import satisfies_schoenberg_whitney

SETTINGS = settings(max_examples=200, deadline=None)
SIDES = ("left", "right")


def _same(a, b):
    """Bit for bit, and the same memory layout (it decides how BLAS multiplies)."""
    assert a.shape == b.shape
    assert a.flags.c_contiguous == b.flags.c_contiguous and a.flags.f_contiguous == b.flags.f_contiguous
    np.testing.assert_array_equal(a.view(np.uint64), b.view(np.uint64))


def _data(curve, side, rng, k, gap, spread):
    """k data parameters beyond ``side`` (sorted, some repeated) and points near the curve's end."""
    lo, hi = curve.domain
    steps = np.sort(rng.uniform(0.0, spread, k))
    steps[rng.random(k) < 0.1] = steps[0]  # repeated parameters
    t = np.sort(hi + gap + steps) if side == "right" else np.sort(lo - gap - steps)
    end = curve.evaluate(np.array([hi if side == "right" else lo]))[0]
    pts = end + rng.normal(0.0, spread, (k, 2))
    return t, pts


@SETTINGS
@given(curve=curves(clamped=True), side=st.sampled_from(SIDES), seed=st.integers(0, 2**32 - 1),
       k=st.integers(1, 40), gap=st.floats(1e-3, 1.0), spread=st.floats(0.01, 5.0),
       spacing=st.floats(0.05, 2.0), gain=st.sampled_from([None, 2.5, 1.2]))
def test_extend_curve_matches_the_numpy_form(curve, side, seed, k, gap, spread, spacing, gain):
    rng = np.random.default_rng(seed)
    t, pts = _data(curve, side, rng, k, gap, spread)
    try:
        want = extend_oracle.extend_curve(curve, side, pts, t, spacing, gain)
    except FitError:
        with pytest.raises(FitError):
            extend_curve(curve, side, pts, t, spacing, max_noise_gain=gain)
        return
    got = extend_curve(curve, side, pts, t, spacing, max_noise_gain=gain)
    _same(got.curve.knots, want[0].knots)
    _same(got.curve.control_points, want[0].control_points)
    _same(got.psi, want[1])
    assert got.n_added == want[2]
    _same(got.T, want[3])


@SETTINGS
@given(curve=curves(clamped=True), side=st.sampled_from(SIDES), end_gap=st.floats(1e-6, 5.0),
       spans=st.integers(1, 8))
def test_extended_knots_and_unclamping_match_the_numpy_form(curve, side, end_gap, spans):
    p, knots = curve.degree, curve.knots
    lo, hi = curve.domain
    right = side == "right"
    end = hi + end_gap if right else lo - end_gap
    ext = kern.extended_knots(knots, p, right, end, spans)
    _same(ext, extend_oracle.extended_knots(knots, p, side, end, spans))
    n_old = curve.n_control
    new = ext[n_old + 1: n_old + p + 1] if right else ext[spans: spans + p]
    assert kern.unclamp_valid(knots, p, right, new)
    u_kernel, u_numpy = np.array(knots), np.array(knots)
    _same(kern.unclamp_transform(u_kernel, p, right, new), extend_oracle.unclamp_transform(u_numpy, p, side, new))
    _same(u_kernel, u_numpy)


@pytest.mark.parametrize(
    ("knots", "right", "new", "valid"),
    [
        (np.array([0, 0, 0, 0, 1, 2, 2, 2, 3.0]), True, [4, 5, 6], False),    # not clamped
        (np.array([0, 0, 0, 0, 1, 2, 2, 2, 2.0]), True, [2.0, 3, 4], False),  # not beyond
        (np.array([0, 0, 0, 0, 1, 2, 2, 2, 2.0]), False, [-3, -2, 0.0], False),
        (np.array([0, 0, 0, 0, 1, 2, 2, 2, 2.0]), True, [5, 4, 6], False),    # decreasing
        (np.array([0, 0, 0, 0, 1, 2, 2, 2, 2.0]), True, [3, np.nan, 6], False),
        (np.array([0, 0, 0, 0, 1, 2, 2, 2, 2.0]), True, [3, 4, 4], True),
        (np.array([0, 0, 0, 0, 1, 2, 2, 2, 2.0]), False, [-3, -3, -1], True),
    ],
)
def test_unclamp_validity_is_unclamps(knots, right, new, valid):
    assert kern.unclamp_valid(knots, 3, right, np.array(new, dtype=float)) == valid


@SETTINGS
@given(kv=knot_vectors(clamped=True), seed=st.integers(0, 2**32 - 1), m=st.integers(1, 30),
       lo_col=st.integers(0, 10), width=st.integers(0, 10))
def test_schoenberg_whitney_and_collocation_match_the_numpy_forms(kv, seed, m, lo_col, width):
    p, knots = kv
    n = knots.shape[0] - p - 1
    rng = np.random.default_rng(seed)
    lo, hi = knots[p], knots[-p - 1]
    # inside the domain, at knots, and outside it (clamped)
    t = np.sort(np.concatenate([rng.uniform(lo - 0.5, hi + 0.5, m), rng.choice(knots, 3)]))
    distinct = np.unique(t)
    c0 = min(lo_col, n - 1)
    c1 = min(c0 + width, n)
    if c1 > c0:
        assert kern.schoenberg_whitney(knots, p, distinct, c0, c1) == \
            satisfies_schoenberg_whitney(knots, p, distinct, slice(c0, c1))
        full = collocation_matrix(knots, p, t)
        inside, outside = kern.split_collocation(knots, p, t, c0, c1)
        cols = np.arange(c0, c1)
        _same(inside, full[:, cols])
        _same(outside, full[:, np.setdiff1d(np.arange(n), cols)])
