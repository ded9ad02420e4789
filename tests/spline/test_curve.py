"""BSplineCurve: validation, evaluation against scipy, polynomial pieces, length, transforms."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad
from scipy.interpolate import BSpline
from spline_cases import curves, domain_samples

from bsslam.errors import SplineError
from bsslam.spline import BSplineCurve, clamped_knots
from bsslam.spline.basis import basis_functions

SETTINGS = settings(max_examples=40, deadline=None)


def _dense(curve: BSplineCurve, n: int = 200_001) -> np.ndarray:
    return curve.evaluate(np.linspace(*curve.domain, n))


@SETTINGS
@given(curve=curves(), seed=st.integers(0, 2**32 - 1))
def test_evaluate_and_derivatives_equal_scipy(curve, seed):
    t = domain_samples(curve.knots, curve.degree, np.random.default_rng(seed))
    ref = BSpline(curve.knots, curve.control_points, curve.degree)
    derivs = curve.derivatives(t, curve.degree + 1)
    gaps = np.diff(curve.knots)
    for nu in range(curve.degree + 2):
        atol = 1e-9 * (1.0 / gaps[gaps > 0].min()) ** nu
        np.testing.assert_allclose(derivs[nu], ref(t, nu=nu), rtol=0, atol=atol)
        np.testing.assert_allclose(curve.evaluate(t, der=nu), ref(t, nu=nu), rtol=0, atol=atol)
    np.testing.assert_array_equal(curve(t), curve.evaluate(t))


@SETTINGS
@given(curve=curves(), seed=st.integers(0, 2**32 - 1))
def test_polynomial_pieces_reproduce_the_curve(curve, seed):
    t = domain_samples(curve.knots, curve.degree, np.random.default_rng(seed))
    gaps = np.diff(curve.knots)
    for nu, value in enumerate(curve.pieces.evaluate(t, 2)):
        atol = 1e-9 * (1.0 / gaps[gaps > 0].min()) ** nu
        np.testing.assert_allclose(value, curve.evaluate(t, der=nu), rtol=0, atol=atol)


def test_properties_and_domain():
    knots = np.array([0.0, 0, 0, 0, 1, 2, 2, 2, 2])
    curve = BSplineCurve(np.arange(10.0).reshape(5, 2), knots, 3)
    assert (curve.order, curve.n_control, curve.domain) == (4, 5, (0.0, 2.0))
    # Clamped: the curve starts and ends at the end control points.
    np.testing.assert_allclose(curve.evaluate([0.0, 2.0]), [[0, 1], [8, 9]], atol=1e-14)


def test_constructor_copies_and_freezes_its_arrays():
    control = np.zeros((4, 2))
    curve = BSplineCurve(control, clamped_knots(1.0, 1.0, 3), 3)
    control[0, 0] = 99.0
    assert curve.control_points[0, 0] == 0.0
    with pytest.raises(ValueError):
        curve.control_points[0, 0] = 1.0


@pytest.mark.parametrize(
    ("control", "knots", "degree", "match"),
    [
        (np.zeros((4, 3)), clamped_knots(1.0, 1.0, 3), 3, r"shape \(m, 2\)"),
        (np.zeros((5, 2)), clamped_knots(1.0, 1.0, 3), 3, "need 4 control points, got 5"),
        (np.zeros((4, 2)), [0, 0, 0, 0, 1, 1, 0.5, 1], 3, "non-decreasing"),
        (np.zeros((4, 2)), [0, 0, 0, 0, 1, 1, 1, np.inf], 3, "finite"),
        (np.full((4, 2), np.nan), clamped_knots(1.0, 1.0, 3), 3, "finite"),
        (np.zeros((4, 2)), clamped_knots(1.0, 1.0, 3), 0, "degree"),
        (np.zeros((4, 2)), np.zeros(8), 3, "empty parameter domain"),
        (np.zeros((6, 2)), [0, 0, 0, 0, 1, 1, 1, 1, 1, 2], 3, "repeated 5 times"),
        (np.zeros((1, 2)), [0, 0, 1], 1, "at least 4 knots"),
    ],
)
def test_invalid_curves_raise_specific_errors(control, knots, degree, match):
    with pytest.raises(SplineError, match=match):
        BSplineCurve(control, knots, degree)


def test_length_of_a_polyline_is_exact():
    control = np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 10.0], [-1.0, 10.0]])
    knots = np.array([0.0, 0.0, 1.0, 2.0, 5.0, 5.0])  # degree 1: the control polygon itself
    assert BSplineCurve(control, knots, 1).length() == pytest.approx(5.0 + 6.0 + 4.0, rel=1e-14)


@SETTINGS
@given(curve=curves(min_degree=2))
def test_length_matches_adaptive_quadrature(curve):
    speed = BSpline(curve.knots, curve.control_points, curve.degree).derivative()
    breaks = np.unique(curve.knots[curve.degree : curve.n_control + 1])
    # Adaptive quadrature span by span (the speed has kinks at knots of high multiplicity).
    expected = sum(
        quad(lambda t: np.linalg.norm(speed(t)), a, b, epsabs=1e-13, epsrel=1e-13, limit=200)[0]
        for a, b in zip(breaks[:-1], breaks[1:])
    )
    assert curve.length() == pytest.approx(expected, rel=1e-9)


@SETTINGS
@given(curve=curves())
def test_bbox_contains_the_curve(curve):
    pts = _dense(curve, 20_001)
    box = curve.bbox()
    assert np.all(pts >= box[:2] - 1e-12) and np.all(pts <= box[2:] + 1e-12)


@SETTINGS
@given(curve=curves(), angle=st.floats(-4.0, 4.0), shift=st.tuples(st.floats(-50, 50), st.floats(-50, 50)))
def test_rigid_transform_moves_the_curve_the_same_way(curve, angle, shift):
    t = np.linspace(*curve.domain, 101)
    moved = curve.transformed(angle, shift)
    c, s = np.cos(angle), np.sin(angle)
    expected = curve.evaluate(t) @ np.array([[c, -s], [s, c]]).T + np.asarray(shift)
    np.testing.assert_allclose(moved.evaluate(t), expected, rtol=0, atol=1e-11)
    assert moved.knots is curve.knots


def test_with_control_points_keeps_knots_and_degree():
    curve = BSplineCurve(np.zeros((4, 2)), clamped_knots(1.0, 1.0, 3), 3)
    other = curve.with_control_points(np.ones((4, 2)))
    assert other.knots is curve.knots and other.degree == 3
    np.testing.assert_allclose(other.evaluate([0.3]), [[1.0, 1.0]])


def _evaluate_numpy(curve: BSplineCurve, t: np.ndarray) -> np.ndarray:
    """The whole-array form BSplineCurve.evaluate had (the oracle of kernels.curve_points):
    the basis on each parameter's span, then the weighted sum of its control points."""
    span, values = basis_functions(curve.knots, curve.degree, t, 0)
    local = curve.control_points[span[:, None] - curve.degree + np.arange(curve.degree + 1)]
    return np.einsum("mr,mrd->md", values[0], local)


@settings(max_examples=200, deadline=None)
@given(curve=curves(), seed=st.integers(0, 2**32 - 1))
def test_evaluate_is_the_numpy_form_bit_for_bit(curve, seed):
    """Inside the domain, outside it (clamped), at every knot, at ±inf and NaN."""
    rng = np.random.default_rng(seed)
    lo, hi = curve.domain
    t = np.concatenate([domain_samples(curve.knots, curve.degree, rng), rng.uniform(lo - 2.0, hi + 2.0, 20),
                        curve.knots, [lo, hi, -np.inf, np.inf, np.nan]])
    np.testing.assert_array_equal(curve.evaluate(t), _evaluate_numpy(curve, t))
    np.testing.assert_array_equal(curve.evaluate(float(t[0])), _evaluate_numpy(curve, t[:1]))
