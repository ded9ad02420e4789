"""fit_runs: fit_curve of every run of a point array, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bsslam.errors import FitError
from bsslam.spline import fit_curve
from bsslam.spline.fit import fit_runs

SETTINGS = settings(max_examples=60, deadline=None)


def _walk(rng, m):
    """(m, 2) points of a noisy walk with jumps, stops (repeated points) and dense stretches."""
    steps = rng.normal(size=(m, 2)) * rng.exponential(0.05, (m, 1))
    steps[rng.random(m) < 0.08] *= 30.0
    steps[rng.random(m) < 0.05] = 0.0
    return np.cumsum(steps, axis=0)


@SETTINGS
@given(degree=st.integers(1, 4), m=st.integers(1, 150), cuts=st.integers(0, 6), spacing=st.floats(0.02, 1.0),
       gain=st.sampled_from([None, 1.5, 3.0, 10.0]), seed=st.integers(0, 2**32 - 1))
def test_fit_runs_is_fit_curve_of_each_run(degree, m, cuts, spacing, gain, seed):
    rng = np.random.default_rng(seed)
    pts = _walk(rng, m)
    bounds = np.unique(np.concatenate([[0, m], rng.integers(0, m + 1, cuts)]))
    # runs between the bounds, some skipped (as segments rejected between kept ones)
    starts, ends = bounds[:-1], bounds[1:] - 1
    keep = rng.random(starts.shape[0]) < 0.8
    starts, ends = starts[keep], ends[keep]
    got = fit_runs(pts, starts, ends, degree, spacing, max_noise_gain=gain)
    assert len(got) == starts.shape[0]
    for s, e, fit in zip(starts, ends, got):
        try:
            want = fit_curve(pts[s:e + 1], degree, spacing, max_noise_gain=gain)
        except FitError:
            assert fit is None
            continue
        assert fit is not None
        np.testing.assert_array_equal(fit.curve.knots, want.curve.knots)
        np.testing.assert_array_equal(fit.curve.control_points, want.curve.control_points)
        np.testing.assert_array_equal(fit.phi, want.phi)
        np.testing.assert_array_equal(fit.params, want.params)
        assert fit.curve.degree == want.curve.degree


def test_fit_runs_of_no_runs():
    assert fit_runs(np.zeros((3, 2)), np.zeros(0, dtype=int), np.zeros(0, dtype=int), 3, 0.2) == []


def test_fit_runs_rejects_bad_spacing_as_fit_curve():
    pts = np.column_stack([np.linspace(0, 1, 10), np.zeros(10)])
    with pytest.raises(Exception) as want:
        fit_curve(pts, 3, -1.0)
    with pytest.raises(type(want.value)):
        fit_runs(pts, np.array([0]), np.array([9]), 3, -1.0)
