"""Least-squares fitting against scipy's make_lsq_spline, Φ, and Schoenberg–Whitney."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import BSpline, make_lsq_spline
from spline_cases import wavy_wall

from bsslam.errors import FitError, SplineError
from bsslam.spline import BSplineCurve, chord_length_parameters, clamped_knots, collocation_matrix, fit_curve

SETTINGS = settings(max_examples=40, deadline=None)


def test_chord_length_parameters():
    pts = np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 4.0], [3.0, 5.0]])
    np.testing.assert_allclose(chord_length_parameters(pts, start=2.0), [2.0, 7.0, 7.0, 8.0])


@SETTINGS
@given(
    degree=st.integers(1, 4),
    n=st.integers(12, 200),
    spacing=st.floats(0.3, 5.0),
    noise=st.sampled_from([0.0, 0.01]),
    seed=st.integers(0, 2**32 - 1),
)
def test_fit_equals_make_lsq_spline_and_phi_maps_data_to_control_points(degree, n, spacing, noise, seed):
    pts = wavy_wall(n, np.random.default_rng(seed), noise)
    result = fit_curve(pts, degree, spacing)
    curve = result.curve
    np.testing.assert_allclose(result.params, chord_length_parameters(pts))
    # Same knots as asked for, unless Schoenberg–Whitney forced fewer spans.
    wanted = clamped_knots(result.params[-1], spacing, degree)
    assert curve.n_control <= len(wanted) - degree - 1
    if curve.n_control == len(wanted) - degree - 1:
        np.testing.assert_allclose(curve.knots, wanted, rtol=0, atol=1e-12)
    ref = make_lsq_spline(result.params, pts, curve.knots, degree)
    np.testing.assert_allclose(curve.control_points, ref.c, rtol=0, atol=1e-9)
    np.testing.assert_allclose(result.phi @ pts, curve.control_points, rtol=0, atol=1e-12)
    assert result.phi.shape == (curve.n_control, n)
    # A clamped fit reproduces constants: the rows of Φ sum to one.
    np.testing.assert_allclose(result.phi.sum(axis=1), 1.0, atol=1e-10)


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_data_from_a_spline_in_the_space_are_fitted_exactly(degree):
    rng = np.random.default_rng(degree)
    knots = clamped_knots(6.0, 1.5, degree, start=1.0)
    truth = BSplineCurve(rng.uniform(-3, 3, (len(knots) - degree - 1, 2)), knots, degree)
    params = np.linspace(1.0, 7.0, 50)
    result = fit_curve(truth.evaluate(params), degree, 1.5, params=params)
    np.testing.assert_allclose(result.curve.knots, knots, atol=1e-12)
    np.testing.assert_allclose(result.curve.control_points, truth.control_points, atol=1e-10)


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_gap_in_the_data_reduces_the_number_of_spans(degree):
    x = np.concatenate([np.linspace(0.0, 3.0, 30), np.linspace(7.0, 10.0, 30)])
    pts = np.column_stack([x, 0.1 * x])
    params = x.copy()  # the gap stays a gap in parameter space
    result = fit_curve(pts, degree, 0.5, params=params)
    spans = result.curve.n_control - degree
    assert spans < 20
    # Independent oracle: the chosen knot vector has a full-rank collocation matrix and one
    # more span would make it rank deficient (the gap would hold a whole basis function).
    for s, full_rank in ((spans, True), (spans + 1, False)):
        knots = clamped_knots(10.0, 10.0 / s, degree)
        rank = np.linalg.matrix_rank(collocation_matrix(knots, degree, params))
        assert bool(rank == s + degree) is full_rank
    ref = make_lsq_spline(params, pts, result.curve.knots, degree)
    np.testing.assert_allclose(result.curve.control_points, ref.c, atol=1e-9)


@pytest.mark.parametrize(
    ("points", "degree", "params", "match"),
    [
        (np.zeros((3, 2)) + [[0, 0], [1, 0], [2, 0]], 3, None, "at least 4 points"),
        (np.ones((6, 2)), 2, None, "coincident"),
        (np.array([[0.0, 0], [0, 0], [0, 0], [1, 0], [1, 0]]), 2, None, "Schoenberg"),
    ],
)
def test_impossible_fits_raise_fit_error(points, degree, params, match):
    with pytest.raises(FitError, match=match):
        fit_curve(points, degree, 1.0, params=params)


def test_malformed_input_raises_spline_error():
    with pytest.raises(SplineError, match="non-decreasing"):
        fit_curve(np.zeros((5, 2)), 1, 1.0, params=[0, 1, 3, 2, 4])
    with pytest.raises(SplineError, match="shape"):
        fit_curve(np.zeros((5, 3)), 1, 1.0)
    with pytest.raises(SplineError, match="spacing"):
        fit_curve(wavy_wall(10, np.random.default_rng(0)), 1, -1.0)


def test_fitted_curve_passes_through_end_region_and_follows_the_wall():
    rng = np.random.default_rng(7)
    pts = wavy_wall(300, rng, noise_m=0.005)
    curve = fit_curve(pts, 3, 1.0).curve
    clean = wavy_wall(300, rng)
    dense = BSpline(curve.knots, curve.control_points, 3)(np.linspace(*curve.domain, 5000))
    # Every clean wall point lies within a few noise σ of the fitted curve.
    gaps = np.min(np.linalg.norm(clean[:, None, :] - dense[None, :, :], axis=2), axis=1)
    assert gaps.max() < 0.01


def test_noise_gain_bound_rejects_barely_supported_basis_functions():
    """Points crowded at one end leave the last basis function nearly unsupported: the plain
    fit accepts it with a huge noise gain; with a bound the fit uses fewer spans instead."""
    import numpy as np

    from bsslam.spline import fit_curve

    x = np.concatenate([np.linspace(0.0, 1.0, 40), [1.999]])  # one lonely point at the far end
    pts = np.column_stack([x, np.zeros_like(x)])
    t = x.copy()
    loose = fit_curve(pts, 3, 0.25, params=t)
    gain = np.sqrt((loose.phi ** 2).sum(axis=1)).max()
    assert gain > 10.0
    bounded = fit_curve(pts, 3, 0.25, params=t, max_noise_gain=10.0)
    assert bounded.curve.n_control < loose.curve.n_control
    assert np.sqrt((bounded.phi ** 2).sum(axis=1)).max() <= 10.0


def _clustered_params(rng, m):
    """(m,) sorted chord-length-like parameters with gaps and repeats (m)."""
    steps = rng.exponential(0.05, m - 1) * np.where(rng.random(m - 1) < 0.1, 20.0, 1.0)
    steps[rng.random(m - 1) < 0.05] = 0.0   # repeated parameters
    return np.concatenate([[0.0], np.cumsum(steps)]) + rng.uniform(-1, 1)


@SETTINGS
@given(degree=st.integers(1, 4), m=st.integers(6, 120), spacing=st.floats(0.05, 1.0),
       gain=st.sampled_from([None, 1.5, 3.0, 10.0]), seed=st.integers(0, 2**32 - 1))
def test_candidate_span_counts_keep_every_count_the_one_by_one_search_accepts(degree, m, spacing, gain, seed):
    from bsslam.spline.fit import candidate_span_counts, least_squares_operator, satisfies_schoenberg_whitney
    from bsslam.spline.knots import clamped_knots_with_spans, span_count

    t = _clustered_params(np.random.default_rng(seed), m)
    distinct, mult = np.unique(t, return_counts=True)
    most = min(span_count(float(t[-1] - t[0]), spacing), distinct.shape[0] - degree)
    got = set(candidate_span_counts(t, distinct, mult, degree, most, gain).tolist())
    for spans in range(most, 0, -1):
        knots = clamped_knots_with_spans(float(t[-1] - t[0]), spans, degree, start=float(t[0]))
        knots[-degree - 1:] = t[-1]
        sw = satisfies_schoenberg_whitney(knots, degree, distinct)
        if gain is None:
            assert (spans in got) == sw          # Schoenberg–Whitney decided identically
        elif sw and least_squares_operator(collocation_matrix(knots, degree, t), gain) is not None:
            assert spans in got                  # the screen never drops a count that passes
        elif not sw:
            assert spans not in got


def _fit_by_full_search(points, degree, spacing, t, gain):
    """fit_curve as it was first written (the oracle): screen every span count, then
    factorise the survivors from the most spans down; (n_control, knots, Φ) or None."""
    from bsslam.spline.fit import iter_span_counts, least_squares_operator
    from bsslam.spline.knots import clamped_knots_with_spans, span_count

    distinct, mult = np.unique(t, return_counts=True)
    length = float(t[-1] - t[0])
    most = min(span_count(length, spacing), distinct.shape[0] - degree)
    for spans in iter_span_counts(t, distinct, mult, degree, most, gain):
        knots = clamped_knots_with_spans(length, spans, degree, start=float(t[0]))
        knots[-degree - 1:] = t[-1]
        phi = least_squares_operator(collocation_matrix(knots, degree, t), gain)
        if phi is not None:
            return knots, phi
    return None


@SETTINGS
@given(degree=st.integers(1, 4), m=st.integers(5, 120), spacing=st.floats(0.05, 1.0),
       gain=st.sampled_from([None, 1.5, 3.0, 10.0]), seed=st.integers(0, 2**32 - 1))
def test_fit_curve_chooses_and_solves_as_the_full_search(degree, m, spacing, gain, seed):
    """Deciding the most spans first and searching the rest only if they fail gives the full
    search's span count, knots and Φ, bit for bit (or the same FitError)."""
    rng = np.random.default_rng(seed)
    t = _clustered_params(rng, m)
    pts = rng.normal(size=(m, 2))
    want = _fit_by_full_search(pts, degree, spacing, t, gain)
    if want is None:
        with pytest.raises(FitError):
            fit_curve(pts, degree, spacing, params=t, max_noise_gain=gain)
        return
    got = fit_curve(pts, degree, spacing, params=t, max_noise_gain=gain)
    np.testing.assert_array_equal(got.curve.knots, want[0])
    np.testing.assert_array_equal(got.phi, want[1])
    np.testing.assert_array_equal(got.curve.control_points, want[1] @ pts)


