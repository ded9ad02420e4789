"""Least-squares fitting of a clamped B-spline to an ordered run of laser points (spec §2).

The control points are a fixed linear map of the data, ``X = Φ D`` with
``Φ = (BᵀB)⁻¹Bᵀ`` (paper (11)); the filter's Jacobians reuse Φ, so it is returned.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.linalg

try:  # numpy ≥ 2: the C function np.einsum calls (without optimize) after its dispatch
    from numpy._core.multiarray import c_einsum as _c_einsum
except ImportError:  # pragma: no cover - numpy 1.26, or a numpy that moved it: the same numbers
    _c_einsum = np.einsum

from bsslam.errors import FitError, SplineError
from bsslam.spline.basis import basis_functions, collocation_matrix
from bsslam.spline.curve import BSplineCurve, as_points
from bsslam.spline.fit_kernels import fit_setup, next_fit_setup, rank_deficient, run_parameters, span_survivors
from bsslam.spline.knots import check_degree, clamped_knots_with_spans, span_count

# Relative size of R's smallest diagonal entry (QR of the collocation matrix) below which
# the least-squares problem counts as singular even though Schoenberg–Whitney holds: data
# that barely touch a basis function's support would give huge, noise-amplifying Φ.
_RANK_TOLERANCE = 1e-10


def chord_length_parameters(points: object, start: float = 0.0) -> np.ndarray:
    """Cumulative chord length of an ordered point run (paper (9)).

    Args:
        points: (m, 2) points (m), m ≥ 1.
        start: parameter of the first point (m).

    Returns:
        (m,) non-decreasing parameters, ``t_0 = start``, ``t_j = start + Σ_{s≤j} |d_s − d_{s−1}|``.
    """
    pts = as_points(points)
    if pts.shape[0] < 1:
        raise SplineError("need at least one point")
    return _chord_lengths(pts, start)


def _chord_lengths(pts: np.ndarray, start: float = 0.0) -> np.ndarray:
    """:func:`chord_length_parameters` of checked (m, 2) float64 points, m ≥ 1."""
    step = pts[1:] - pts[:-1]
    cumulative = np.zeros(pts.shape[0])
    np.cumsum(np.hypot(step[:, 0], step[:, 1]), out=cumulative[1:])
    return start + cumulative


def satisfies_schoenberg_whitney(
    knots: np.ndarray, degree: int, params: np.ndarray, columns: slice = slice(None)
) -> bool:
    """Whether the collocation matrix's ``columns`` have full column rank in exact arithmetic.

    Schoenberg–Whitney: the basis functions can be matched to distinct data parameters in
    order, each inside the support of its function. With sorted data every support holds a
    contiguous run of data ``[first_i, last_i]`` and both ends grow with i, so the greedy
    match (earliest free datum) decides it; it is a running maximum, so no loop is needed.

    Args:
        knots: knot vector.
        degree: polynomial degree p.
        params: (m,) strictly increasing data parameters inside the domain (m).
        columns: which basis functions must be determined by the data.
    """
    span, values = basis_functions(knots, degree, params)
    m = params.shape[0]
    return _schoenberg_whitney_holds(span, values[0], np.arange(m), m, knots.shape[0] - degree - 1, degree,
                                     columns)


def _schoenberg_whitney_holds(span: np.ndarray, beta: np.ndarray, rows: np.ndarray, d: int, n_control: int,
                              degree: int, columns: slice = slice(None)) -> bool:
    """Schoenberg–Whitney decided from basis values already evaluated (the greedy match of
    :func:`satisfies_schoenberg_whitney`).

    Args:
        span: (r,) knot span of each evaluated parameter; beta: (r, degree+1) its basis values.
        rows: (r,) index of each evaluated parameter among the d distinct ones, non-decreasing
            (rows of repeated parameters hold identical values, so they may all be given).
        d: number of distinct parameters; n_control: number of basis functions.
        degree: polynomial degree p; columns: the basis functions that must be determined.
    """
    at_row, at_r = np.nonzero(beta > 0)
    basis = span[at_row] - degree + at_r
    rows = rows[at_row]
    first = np.full(n_control, d)
    last = np.full(n_control, -1)
    np.minimum.at(first, basis, rows)
    np.maximum.at(last, basis, rows)
    first, last = first[columns], last[columns]
    if first.size == 0 or np.any(last < 0):
        return False
    k = np.arange(first.shape[0])
    matched = k + np.maximum.accumulate(first - k)
    return bool(np.all(matched <= last))


def _schoenberg_whitney_dense(collocation: np.ndarray, rows: np.ndarray) -> bool:
    """:func:`_schoenberg_whitney_holds` for all columns of a dense collocation matrix.

    Args:
        collocation: (m, n) basis values at m sorted parameters (zero off each row's span).
        rows: (m,) index of each parameter among the distinct ones, non-decreasing.

    The rows are sorted, so each column's first and last positive row give its first and
    last datum: two argmax calls instead of scattered minima and maxima.
    """
    positive = collocation > 0
    if not positive.any(axis=0).all():
        return False
    m = positive.shape[0]
    first = rows[positive.argmax(axis=0)]
    last = rows[m - 1 - positive[::-1].argmax(axis=0)]
    k = np.arange(first.shape[0])
    return bool(np.all(k + np.maximum.accumulate(first - k) <= last))


def least_squares_operator(collocation: np.ndarray, max_noise_gain: float | None = None) -> np.ndarray | None:
    """``(BᵀB)⁻¹Bᵀ`` for an (m, n) collocation matrix B, by QR; None if B is rank deficient
    or, with ``max_noise_gain``, if some row of the result has a larger 2-norm.

    A row's norm is how much it amplifies independent noise on the data into its control
    point (σ_cp = norm · σ_data). Well-posed fits stay below about 2.5; a basis function
    barely touched by data passes the rank test yet amplifies noise by 10⁶ or more, and such
    a control point would wreck a covariance it enters.
    """
    m, n = collocation.shape
    if m < n:
        return None
    q, r = _qr_reduced(collocation)
    if rank_deficient(r, _RANK_TOLERANCE):
        return None
    phi = _solve_upper(r, q.T)
    # the squared row norms by einsum's own C function (np.einsum without optimize calls
    # it, after a dispatch costing six Python calls a fit), their maximum by the reduction
    # ndarray.max calls
    if max_noise_gain is not None and np.maximum.reduce(_c_einsum("ij,ij->i", phi, phi)) > max_noise_gain ** 2:
        return None
    return phi


def _qr_reduced(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.linalg.qr(a)`` (reduced) of a float64 (m, n) a, m ≥ n: (m, n) Q and C-ordered
    (n, n) R, whose strictly lower triangle is left holding Householder vectors (only the
    upper triangle is ever read). The same Householder LAPACK routines (geqrf, orgqr),
    called directly: numpy's wrapper costs more than the factorisation at fit sizes."""
    qr, tau, _, info = _DGEQRF(a)
    if info != 0:  # pragma: no cover - only for malformed arguments
        raise np.linalg.LinAlgError(f"geqrf failed: info = {info}")
    r = np.array(qr[: a.shape[1]], order="C")  # a copy even when it is all of qr: orgqr overwrites qr
    q, _, info = _DORGQR(qr, tau, overwrite_a=True)
    if info != 0:  # pragma: no cover
        raise np.linalg.LinAlgError(f"orgqr failed: info = {info}")
    return q, r


def _solve_upper(r: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``scipy.linalg.solve_triangular(r, b, check_finite=False)`` for an upper triangular
    float64 (n, n) r and (n, k) b: the same LAPACK call (so the same result) without the
    wrapper's validation, which costs more than the solve at the sizes fits have."""
    if r.flags.f_contiguous:
        x, info = _DTRTRS(r, b, overwrite_b=False, lower=False, trans=0, unitdiag=False)
    else:  # as solve_triangular does: trtrs wants Fortran order, so solve the transpose
        x, info = _DTRTRS(r.T, b, overwrite_b=False, lower=True, trans=1, unitdiag=False)
    if info != 0:  # pragma: no cover - the caller has checked the diagonal
        raise np.linalg.LinAlgError(f"trtrs failed: info = {info}")
    return x


_DTRTRS, _DGEQRF, _DORGQR = scipy.linalg.get_lapack_funcs(("trtrs", "geqrf", "orgqr"), (np.zeros((1, 1)),))


def check_params(params: object, m: int) -> np.ndarray:
    """Data parameters as a finite, non-decreasing float64 (m,) array, or SplineError."""
    t = np.asarray(params, dtype=float)
    if t.shape != (m,):
        raise SplineError(f"params must have shape ({m},), got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise SplineError("params must be finite")
    if np.any(np.diff(t) < 0):
        raise SplineError("params must be non-decreasing (an ordered point run)")
    return t


# Relative margin of the noise-gain screen: it rejects a span count only when its lower bound
# exceeds the limit by more than rounding could explain, so the exact test decides the rest.
_SCREEN_MARGIN = 1e-6


def candidate_span_counts(t: np.ndarray, distinct: np.ndarray, multiplicity: np.ndarray, degree: int,
                          most: int, max_noise_gain: float | None = None) -> np.ndarray:
    """All of :func:`iter_span_counts`, as a (k,) int array."""
    return np.array(list(iter_span_counts(t, distinct, multiplicity, degree, most, max_noise_gain)), dtype=int)


def iter_span_counts(t: np.ndarray, distinct: np.ndarray, multiplicity: np.ndarray, degree: int,
                     most: int, max_noise_gain: float | None = None):
    """The span counts ``most … 1`` (descending) that :func:`fit_curve` must still try.

    For every count at once: the clamped knot vector exactly as ``fit_curve`` builds it;
    Schoenberg–Whitney on the distinct parameters, decided as
    :func:`satisfies_schoenberg_whitney` decides it; and, with ``max_noise_gain``, a lower
    bound of the noise gain of the control points that few data determine. The gain of
    control point i is ``‖Φ_i‖ = sqrt((BᵀB)⁻¹_ii)``; for a principal block M of ``A = BᵀB``
    around i, ``(M⁻¹)_ii ≤ (A⁻¹)_ii`` (conditioning on fewer variables), so a count whose
    bound exceeds the limit cannot pass the exact test (computed by symmetric elimination
    of the block's neighbours: :func:`bsslam.spline.fit_kernels.span_survivors`).

    Schoenberg–Whitney needs no basis evaluation: where the domain knots are strictly
    increasing, basis function i is non-zero exactly at the data strictly inside its
    support (ξ_i, ξ_{i+p+1}) (the first function also at the start, the last at the end),
    so the first and last datum of every support follow from binary searches of the
    knots. Basis values are evaluated only at the data near the control points the screen
    tests (at every datum if some knot vector has an empty span).

    Args:
        t: (m,) the data parameters (m), non-decreasing.
        distinct: (d,) the distinct values of ``t``; multiplicity: (d,) their counts.
        degree: polynomial degree p.
        most: the largest span count (≥ 1 for any candidate).
        max_noise_gain: the limit of :func:`least_squares_operator`, or None.

    Yields:
        int span counts, descending.
    """
    if most < 1:
        return
    yield from (int(c) for c in _surviving_counts([(t, distinct, multiplicity, most)], degree, max_noise_gain)[0])


def _surviving_counts(runs: list[tuple[np.ndarray, np.ndarray, np.ndarray, int]], p: int,
                      max_noise_gain: float | None) -> list[np.ndarray]:
    """:func:`iter_span_counts` of several runs: for each run ``(t, distinct, multiplicity,
    most)`` with most ≥ 1, its surviving span counts, descending, as an int array (one
    compiled loop per run: :func:`bsslam.spline.fit_kernels.span_survivors`)."""
    screen = max_noise_gain is not None
    # the limit as the numpy form computed it (a Python float), so the kernel compares alike
    limit = max_noise_gain ** 2 * (1.0 + _SCREEN_MARGIN) if screen else 0.0
    out = []
    for _, distinct, multiplicity, most in runs:
        keep = span_survivors(distinct, multiplicity, most, p, screen, limit, _SCREEN_FEW_DATA,
                              _SCREEN_HALF_WIDTH, 1.0 + _SCREEN_SHIFT)
        out.append(np.arange(most, 0, -1)[keep])
    return out


# Control points whose support holds fewer distinct data than this are screened for their
# noise gain (the others are left to the exact test). Chosen on recorded simulated-corridor
# and Intel fits: 4, 6 and 8 leave the same number of exact tests (3 a few more), and 4
# tests the fewest control points.
_SCREEN_FEW_DATA = 4

# Half-width h of the principal blocks of the noise-gain screen: the (2h+1)² block of A
# around each tested control point. On recorded simulated-corridor fits (cubic, 0.2 m) the
# 3 × 3 blocks reject 83 % of the span counts the exact test rejects for their noise gain,
# the 5 × 5 ones 97 %, the 7 × 7 ones 99 %; the exact test (a QR) decides the survivors.
_SCREEN_HALF_WIDTH = 2

# Relative diagonal shift of the screen's blocks. Cholesky elimination is backward stable:
# the computed Schur complement is the exact one of M + ΔM, |ΔM| ≤ (a few ε)·sqrt(M_ii M_jj);
# shifting the diagonal by far more than that makes the computed value the exact Schur
# complement of a matrix ⪰ M, whose inverse ⪯ M⁻¹: the bound stays a lower bound.
_SCREEN_SHIFT = 1e-13


@dataclass(frozen=True, eq=False)
class FitResult:
    """A least-squares spline fit.

    Attributes:
        curve: the fitted clamped curve.
        phi: (n_control, m) ``Φ``: ``curve.control_points == phi @ points`` (x and y alike).
        params: (m,) parameter of each data point (m).
    """

    curve: BSplineCurve
    phi: np.ndarray
    params: np.ndarray


def fit_curve(points: object, degree: int, spacing_m: float, params: object = None, *,
              max_noise_gain: float | None = None) -> FitResult:
    """Least-squares clamped B-spline through an ordered point run (spec §2).

    Args:
        points: (m, 2) data points d_j in order along the run (m).
        degree: polynomial degree p (order κ = p + 1).
        spacing_m: target knot spacing ρ (m).
        params: optional (m,) non-decreasing parameters; default chord length from 0.
        max_noise_gain: if given, a number of spans whose Φ amplifies data noise more than
            this (largest row 2-norm) counts as ill-posed, like a Schoenberg–Whitney failure.

    Returns:
        FitResult on ``clamped_knots(params[-1] − params[0], spacing_m, degree,
        start=params[0])``, or on fewer spans if that knot vector violates
        Schoenberg–Whitney (e.g. a gap in the data).

    Raises:
        FitError: fewer distinct parameters than degree + 1, all points at one parameter,
            or no number of spans ≥ 1 gives a well-posed fit.
        SplineError: malformed input (shapes, non-finite values, bad spacing).
    """
    degree = check_degree(degree)
    pts = as_points(points)
    m = pts.shape[0]
    if m < degree + 1:
        raise FitError(f"a degree-{degree} fit needs at least {degree + 1} points, got {m}")
    t = _chord_lengths(pts) if params is None else check_params(params, m)
    length = float(t[-1] - t[0])
    if not length > 0:
        raise FitError("all points share one parameter (coincident points); nothing to fit")
    distinct, multiplicity, _ = _distinct_sorted(t)
    # n_control = spans + degree can never exceed the number of distinct parameters.
    most = min(span_count(length, spacing_m), distinct.shape[0] - degree)
    return _fit_from(pts, t, distinct, multiplicity, degree, most, most, max_noise_gain, _DIRECT_TRIES)


def _fit_from(pts: np.ndarray, t: np.ndarray, distinct: np.ndarray, multiplicity: np.ndarray, degree: int,
              most: int, most_spans: int, max_noise_gain: float | None, tries: int) -> FitResult:
    """:func:`fit_curve` from its span count ``most`` down (``most_spans``: its first
    count, for the message), after its checks: ``tries`` counts decided directly, then the
    search. Arguments as :func:`_fit_with_spans`, plus multiplicity (d,) of the distinct
    parameters."""
    # The most spans that give a well-posed fit win. On real scans the most spans nearly
    # always do (and else one or two fewer), so the first count is decided directly, from
    # one basis evaluation; only if it fails are the remaining counts screened at once
    # (Schoenberg–Whitney and a lower bound of the noise gain) and the survivors
    # factorised, from the most spans down.
    for _ in range(tries):
        if most < 1:
            break
        fit = _fit_with_spans(pts, t, distinct, most, degree, max_noise_gain)
        if isinstance(fit, FitResult):
            return fit
        if fit is not _REJECTED:  # undecided: the search decides this count and the rest
            break
        most -= 1
    fit = _search_fit(pts, t, distinct, multiplicity, degree, most, max_noise_gain) if most >= 1 else None
    if fit is not None:
        return fit
    raise FitError(
        f"no degree-{degree} spline with 1..{max(most_spans, 1)} spans fits these {pts.shape[0]} points "
        "(Schoenberg–Whitney fails: too few distinct points)")


def _search_fit(pts: np.ndarray, t: np.ndarray, distinct: np.ndarray, multiplicity: np.ndarray, degree: int,
                most: int, max_noise_gain: float | None) -> FitResult | None:
    """The fit on the first of the span counts ``most … 1`` that the search keeps
    (:func:`iter_span_counts`) and the exact test accepts, or None. The counts are
    screened one at a time, each with its setup, and none after the accepted one
    (:func:`bsslam.spline.fit_kernels.next_fit_setup`)."""
    screen = max_noise_gain is not None
    # the limit as the numpy form computed it (a Python float), so the kernel compares alike
    limit = max_noise_gain ** 2 * (1.0 + _SCREEN_MARGIN) if screen else 0.0
    below = most
    while below >= 1:
        spans, status, knots, collocation = next_fit_setup(
            t, distinct, multiplicity, most, below, degree, screen, limit, _SCREEN_FEW_DATA, _SCREEN_HALF_WIDTH,
            1.0 + _SCREEN_SHIFT)
        if spans == 0:
            return None
        below = spans - 1
        if status == 2:
            # a knot vector with an empty span: find_span's clamping decides the spans
            knots = clamped_knots_with_spans(float(t[-1] - t[0]), spans, degree, start=float(t[0]))
            knots[-degree - 1 :] = t[-1]  # exactly the last parameter, not start + length
            collocation = collocation_matrix(knots, degree, t)
        phi = least_squares_operator(collocation, max_noise_gain)
        if phi is not None:
            return FitResult(curve=BSplineCurve.unchecked(phi @ pts, knots, degree), phi=phi, params=t)
    return None


def fit_runs(points: np.ndarray, starts: np.ndarray, ends: np.ndarray, degree: int, spacing_m: float, *,
             max_noise_gain: float | None = None) -> list[FitResult | None]:
    """:func:`fit_curve` of each run ``points[starts[i] : ends[i] + 1]`` (default chord-length
    parameters), the same results bit for bit, None where it raises FitError.

    All runs' parameters come from one compiled loop; each run's knot vector,
    Schoenberg–Whitney test and collocation matrix at the most spans from another
    (:func:`bsslam.spline.fit_kernels.fit_setup`), then one factorisation. The runs whose
    most spans fail go through :func:`fit_curve`'s search from one fewer; unusual runs (repeated
    parameters, an empty knot span, too few points) through fit_curve itself.

    Args:
        points: (M, 2) float64 points (m), the runs consecutive slices of them.
        starts, ends: (S,) first and last row of each run (inclusive), ends ≥ starts.
        degree, spacing_m, max_noise_gain: as in :func:`fit_curve`.

    Returns:
        S fit results, in run order.
    """
    p = check_degree(degree)
    starts = np.asarray(starts, dtype=np.intp)
    ends = np.asarray(ends, dtype=np.intp)
    S = starts.shape[0]
    if S == 0:
        return []
    pts_all = as_points(points)
    sizes = ends - starts + 1
    # chord lengths of every run, each run's running sum alone (the sums of _chord_lengths)
    step = pts_all[1:] - pts_all[:-1]
    t_all, distinct = run_parameters(np.hypot(step[:, 0], step[:, 1]), starts, sizes)
    results: list[FitResult | None] = [None] * S
    failed = []
    a = 0
    for i in range(S):
        m = int(sizes[i])
        b = a + m
        pts = pts_all[starts[i]: starts[i] + m]
        t_run = t_all[a:b].copy()                      # each fit owns its parameters
        a = b
        # usual runs: enough points, distinct parameters (strictly increasing), most ≥ 1
        length = float(t_run[-1])
        most = min(span_count(length, spacing_m), m - p) if distinct[i] and m >= p + 1 and length > 0 else 0
        if most < 1:
            results[i] = _fit_or_none(pts, p, spacing_m, max_noise_gain)
            continue
        fit = _fit_with_spans(pts, t_run, t_run, most, p, max_noise_gain)
        if isinstance(fit, FitResult):
            results[i] = fit
        elif fit is None:  # an empty span: fit_curve leaves such a count to its search
            results[i] = _fit_or_none(pts, p, spacing_m, max_noise_gain)
        else:  # the most spans fail: fit_curve's search from one fewer, for all such runs at once
            failed.append((i, pts, t_run, most - 1))
    if _DIRECT_TRIES != 1:  # pragma: no cover - fit_curve's further direct tries first
        for i, pts, t_run, fewer in failed:
            try:
                results[i] = _fit_from(pts, t_run, t_run, np.ones(t_run.shape[0], dtype=np.intp), p, fewer,
                                       fewer + 1, max_noise_gain, _DIRECT_TRIES - 1)
            except FitError:
                results[i] = None
        return results
    for i, pts, t_run, fewer in failed:
        if fewer >= 1:                                 # else no count left: FitError (None)
            results[i] = _search_fit(pts, t_run, t_run, _ones(t_run.shape[0]), p, fewer, max_noise_gain)
    return results


def _fit_or_none(pts: np.ndarray, degree: int, spacing_m: float, max_noise_gain: float | None) -> FitResult | None:
    """:func:`fit_curve`, None where it raises FitError."""
    try:
        return fit_curve(pts, degree, spacing_m, max_noise_gain=max_noise_gain)
    except FitError:
        return None


def _distinct_sorted(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.unique(t, return_counts=True, return_inverse=True)`` for non-decreasing t,
    without the sort: (d,) distinct values, (d,) their counts, (m,) index of each value."""
    m = t.shape[0]
    new = np.empty(m, dtype=bool)
    new[0] = True
    np.greater(t[1:], t[:-1], out=new[1:])
    inverse = np.cumsum(new)
    inverse -= 1
    if inverse[-1] == m - 1:  # all distinct, the usual case for chord lengths of scan points
        return t, np.ones(m, dtype=np.intp), inverse
    first = np.flatnonzero(new)
    counts = np.empty(first.shape[0], dtype=np.intp)
    counts[:-1] = first[1:] - first[:-1]
    counts[-1] = m - first[-1]
    return t[first], counts, inverse


@functools.lru_cache(maxsize=1024)
def _ones(n: int) -> np.ndarray:
    """``np.ones(n, dtype=np.intp)``, read-only and cached: multiplicities of distinct data."""
    ones = np.ones(n, dtype=np.intp)
    ones.setflags(write=False)
    return ones


# Span counts fit_curve decides one by one before it screens all the others at once. On
# real scans the most spans nearly always pass; on the simulated corridor they fail for
# ~20 counts in a row, where each further direct try would cost about half a screen.
_DIRECT_TRIES = 1

# What _fit_with_spans returns for a span count that fit_curve's search rejects.
_REJECTED = object()


def _fit_with_spans(pts: np.ndarray, t: np.ndarray, distinct: np.ndarray, spans: int, degree: int,
                    max_noise_gain: float | None) -> FitResult | object | None:
    """The fit on ``spans`` spans; :data:`_REJECTED` where :func:`fit_curve`'s search
    rejects that count (Schoenberg–Whitney on the distinct parameters, then
    :func:`least_squares_operator`); None, undecided, if a span of the knot vector's
    domain is empty (only for a length near the rounding of the start), where the search
    decides.

    Knots, Schoenberg–Whitney (from the knots and the distinct parameters alone, as in
    :func:`iter_span_counts`) and the collocation matrix come from one compiled loop
    (:func:`bsslam.spline.fit_kernels.fit_setup`); the factorisation stays LAPACK's.

    Args:
        pts: (m, 2) data points (m); t: (m,) their non-decreasing parameters (m).
        distinct: (d,) the distinct values of ``t``.
        spans: number of spans ≥ 1; degree: polynomial degree p.
        max_noise_gain: as in :func:`fit_curve`.
    """
    status, knots, collocation = fit_setup(t, distinct, spans, degree)
    if status == 2:
        return None
    if status == 1:
        return _REJECTED
    phi = least_squares_operator(collocation, max_noise_gain)
    if phi is None:
        return _REJECTED
    return FitResult(curve=BSplineCurve.unchecked(phi @ pts, knots, degree), phi=phi, params=t)
