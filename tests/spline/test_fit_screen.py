"""The noise-gain screen of fit_curve's span search: a lower bound, never above the exact
squared noise gain of the control point it bounds."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from fit_oracle import _surely_too_noisy
from fit_oracle import _surviving_counts as numpy_surviving_counts
from hypothesis import strategies as st

from bsslam.spline import collocation_matrix
from bsslam.spline.basis import basis_functions
from bsslam.spline.fit import _distinct_sorted, _surviving_counts, iter_span_counts, least_squares_operator
from bsslam.spline.knots import clamped_knots_with_spans, span_count

SETTINGS = settings(max_examples=60, deadline=None)


def _clustered_params(rng, m):
    steps = rng.exponential(0.05, m - 1) * np.where(rng.random(m - 1) < 0.15, 20.0, 1.0)
    steps[rng.random(m - 1) < 0.05] = 0.0
    return np.concatenate([[0.0], np.cumsum(steps)])


@SETTINGS
@given(degree=st.integers(1, 4), m=st.integers(8, 80), spans=st.integers(1, 20), seed=st.integers(0, 2**32 - 1))
def test_screen_never_rejects_below_the_exact_gain(degree, m, spans, seed):
    """(The numpy form of the screen, which the compiled search matches bit for bit: see
    test_compiled_search_is_the_numpy_search.) For every control point alone, the screen rejects a limit only if the exact squared
    gain (A⁻¹)_cc exceeds it: at a limit just below the exact gain it may reject, at a limit
    just above it must not."""
    t = _clustered_params(np.random.default_rng(seed), m)
    distinct, mult, _ = _distinct_sorted(t)
    knots = clamped_knots_with_spans(float(t[-1]), spans, degree)
    knots[-degree - 1:] = t[-1]
    B = collocation_matrix(knots, degree, t)
    n = B.shape[1]
    A = B.T @ B
    if np.linalg.cond(A) > 1e10:
        return
    exact = np.diag(np.linalg.inv(A))
    span, values = basis_functions(knots, degree, distinct)
    cp = span[:, None] - degree + np.arange(degree + 1)
    cp_start = np.array([0, n])
    cp_owner = np.zeros(n, dtype=int)
    for c in range(n):
        gain = np.sqrt(exact[c]) * (1.0 + 1e-9)
        assert not _surely_too_noisy(values[0], cp, mult, cp_start, cp_owner, degree, gain, np.array([c]))[0]


@SETTINGS
@given(degree=st.integers(1, 4), m=st.integers(6, 120), spacing=st.floats(0.02, 1.0),
       gain=st.sampled_from([1.5, 3.0, 10.0]), seed=st.integers(0, 2**32 - 1))
def test_search_keeps_every_count_the_exact_test_accepts(degree, m, spacing, gain, seed):
    """Dense data with sparse stretches (as far walls give): the counts the search drops
    all fail the exact test."""
    t = _clustered_params(np.random.default_rng(seed), m)
    distinct, mult, _ = _distinct_sorted(t)
    most = min(span_count(float(t[-1]), spacing), distinct.shape[0] - degree)
    kept = set(iter_span_counts(t, distinct, mult, degree, most, gain))
    for spans in range(most, 0, -1):
        if spans in kept:
            continue
        knots = clamped_knots_with_spans(float(t[-1]), spans, degree)
        knots[-degree - 1:] = t[-1]
        assert least_squares_operator(collocation_matrix(knots, degree, t), gain) is None


def _runs(rng, sizes, spacing, degree, tiny):
    """Runs of clustered parameters (the first a few ulps apart when ``tiny``: empty spans),
    each with its distinct values, multiplicities and largest span count."""
    runs = []
    for r, m in enumerate(sizes):
        if tiny and r == 0:   # parameters a few ulps apart, far from 0: empty spans
            t = 1.0 + np.arange(m) * np.spacing(1.0)
        else:
            t = _clustered_params(rng, m) + rng.uniform(-1, 1)
        distinct, mult, _ = _distinct_sorted(t)
        length = float(t[-1] - t[0])
        if not length > 0:
            continue
        most = min(span_count(length, spacing if not (tiny and r == 0) else length / 50), distinct.shape[0] - degree)
        if most >= 1:
            runs.append((t, distinct, mult, most))
    return runs


@SETTINGS
@given(degree=st.integers(1, 4), sizes=st.lists(st.integers(6, 60), min_size=1, max_size=5),
       spacing=st.floats(0.01, 0.5), gain=st.sampled_from([None, 1.5, 3.0, 10.0]),
       tiny=st.booleans(), seed=st.integers(0, 2**32 - 1))
def test_several_runs_at_once_give_each_runs_counts(degree, sizes, spacing, gain, tiny, seed):
    """The search over several runs in one pass keeps, for each run, exactly the counts
    its own search keeps (also when a run's knot vectors have empty spans)."""
    runs = _runs(np.random.default_rng(seed), sizes, spacing, degree, tiny)
    if not runs:
        return
    got = _surviving_counts(runs, degree, gain)
    for (t, distinct, mult, most), counts in zip(runs, got):
        assert counts.tolist() == list(iter_span_counts(t, distinct, mult, degree, most, gain))


@SETTINGS
@given(degree=st.integers(1, 4), sizes=st.lists(st.integers(4, 80), min_size=1, max_size=4),
       spacing=st.floats(0.01, 0.5), gain=st.sampled_from([None, 1.2, 1.5, 3.0, 10.0]),
       tiny=st.booleans(), seed=st.integers(0, 2**32 - 1))
def test_compiled_search_is_the_numpy_search(degree, sizes, spacing, gain, tiny, seed):
    """The compiled search (fit_kernels.span_survivors) keeps exactly the counts of its numpy
    form (the oracle), run by run, with repeated parameters and with empty spans: it does the
    same floating-point operations in the same order, so even counts at the screen's limit
    agree."""
    runs = _runs(np.random.default_rng(seed), sizes, spacing, degree, tiny)
    if not runs:
        return
    got = _surviving_counts(runs, degree, gain)
    want = numpy_surviving_counts(runs, degree, gain)
    for g, w in zip(got, want, strict=True):
        assert g.tolist() == w.tolist()


@SETTINGS
@given(degree=st.integers(1, 4), sizes=st.lists(st.integers(4, 80), min_size=1, max_size=3),
       spacing=st.floats(0.01, 0.5), gain=st.sampled_from([None, 1.2, 1.5, 3.0, 10.0]),
       tiny=st.booleans(), seed=st.integers(0, 2**32 - 1))
def test_step_by_step_search_visits_the_numpy_searchs_counts(degree, sizes, spacing, gain, tiny, seed):
    """The lazy search (fit_kernels.next_fit_setup), restarted below each count it returns,
    visits exactly the counts the numpy search keeps whose setup passes Schoenberg–Whitney,
    in order, each with fit_setup's knots and collocation matrix."""
    from bsslam.spline.fit import _SCREEN_FEW_DATA, _SCREEN_HALF_WIDTH, _SCREEN_MARGIN, _SCREEN_SHIFT
    from bsslam.spline.fit_kernels import fit_setup, next_fit_setup

    screen = gain is not None
    limit = gain ** 2 * (1.0 + _SCREEN_MARGIN) if screen else 0.0
    runs = _runs(np.random.default_rng(seed), sizes, spacing, degree, tiny)
    for (t, distinct, mult, most), kept in zip(runs, numpy_surviving_counts(runs, degree, gain) if runs else []):
        want = [int(c) for c in kept if fit_setup(t, distinct, int(c), degree)[0] != 1]
        got = []
        below = most
        while below >= 1:
            spans, status, knots, collocation = next_fit_setup(
                t, distinct, mult, most, below, degree, screen, limit, _SCREEN_FEW_DATA, _SCREEN_HALF_WIDTH,
                1.0 + _SCREEN_SHIFT)
            if spans == 0:
                break
            w_status, w_knots, w_collocation = fit_setup(t, distinct, spans, degree)
            assert status == w_status
            assert np.array_equal(knots, w_knots) and np.array_equal(collocation, w_collocation)
            got.append(spans)
            below = spans - 1
        assert got == want