@SETTINGS
@given(m=st.integers(1, 60), seed=st.integers(0, 2**32 - 1))
def test_distinct_sorted_is_unique_of_a_sorted_array(m, seed):
    from bsslam.spline.fit import _distinct_sorted

    t = np.sort(np.round(np.random.default_rng(seed).uniform(0, 3, m), 1))
    got = _distinct_sorted(t)
    want = np.unique(t, return_counts=True, return_inverse=True)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[2])
    np.testing.assert_array_equal(got[2], want[1])


@SETTINGS
@given(degree=st.integers(1, 4), m=st.integers(6, 80), spans=st.integers(1, 12), seed=st.integers(0, 2**32 - 1))
def test_schoenberg_whitney_on_repeated_rows_is_that_on_distinct_parameters(degree, m, spans, seed):
    from bsslam.spline import basis_functions
    from bsslam.spline.fit import (_distinct_sorted, _schoenberg_whitney_dense, _schoenberg_whitney_holds,
                                   satisfies_schoenberg_whitney)
    from bsslam.spline.knots import clamped_knots_with_spans

    t = _clustered_params(np.random.default_rng(seed), m)
    knots = clamped_knots_with_spans(float(t[-1] - t[0]), spans, degree, start=float(t[0]))
    knots[-degree - 1:] = t[-1]
    distinct, _, inverse = _distinct_sorted(t)
    span, values = basis_functions(knots, degree, t)
    got = _schoenberg_whitney_holds(span, values[0], inverse, distinct.shape[0], spans + degree, degree)
    want = satisfies_schoenberg_whitney(knots, degree, distinct)
    assert got == want
    dense = _schoenberg_whitney_dense(collocation_matrix(knots, degree, t), inverse)
    assert dense == want


