"""Least-squares fitting of a clamped B-spline to an ordered run of laser points (spec §2).

The control points are a fixed linear map of the data, ``X = Φ D`` with
``Φ = (BᵀB)⁻¹Bᵀ`` (paper (11)); the filter's Jacobians reuse Φ, so it is returned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from bsslam.errors import FitError, SplineError
from bsslam.spline.basis import basis_functions, collocation_matrix
from bsslam.spline.curve import BSplineCurve, as_points
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
    diag = np.abs(np.diag(r))
    if diag.min() <= _RANK_TOLERANCE * diag.max():
        return None
    phi = _solve_upper(r, q.T)
    if max_noise_gain is not None and np.max(np.einsum("ij,ij->i", phi, phi)) > max_noise_gain ** 2:
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


# Span counts screened together: the first well-posed count usually passes, so screening
# all of them (up to ~50) at once would mostly be wasted.
_SCREEN_CHUNK = 6


def candidate_span_counts(t: np.ndarray, distinct: np.ndarray, multiplicity: np.ndarray, degree: int,
                          most: int, max_noise_gain: float | None = None) -> np.ndarray:
    """All of :func:`iter_span_counts`, as a (k,) int array."""
    return np.array(list(iter_span_counts(t, distinct, multiplicity, degree, most, max_noise_gain)), dtype=int)


def iter_span_counts(t: np.ndarray, distinct: np.ndarray, multiplicity: np.ndarray, degree: int,
                     most: int, max_noise_gain: float | None = None):
    """The span counts ``most … 1`` (descending) that :func:`fit_curve` must still try.

    For every count at once (one basis evaluation for all their knot vectors): the clamped
    knot vector exactly as ``fit_curve`` builds it; Schoenberg–Whitney on the distinct
    parameters, decided as :func:`satisfies_schoenberg_whitney` decides it; and, with
    ``max_noise_gain``, a lower bound of each control point's noise gain. The gain of
    control point i is ``‖Φ_i‖ = sqrt((BᵀB)⁻¹_ii)``; for the principal block M of ``A = BᵀB``
    on the 2·degree + 1 neighbours of i, ``(M⁻¹)_ii ≤ (A⁻¹)_ii`` (conditioning on fewer
    variables), so a count whose bound exceeds the limit cannot pass the exact test.

    Args:
        t: (m,) the data parameters (m), non-decreasing.
        distinct: (d,) the distinct values of ``t``; multiplicity: (d,) their counts.
        degree: polynomial degree p.
        most: the largest span count (≥ 1 for any candidate).
        max_noise_gain: the limit of :func:`least_squares_operator`, or None.

    Yields:
        int span counts, descending; the noise screen runs on a few counts at a time, as
        the caller asks for more.
    """
    p = degree
    spans = np.arange(most, 0, -1)
    if spans.size == 0:
        return
    k = spans.shape[0]
    n = spans + p                                        # control points per candidate
    start, length, end = float(t[0]), float(t[-1] - t[0]), float(t[-1])
    # all knot vectors, bit for bit as clamped_knots_with_spans (+ the exact end) builds them
    owner, local = _groups(n + p + 1)
    j = local - p
    interior = start + length * (j / spans[owner])
    K = np.where(local <= p, start, np.where(local >= n[owner], end, interior))
    knot_start = np.concatenate([[0], np.cumsum(n + p + 1)])
    # span of every distinct parameter under every candidate (find_span, exactly)
    d = distinct.shape[0]
    q_owner = np.repeat(np.arange(k), d)
    tq = np.tile(distinct, k)
    found = np.searchsorted(owner + 1j * K, q_owner + 1j * tq, side="right") - 1 - knot_start[q_owner]
    span_local = np.clip(found, p, n[q_owner] - 1)
    _, values = basis_functions(K, p, tq, span=knot_start[q_owner] + span_local)
    beta = values[0]                                     # (k·d, p+1)
    cp_start = np.concatenate([[0], np.cumsum(n)])
    cp = cp_start[q_owner][:, None] + span_local[:, None] - p + np.arange(p + 1)   # global cp rows
    row = np.tile(np.arange(d), k)

    # Schoenberg–Whitney per candidate: the greedy match of satisfies_schoenberg_whitney
    nonzero = beta > 0
    first = np.full(cp_start[-1], d)
    last = np.full(cp_start[-1], -1)
    rows = np.broadcast_to(row[:, None], nonzero.shape)[nonzero]
    np.minimum.at(first, cp[nonzero], rows)
    np.maximum.at(last, cp[nonzero], rows)
    cp_owner, i = _groups(n)
    # a running maximum per candidate: offset each candidate above everything before it
    big = d + int(n.max()) + 1
    matched = i + np.maximum.accumulate(first - i + cp_owner * big) - cp_owner * big
    ok = np.bincount(cp_owner, weights=(matched > last) | (last < 0), minlength=k) == 0

    well_posed = np.flatnonzero(ok)
    if max_noise_gain is None:
        yield from (int(c) for c in spans[well_posed])
        return
    weight = multiplicity[row]
    for at in range(0, well_posed.shape[0], _SCREEN_CHUNK):
        chunk = well_posed[at: at + _SCREEN_CHUNK]
        # the chunk's rows, with its control points renumbered from 0
        rank = np.full(k, -1)
        rank[chunk] = np.arange(chunk.shape[0])
        rows_in = rank[q_owner] >= 0
        n_c = n[chunk]
        start_c = np.concatenate([[0], np.cumsum(n_c)])
        owner_rows = q_owner[rows_in]
        cp_c = cp[rows_in] - cp_start[owner_rows][:, None] + start_c[rank[owner_rows]][:, None]
        noisy = _surely_too_noisy(beta[rows_in], cp_c, weight[rows_in], start_c, _groups(n_c)[0], p,
                                  max_noise_gain)
        yield from (int(c) for c in spans[chunk[~noisy]])


def _groups(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For consecutive groups of ``counts`` items: each item's group and index in it."""
    owner = np.repeat(np.arange(counts.shape[0]), counts)
    return owner, np.arange(owner.shape[0]) - np.repeat(np.cumsum(counts) - counts, counts)


