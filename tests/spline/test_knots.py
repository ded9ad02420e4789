"""Knot vectors: span counts, clamping, uniform knots and their errors."""

from __future__ import annotations

import numpy as np
import pytest

from bsslam.errors import SplineError
from bsslam.spline import clamped_knots, knot_domain, n_control_points, uniform_knots


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
@pytest.mark.parametrize(("length", "spacing", "spans"), [(3.0, 1.0, 3), (3.05, 1.0, 4), (0.2, 1.0, 1), (0.3, 0.1, 3)])
def test_clamped_knots_spans_and_repetition(degree, length, spacing, spans):
    knots = clamped_knots(length, spacing, degree, start=2.5)
    assert knots.shape == (spans + 2 * degree + 1,)
    np.testing.assert_array_equal(knots[: degree + 1], 2.5)
    np.testing.assert_allclose(knots[-degree - 1 :], 2.5 + length, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.diff(knots[degree : -degree]), length / spans, rtol=1e-12)
    assert n_control_points(knots, degree) == spans + degree
    lo, hi = knot_domain(knots, degree)
    assert lo == 2.5 and hi == pytest.approx(2.5 + length, abs=1e-12)


def test_exact_multiple_of_spacing_adds_no_sliver_span():
    # 0.3 / 0.1 is 2.9999999999999996 in floating point; it must still be 3 spans.
    assert clamped_knots(0.7 - 0.4, 0.1, 3).shape == (3 + 7,)


def test_uniform_knots_are_unclamped_and_evenly_spaced():
    knots = uniform_knots(6, 3, spacing=0.5, start=-1.0)
    np.testing.assert_allclose(knots, -1.0 + 0.5 * np.arange(10))
    assert n_control_points(knots, 3) == 6
    assert knot_domain(knots, 3) == (0.5, 2.0)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: clamped_knots(0.0, 1.0, 3), "length"),
        (lambda: clamped_knots(1.0, 0.0, 3), "spacing"),
        (lambda: clamped_knots(1.0, np.nan, 3), "spacing"),
        (lambda: clamped_knots(1.0, 1.0, 0), "degree"),
        (lambda: clamped_knots(1.0, 1.0, 2.5), "degree"),
        (lambda: uniform_knots(3, 3), "n_control"),
        (lambda: uniform_knots(5, 3, spacing=-1.0), "spacing"),
    ],
)
def test_bad_knot_requests_raise_spline_error(call, match):
    with pytest.raises(SplineError, match=match):
        call()