@SETTINGS
@given(n=st.integers(1, 12), k=st.integers(1, 40), fortran=st.booleans(), seed=st.integers(0, 2**32 - 1))
def test_solve_upper_is_scipy_solve_triangular(n, k, fortran, seed):
    import scipy.linalg

    from bsslam.spline.fit import _solve_upper

    rng = np.random.default_rng(seed)
    r = np.triu(rng.normal(size=(n, n))) + 3.0 * np.eye(n)
    r = np.asfortranarray(r) if fortran else np.ascontiguousarray(r)
    b = rng.normal(size=(k, n)).T          # a transposed view, as Qᵀ is passed
    np.testing.assert_array_equal(_solve_upper(r, b), scipy.linalg.solve_triangular(r, b, check_finite=False))


def test_chord_length_parameters_of_one_point():
    np.testing.assert_array_equal(chord_length_parameters([[1.0, 2.0]], start=0.5), [0.5])


@SETTINGS
@given(n=st.integers(1, 10), extra=st.integers(0, 30), seed=st.integers(0, 2**32 - 1))
def test_qr_reduced_is_numpys_reduced_qr(n, extra, seed):
    """Q and R's upper triangle as numpy's (the same LAPACK routines), square case included,
    and the input left alone."""
    from bsslam.spline.fit import _qr_reduced

    a = np.random.default_rng(seed).normal(size=(n + extra, n))
    before = a.copy()
    q, r = _qr_reduced(a)
    q_ref, r_ref = np.linalg.qr(a)
    np.testing.assert_array_equal(a, before)
    assert q.shape == (n + extra, n) and r.shape == (n, n) and r.flags.c_contiguous
    np.testing.assert_allclose(q, q_ref, rtol=0, atol=1e-13)
    np.testing.assert_allclose(np.triu(r), r_ref, rtol=0, atol=1e-13 * np.abs(r_ref).max())