def _surely_too_noisy(beta, cp, weight, cp_start, cp_owner, p, max_noise_gain) -> np.ndarray:
    """(k,) bool: for k candidates satisfying Schoenberg–Whitney (so A is positive
    definite), whether some control point's local lower bound of its squared noise gain
    exceeds the limit (see :func:`iter_span_counts`).

    Args:
        beta: (r, p+1) basis values of the data rows; cp: (r, p+1) their control points,
            numbered across candidates; weight: (r,) multiplicity of each row;
        cp_start: (k+1,) first control point of each candidate; cp_owner: (N,) candidate
            of each control point; p: degree; max_noise_gain: the limit.
    """
    N = cp_start[-1]
    k = cp_start.shape[0] - 1
    # band of A = BᵀB: band[c, e] = A[c, c + e], from each datum's degree + 1 basis values
    band = np.zeros(N * (p + 1))
    for r in range(p + 1):
        for e in range(p + 1 - r):
            band += np.bincount(cp[:, r] * (p + 1) + e, weights=weight * beta[:, r] * beta[:, r + e],
                                minlength=N * (p + 1))
    band = band.reshape(N, p + 1)
    # the (2p+1)² principal block around each control point; neighbours outside the curve
    # become decoupled unit entries, which leave the bound unchanged
    w = 2 * p + 1
    a, b = np.meshgrid(np.arange(w), np.arange(w), indexing="ij")
    c = np.arange(N)[:, None, None] - p
    lo_i = c + np.minimum(a, b)
    gap = np.abs(a - b)
    inside = ((lo_i >= cp_start[cp_owner][:, None, None]) & (c + np.maximum(a, b) < cp_start[cp_owner + 1][:, None, None])
              & (gap <= p))
    M = np.where(inside, band[np.clip(lo_i, 0, N - 1), np.minimum(gap, p)], 0.0)
    outside = (c + np.arange(w) < cp_start[cp_owner][:, None, None]) | (
        c + np.arange(w) >= cp_start[cp_owner + 1][:, None, None])        # (N, 1, w)
    diag = np.arange(w)
    M[:, diag, diag] = np.where(outside[:, 0, :], 1.0, M[:, diag, diag])
    # Nearly singular blocks (barely determined control points, the very cases to catch)
    # must not stop the solve: M + εI is positive definite and (M + εI)⁻¹ ⪯ M⁻¹, so the
    # bound stays a lower bound.
    M[:, diag, diag] += 1e-13 * np.max(M[:, diag, diag], axis=1, keepdims=True)
    rhs = np.zeros((N, w, 1))
    rhs[:, p, 0] = 1.0
    try:
        with np.errstate(all="ignore"):
            gain2 = np.linalg.solve(M, rhs)[:, p, 0]    # (M⁻¹)_ii ≤ (A⁻¹)_ii = ‖Φ_i‖²
    except np.linalg.LinAlgError:  # pragma: no cover - M + εI is positive definite
        return np.zeros(k, dtype=bool)
    noisy = np.isfinite(gain2) & (gain2 > max_noise_gain ** 2 * (1.0 + _SCREEN_MARGIN))
    return np.bincount(cp_owner, weights=noisy, minlength=k) > 0


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
    distinct, multiplicity, inverse = _distinct_sorted(t)
    # n_control = spans + degree can never exceed the number of distinct parameters.
    most = most_spans = min(span_count(length, spacing_m), distinct.shape[0] - degree)
    # The most spans that give a well-posed fit win. On real scans the most spans nearly
    # always do (and else one or two fewer), so the first few counts are decided directly,
    # each from one basis evaluation; only if they all fail are the remaining counts
    # screened at once (Schoenberg–Whitney and a lower bound of the noise gain) and the
    # survivors factorised, from the most spans down.
    for _ in range(_DIRECT_TRIES):
        if most < 1:
            break
        fit = _fit_with_spans(pts, t, inverse, distinct.shape[0], most, degree, max_noise_gain)
        if isinstance(fit, FitResult):
            return fit
        if fit is not _REJECTED:  # undecided: the search decides this count and the rest
            break
        most -= 1
    for spans in iter_span_counts(t, distinct, multiplicity, degree, most, max_noise_gain):
        knots = clamped_knots_with_spans(length, spans, degree, start=float(t[0]))
        knots[-degree - 1 :] = t[-1]  # exactly the last parameter, not start + length
        phi = least_squares_operator(collocation_matrix(knots, degree, t), max_noise_gain)
        if phi is None:
            continue
        curve = BSplineCurve.unchecked(phi @ pts, knots, degree)
        return FitResult(curve=curve, phi=phi, params=t)
    raise FitError(
        f"no degree-{degree} spline with 1..{max(most_spans, 1)} spans fits these {m} points "
        "(Schoenberg–Whitney fails: too few distinct points)")


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


