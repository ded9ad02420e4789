"""Basis functions against scipy.interpolate.BSpline and their defining properties."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import BSpline
from basis_oracle import _basis_triangle, _derivatives_from_triangle
from spline_cases import domain_samples, knot_vectors

from bsslam.spline import basis_functions, clamped_knots, collocation_matrix, find_span

SETTINGS = settings(max_examples=60, deadline=None)


def _scipy_all_basis(knots, degree, t, nu):
    """(m, n_control): every basis function (or derivative) by scipy, the oracle."""
    n_control = len(knots) - degree - 1
    return BSpline(knots, np.eye(n_control), degree)(t, nu=nu)


def _scale(knots, degree, nu):
    """Typical size of a nu-th basis derivative: 1 / (shortest non-empty span)^nu."""
    gaps = np.diff(knots)
    return (1.0 / gaps[gaps > 0].min()) ** nu


@SETTINGS
@given(case=knot_vectors(), seed=st.integers(0, 2**32 - 1))
def test_values_and_derivatives_equal_scipy(case, seed):
    degree, knots = case
    t = domain_samples(knots, degree, np.random.default_rng(seed))
    for nu in range(degree + 2):
        ours = collocation_matrix(knots, degree, t, nder=nu)
        ref = _scipy_all_basis(knots, degree, t, nu)
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-10 * _scale(knots, degree, nu))


@SETTINGS
@given(case=knot_vectors(), seed=st.integers(0, 2**32 - 1))
def test_partition_of_unity_non_negativity_and_local_support(case, seed):
    degree, knots = case
    t = domain_samples(knots, degree, np.random.default_rng(seed))
    span, values = basis_functions(knots, degree, t, nder=2)
    np.testing.assert_allclose(values[0].sum(axis=1), 1.0, rtol=0, atol=1e-13)
    for k in (1, 2):
        np.testing.assert_allclose(values[k].sum(axis=1), 0.0, rtol=0, atol=1e-10 * _scale(knots, degree, k))
    assert np.all(values[0] >= 0.0)
    # The degree+1 functions reported are the ones whose support holds t ...
    index = span[:, None] - degree + np.arange(degree + 1)
    assert np.all(knots[index] <= t[:, None]) and np.all(t[:, None] <= knots[index + degree + 1])
    # ... and every other basis function vanishes there.
    full = _scipy_all_basis(knots, degree, t, 0)
    np.put_along_axis(full, index, 0.0, axis=1)
    np.testing.assert_allclose(full, 0.0, rtol=0, atol=1e-14)


@SETTINGS
@given(case=knot_vectors())
def test_continuity_at_interior_knots(case):
    """At a knot of multiplicity μ, derivatives 0 … degree−μ agree from both sides."""
    degree, knots = case
    n_control = len(knots) - degree - 1
    lo, hi = knots[degree], knots[n_control]
    for value in np.unique(knots[(knots > lo) & (knots < hi)]):
        mult = int(np.sum(knots == value))
        smooth = degree - mult
        if smooth < 0:
            continue
        left_span = np.searchsorted(knots, value, side="left") - 1
        right_span = np.searchsorted(knots, value, side="right") - 1
        sides = []
        for span in (left_span, right_span):
            s, vals = basis_functions(knots, degree, [value], nder=smooth, span=[span])
            full = np.zeros((smooth + 1, n_control))
            full[:, s[0] - degree : s[0] + 1] = vals[:, 0, :]
            sides.append(full)
        for k in range(smooth + 1):
            np.testing.assert_allclose(sides[0][k], sides[1][k], rtol=0, atol=1e-10 * _scale(knots, degree, k))


@SETTINGS
@given(case=knot_vectors(), seed=st.integers(0, 2**32 - 1))
def test_collocation_matrix_equals_scipy_design_matrix(case, seed):
    degree, knots = case
    t = domain_samples(knots, degree, np.random.default_rng(seed))
    ref = BSpline.design_matrix(t, knots, degree).toarray()
    dense = collocation_matrix(knots, degree, t)
    sparse = collocation_matrix(knots, degree, t, sparse=True)
    assert scipy.sparse.issparse(sparse) and sparse.shape == ref.shape
    np.testing.assert_allclose(dense, ref, rtol=0, atol=1e-13)
    np.testing.assert_allclose(sparse.toarray(), ref, rtol=0, atol=1e-13)


@SETTINGS
@given(case=knot_vectors(), seed=st.integers(0, 2**32 - 1))
def test_values_alone_are_the_triangle_column_bit_for_bit(case, seed):
    """The values-only path (nder = 0) repeats the full triangle's operations exactly."""
    from bsslam.spline.basis import _basis_values

    degree, knots = case
    t = domain_samples(knots, degree, np.random.default_rng(seed))
    span = find_span(knots, degree, t)
    np.testing.assert_array_equal(_basis_values(knots, degree, t, span),
                                  _basis_triangle(knots, degree, t, span)[:, degree])
    np.testing.assert_array_equal(basis_functions(knots, degree, t)[1][0], basis_functions(knots, degree, t, 1)[1][0])


@SETTINGS
@given(case=knot_vectors(), seed=st.integers(0, 2**32 - 1), nder=st.integers(0, 5))
def test_compiled_derivatives_equal_the_whole_array_form_bit_for_bit(case, seed, nder):
    """The compiled A2.3 does the whole-array form's operations in its order, per parameter."""
    degree, knots = case
    t = domain_samples(knots, degree, np.random.default_rng(seed))
    span = find_span(knots, degree, t)
    expected = _derivatives_from_triangle(_basis_triangle(knots, degree, t, span), degree, nder)
    np.testing.assert_array_equal(basis_functions(knots, degree, t, nder, span=span)[1],
                                  expected.transpose(0, 2, 1))


def test_find_span_at_ends_outside_and_repeated_knots():
    knots = np.array([0.0, 0.0, 0.0, 1.0, 2.0, 2.0, 3.0, 3.0, 3.0])  # degree 2, knot 2 doubled
    t = np.array([-5.0, 0.0, 0.5, 1.0, 2.0, 2.5, 3.0, 9.0, np.nan])
    np.testing.assert_array_equal(find_span(knots, 2, t), [2, 2, 2, 3, 5, 5, 5, 5, 5])


def test_parameters_outside_the_domain_are_clamped():
    knots = clamped_knots(2.0, 0.5, 3)
    _, inside = basis_functions(knots, 3, [0.0, 2.0], nder=1)
    _, outside = basis_functions(knots, 3, [-1.0, 7.0], nder=1)
    np.testing.assert_array_equal(inside, outside)


def test_scalar_parameter_and_derivatives_above_the_degree():
    knots = clamped_knots(2.0, 0.5, 2)
    span, values = basis_functions(knots, 2, 0.7, nder=4)
    assert span.shape == (1,) and values.shape == (5, 1, 3)
    np.testing.assert_array_equal(values[3:], 0.0)


def test_two_dimensional_parameters_are_rejected():
    with pytest.raises(ValueError, match="1-D"):
        basis_functions(clamped_knots(2.0, 0.5, 2), 2, np.zeros((2, 2)))