def test_a_knot_vector_with_an_empty_end_span_is_left_to_the_search():
    """Parameters a few ulps apart far from 0: with many spans the first interior knot
    rounds onto the start and the direct decision declines (None: fit_curve then leaves
    that count to the search); at the finest spacing fit_curve still returns what the full
    search returns."""
    from bsslam.spline.fit import _distinct_sorted, _fit_with_spans

    t = 1.0 + np.arange(8) * np.spacing(1.0)
    pts = np.column_stack([np.arange(8.0), np.sin(np.arange(8.0))])
    distinct, _, _ = _distinct_sorted(t)
    assert _fit_with_spans(pts, t, distinct, 100, 3, None) is None
    want = _fit_by_full_search(pts, 1, float(np.spacing(1.0)) / 4, t, None)
    got = fit_curve(pts, 1, float(np.spacing(1.0)) / 4, params=t)
    np.testing.assert_array_equal(got.curve.knots, want[0])
    np.testing.assert_array_equal(got.phi, want[1])


@SETTINGS
@given(n=st.integers(1, 10), seed=st.integers(0, 2**32 - 1), special=st.sampled_from(["none", "nan", "zero", "tie"]))
def test_rank_test_is_the_numpy_one(n, seed, special):
    """The compiled rank test (fit_kernels.rank_deficient) decides as the numpy form it
    replaced, NaN, zero and near-threshold diagonals included."""
    from bsslam.spline.fit import _RANK_TOLERANCE
    from bsslam.spline.fit_kernels import rank_deficient

    rng = np.random.default_rng(seed)
    r = rng.normal(size=(n, n)) * 10.0 ** rng.integers(-12, 3, size=(n, n))
    i = int(rng.integers(n))
    if special == "nan":
        r[i, i] = np.nan
    elif special == "zero":
        r[i, i] = -0.0 if rng.random() < 0.5 else 0.0
    elif special == "tie" and n > 1:
        j = int(np.abs(r.diagonal()).argmax())
        r[(j + 1) % n, (j + 1) % n] = -_RANK_TOLERANCE * r[j, j]      # exactly at the threshold
    diag = np.abs(r.diagonal())
    assert rank_deficient(r, _RANK_TOLERANCE) == bool(diag.min() <= _RANK_TOLERANCE * diag.max())
    for row in range(n):                          # every position of the smallest entry
        s = r.copy()
        s[row, row] = 1e-300
        d = np.abs(s.diagonal())
        assert rank_deficient(s, _RANK_TOLERANCE) == bool(d.min() <= _RANK_TOLERANCE * d.max())