# Span counts fit_curve decides one by one before it screens all the others at once: one
# direct decision costs about a tenth of the screen's setup, and in refined fits (half the
# knot spacing) the most spans fail about one time in five, nearly always for one or two
# counts only.
_DIRECT_TRIES = 3

# What _fit_with_spans returns for a span count that fit_curve's search rejects.
_REJECTED = object()


def _fit_with_spans(pts: np.ndarray, t: np.ndarray, inverse: np.ndarray, d: int, spans: int, degree: int,
                    max_noise_gain: float | None) -> FitResult | object | None:
    """The fit on ``spans`` spans; :data:`_REJECTED` where :func:`fit_curve`'s search
    rejects that count (Schoenberg–Whitney on the distinct parameters, then
    :func:`least_squares_operator`); None, undecided, if an end span of the knot vector is
    empty (only for a length below the rounding of the start), where the search's span
    lookup and :func:`find_span` could differ: the search decides then.

    One basis evaluation at the m parameters serves both tests and the collocation matrix;
    rows of repeated parameters are identical, so the Schoenberg–Whitney match on them is
    the one on the distinct parameters.

    Args:
        pts: (m, 2) data points (m); t: (m,) their non-decreasing parameters (m).
        inverse: (m,) index of each parameter among the d distinct ones.
        spans: number of spans ≥ 1; degree: polynomial degree p.
        max_noise_gain: as in :func:`fit_curve`.
    """
    p = degree
    n = spans + p
    # clamped_knots_with_spans(length, spans, p, start) with the exact last parameter as
    # its end, bit for bit, without the argument checks (fit_curve has made them)
    start = float(t[0])
    knots = np.empty(n + p + 1)
    knots[: p + 1] = start
    knots[p + 1 : n] = start + float(t[-1] - t[0]) * (np.arange(1, spans) / spans)
    knots[n:] = t[-1]
    if not (knots[p] < knots[p + 1] and knots[n - 1] < knots[n]):
        return None
    # find_span, and the search's lookup, when neither end span is empty
    span = np.searchsorted(knots, t, side="right") - 1
    np.maximum(span, p, out=span)
    np.minimum(span, n - 1, out=span)
    _, values = basis_functions(knots, p, t, span=span)
    collocation = np.zeros((t.shape[0], n))
    collocation[np.arange(t.shape[0])[:, None], span[:, None] - p + np.arange(p + 1)] = values[0]
    if not _schoenberg_whitney_dense(collocation, inverse):
        return _REJECTED
    phi = least_squares_operator(collocation, max_noise_gain)
    if phi is None:
        return _REJECTED
    return FitResult(curve=BSplineCurve.unchecked(phi @ pts, knots, p), phi=phi, params=t)
