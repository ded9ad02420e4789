"""Least-squares fitting of a clamped B-spline to an ordered run of laser points (spec §2).

The control points are a fixed linear map of the data, ``X = Φ D`` with
``Φ = (BᵀB)⁻¹Bᵀ`` (paper (11)); the filter's Jacobians reuse Φ, so it is returned.
"""

from __future__ import annotations

import functools
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
    diag = np.abs(r.diagonal())
    if diag.min() <= _RANK_TOLERANCE * diag.max():
        return None
    phi = _solve_upper(r, q.T)
    if max_noise_gain is not None and np.einsum("ij,ij->i", phi, phi).max() > max_noise_gain ** 2:
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
    bound exceeds the limit cannot pass the exact test (see :func:`_surely_too_noisy`).

    Schoenberg–Whitney needs no basis evaluation: where the domain knots are strictly
    increasing, basis function i is non-zero exactly at the data strictly inside its
    support (ξ_i, ξ_{i+p+1}) (the first function also at the start, the last at the end),
    so the first and last datum of every support follow from one ``searchsorted`` of all
    knot vectors' knots. Basis values are evaluated only at the data near the control
    points the screen tests.

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
    """:func:`iter_span_counts` of several runs at once (the candidates of all runs in one
    pass, as those of one run are): for each run ``(t, distinct, multiplicity, most)``
    with most ≥ 1, its surviving span counts, descending, as an int array."""
    R = len(runs)
    lay = _candidate_layout(runs[0][3], p) if R == 1 else _runs_layout(tuple(r[3] for r in runs), p)
    spans, n, k = lay.spans, lay.n, lay.k
    # each knot's and control point's run, and the runs' data, one after another
    t0 = [float(t[0]) for t, _, _, _ in runs]
    t1 = [float(t[-1]) for t, _, _, _ in runs]
    lengths = [float(t[-1] - t[0]) for t, _, _, _ in runs]
    if R == 1:
        # all knot vectors, bit for bit as clamped_knots_with_spans (+ the exact end)
        K = t0[0] + lengths[0] * lay.ratio
        K[lay.clamped_start] = t0[0]
        K[lay.clamped_end] = t1[0]
        distinct = runs[0][1]
        multiplicity = runs[0][2]
    else:
        knot_run = lay.run[lay.knot_owner]
        K = np.array(t0)[knot_run] + np.array(lengths)[knot_run] * lay.ratio
        K[lay.clamped_start] = np.array(t0)[knot_run[lay.clamped_start]]
        K[lay.clamped_end] = np.array(t1)[knot_run[lay.clamped_end]]
        distinct = np.concatenate([r[1] for r in runs])
        multiplicity = np.concatenate([r[2] for r in runs])
    degenerate = K[lay.domain_next] <= K[lay.domain_knot]
    if degenerate.any():
        # a span rounded to nothing (a length of a few ulps of the start): those runs are
        # decided by the basis values themselves, as satisfies_schoenberg_whitney does
        bad = set(lay.run[lay.knot_owner[lay.domain_knot[degenerate]]].tolist())
        good = [r for r in range(R) if r not in bad]
        out: list[np.ndarray] = [np.zeros(0, dtype=np.intp)] * R
        for r in bad:
            t, dist, mult, most = runs[r]
            out[r] = np.array(list(_iter_span_counts_by_basis(t, dist, mult, p, most, max_noise_gain)), dtype=np.intp)
        if good:
            for r, counts in zip(good, _surviving_counts([runs[r] for r in good], p, max_noise_gain)):
                out[r] = counts
        return out
    d_run = np.array([r[1].shape[0] for r in runs])
    D = int(d_run.max()) + 1                              # datum slots per candidate
    d_start = np.concatenate([[0], np.cumsum(d_run)])
    cand_run = lay.run                                    # (k,) run of each candidate
    # first and last datum of every basis function's support, all candidates at once:
    # data before each knot (to find spans later), data up to each support's first knot
    if R == 1:
        before = np.searchsorted(distinct, K, side="left")
        first = np.searchsorted(distinct, K[lay.cp_knot], side="right")
    else:  # complex keys (run, value) compare run first: one searchsorted for all runs
        keys = np.repeat(np.arange(R), d_run) + 1j * distinct
        knot_run = cand_run[lay.knot_owner]
        before = np.searchsorted(keys, knot_run + 1j * K, side="left") - d_start[knot_run]
        cp_knot_run = knot_run[lay.cp_knot]
        first = np.searchsorted(keys, cp_knot_run + 1j * K[lay.cp_knot], side="right") - d_start[cp_knot_run]
    first[lay.first_cp] = 0
    last = before[lay.cp_knot + p + 1] - 1
    last[lay.last_cp] = d_run[cand_run[lay.cp_owner[lay.last_cp]]] - 1
    # Schoenberg–Whitney per candidate: the greedy match of satisfies_schoenberg_whitney, a
    # running maximum per candidate (each candidate offset above everything before it)
    big = D + int(n.max()) + 1
    offset = lay.cp_owner * big
    matched = lay.cp_index + np.maximum.accumulate(first - lay.cp_index + offset) - offset
    ok = np.bincount(lay.cp_owner, weights=matched > last, minlength=k) == 0
    # Control points with few data in their support are the ones a noise gain can wreck:
    # screen those (of the well-posed counts) at once; the exact test decides the rest.
    tested = np.flatnonzero(ok[lay.cp_owner] & (last - first < _SCREEN_FEW_DATA))
    if max_noise_gain is not None and tested.shape[0] > 0:
        # the data of the supports of each tested control point and of its neighbours in
        # its screen block (all of them: a block from fewer data would bound too high), once
        # per candidate: a difference array over (candidate, datum slot)
        owner_t = lay.cp_owner[tested]
        h = _SCREEN_HALF_WIDTH
        lo_cp = np.maximum(tested - h, lay.cp_start[owner_t])
        hi_cp = np.minimum(tested + h, lay.cp_start[owner_t + 1] - 1)
        flat = owner_t * D
        marks = (np.bincount(flat + first[lo_cp], minlength=k * D)
                 - np.bincount(flat + last[hi_cp] + 1, minlength=k * D))
        pair = np.flatnonzero(np.cumsum(marks))
        q_owner, row = np.divmod(pair, D)
        datum = d_start[cand_run[q_owner]] + row
        # span of each of those data under its candidate, as find_span finds it (the domain
        # knots increase strictly): the knots at or before datum j are those with at most j
        # data before them, counted by an integer searchsorted within the candidate's knots
        span = np.searchsorted(lay.knot_owner * D + before, pair, side="right") - 1
        np.maximum(span, lay.knot_start[q_owner] + p, out=span)
        np.minimum(span, lay.knot_start[q_owner] + n[q_owner] - 1, out=span)
        _, values = basis_functions(K, p, distinct[datum], span=span)
        cp = (span - lay.knot_start[q_owner] + lay.cp_start[q_owner] - p)[:, None] + np.arange(p + 1)
        ok &= ~_surely_too_noisy(values[0], cp, multiplicity[datum], lay.cp_start, lay.cp_owner, p,
                                 max_noise_gain, tested)
    if R == 1:
        return [spans[ok]]
    return [spans[lay.cand_start[r]: lay.cand_start[r + 1]][ok[lay.cand_start[r]: lay.cand_start[r + 1]]]
            for r in range(R)]


class _Layout:
    """Index arrays of the candidate knot vectors of :func:`iter_span_counts` (spans
    ``most … 1``, degree p): they depend on those two numbers only, so they are cached.

    Attributes:
        spans: (k,) span counts, descending; n: (k,) control points of each; k; n_cp = Σ n.
        ratio: (Σ(n+p+1),) ``j / spans`` of every knot (j = local index − p): the interior
            knot is ``start + length · ratio``, as clamped_knots_with_spans computes it.
        clamped_start, clamped_end: indices of the clamped end knots.
        domain_knot, domain_next: consecutive knot pairs inside each domain.
        knot_owner: (Σ(n+p+1),) candidate of each knot; knot_start, cp_start: (k+1,)
            first knot and control point of each candidate.
        cp_owner, cp_index: (n_cp,) candidate and local index of each control point;
        cp_knot: its first support knot; first_cp, last_cp: the end control points.
        run: (k,) run of each candidate, cand_start: (R+1,) first candidate of each run
            (one run, unless :meth:`concatenate` built it).
    """

    def __init__(self, most: int, p: int) -> None:
        self.spans = np.arange(most, 0, -1)
        self.n = self.spans + p
        self.k = self.spans.shape[0]
        self.knot_owner, local = _groups(self.n + p + 1)
        self.ratio = (local - p) / self.spans[self.knot_owner]
        self.clamped_start = np.flatnonzero(local <= p)
        self.clamped_end = np.flatnonzero(local >= self.n[self.knot_owner])
        domain = np.flatnonzero((local >= p) & (local < self.n[self.knot_owner]))
        self.domain_knot, self.domain_next = domain, domain + 1
        self.knot_start = np.concatenate([[0], np.cumsum(self.n + p + 1)])
        self.cp_start = np.concatenate([[0], np.cumsum(self.n)])
        self.cp_owner, self.cp_index = _groups(self.n)
        self.n_cp = self.cp_owner.shape[0]
        self.cp_knot = self.knot_start[self.cp_owner] + self.cp_index
        self.first_cp = self.cp_start[:-1]
        self.last_cp = self.cp_start[1:] - 1
        self.run = np.zeros(self.k, dtype=np.intp)          # one run: see concatenate
        self.cand_start = np.array([0, self.k])
        for value in vars(self).values():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)

    @classmethod
    def concatenate(cls, lays: list[_Layout]) -> _Layout:
        """The layouts of several runs' candidates, one after another (indices shifted);
        ``run`` (k,) tells each candidate's run, ``cand_start`` (R+1,) each run's first."""
        out = object.__new__(cls)
        ks = np.array([lay.k for lay in lays])
        knots = np.array([lay.knot_start[-1] for lay in lays])
        cps = np.array([lay.n_cp for lay in lays])
        k0 = np.concatenate([[0], np.cumsum(ks)])
        g0 = np.concatenate([[0], np.cumsum(knots)])
        c0 = np.concatenate([[0], np.cumsum(cps)])
        cat = np.concatenate
        out.spans = cat([lay.spans for lay in lays])
        out.n = cat([lay.n for lay in lays])
        out.k = int(k0[-1])
        out.n_cp = int(c0[-1])
        out.ratio = cat([lay.ratio for lay in lays])
        out.knot_owner = cat([lay.knot_owner + k for lay, k in zip(lays, k0)])
        out.clamped_start = cat([lay.clamped_start + g for lay, g in zip(lays, g0)])
        out.clamped_end = cat([lay.clamped_end + g for lay, g in zip(lays, g0)])
        out.domain_knot = cat([lay.domain_knot + g for lay, g in zip(lays, g0)])
        out.domain_next = out.domain_knot + 1
        out.knot_start = cat([[0], *[lay.knot_start[1:] + g for lay, g in zip(lays, g0)]])
        out.cp_start = cat([[0], *[lay.cp_start[1:] + c for lay, c in zip(lays, c0)]])
        out.cp_owner = cat([lay.cp_owner + k for lay, k in zip(lays, k0)])
        out.cp_index = cat([lay.cp_index for lay in lays])
        out.cp_knot = cat([lay.cp_knot + g for lay, g in zip(lays, g0)])
        out.first_cp = out.cp_start[:-1]
        out.last_cp = out.cp_start[1:] - 1
        out.run = np.repeat(np.arange(len(lays)), ks)
        out.cand_start = k0
        for value in vars(out).values():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
        return out


@functools.lru_cache(maxsize=512)
def _candidate_layout(most: int, p: int) -> _Layout:
    """The cached :class:`_Layout` of spans ``most … 1`` at degree p."""
    return _Layout(most, p)


@functools.lru_cache(maxsize=256)
def _runs_layout(mosts: tuple[int, ...], p: int) -> _Layout:
    """The cached :class:`_Layout` of several runs' candidates (spans ``most … 1`` each):
    consecutive scans often repeat the same most spans."""
    return _Layout.concatenate([_candidate_layout(most, p) for most in mosts])


# Control points whose support holds fewer distinct data than this are screened for their
# noise gain (the others are left to the exact test). Chosen on recorded simulated-corridor
# and Intel fits: 4, 6 and 8 leave the same number of exact tests (3 a few more), and 4
# tests the fewest control points.
_SCREEN_FEW_DATA = 4


def _iter_span_counts_by_basis(t: np.ndarray, distinct: np.ndarray, multiplicity: np.ndarray, degree: int,
                               most: int, max_noise_gain: float | None = None):
    """:func:`iter_span_counts` from one basis evaluation at every distinct parameter under
    every candidate: for knot vectors with an empty span, where the supports' data do not
    follow from the knots alone."""
    p = degree
    spans = np.arange(most, 0, -1)
    k = spans.shape[0]
    n = spans + p
    start, length, end = float(t[0]), float(t[-1] - t[0]), float(t[-1])
    owner, local = _groups(n + p + 1)
    interior = start + length * ((local - p) / spans[owner])
    K = np.where(local <= p, start, np.where(local >= n[owner], end, interior))
    knot_start = np.concatenate([[0], np.cumsum(n + p + 1)])
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
    nonzero = beta > 0
    first = np.full(cp_start[-1], d)
    last = np.full(cp_start[-1], -1)
    rows = np.broadcast_to(row[:, None], nonzero.shape)[nonzero]
    np.minimum.at(first, cp[nonzero], rows)
    np.maximum.at(last, cp[nonzero], rows)
    cp_owner, i = _groups(n)
    big = d + int(n.max()) + 1
    matched = i + np.maximum.accumulate(first - i + cp_owner * big) - cp_owner * big
    ok = np.bincount(cp_owner, weights=(matched > last) | (last < 0), minlength=k) == 0
    well_posed = np.flatnonzero(ok)
    if max_noise_gain is None or well_posed.shape[0] == 0:
        yield from (int(c) for c in spans[well_posed])
        return
    keep = ok[q_owner]
    noisy = _surely_too_noisy(beta[keep], cp[keep], multiplicity[row[keep]], cp_start, cp_owner, p,
                              max_noise_gain, np.flatnonzero(ok[cp_owner]))
    yield from (int(c) for c in spans[well_posed[~noisy[well_posed]]])


def _groups(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For consecutive groups of ``counts`` items: each item's group and index in it."""
    owner = np.repeat(np.arange(counts.shape[0]), counts)
    return owner, np.arange(owner.shape[0]) - np.repeat(np.cumsum(counts) - counts, counts)


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


@functools.lru_cache(maxsize=None)
def _screen_plan(p: int, h: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, tuple[int, ...]]:
    """The constants of :func:`_surely_too_noisy` for degree p and half-width h.

    Returns:
        pairs: (2, P) the index pairs (r, r + e) of the degree + 1 basis values a datum
            contributes to the band entry A[c, c + e] (c its r-th control point).
        low, gap: (w, w) for the block on offsets −h … h (w = 2h + 1): the offset of the
            band row of each entry (min(a, b) − h) and its band column |a − b| (≤ p).
        zero: (w, w) the entries outside the band (exactly zero in A).
        pivots: the order of elimination, −h … −1 then h … 1, as block indices.
    """
    r_i, r_j = np.triu_indices(p + 1)
    a, b = np.meshgrid(np.arange(2 * h + 1), np.arange(2 * h + 1), indexing="ij")
    gap = np.abs(a - b)
    pivots = (*range(h), *range(2 * h, h, -1))
    return np.stack((r_i, r_j)), np.minimum(a, b) - h, np.minimum(gap, p), gap > p, pivots


def _surely_too_noisy(beta, cp, weight, cp_start, cp_owner, p, max_noise_gain, tested) -> np.ndarray:
    """(k,) bool: for k candidates, whether some tested control point's local lower bound
    of its squared noise gain exceeds the limit (see :func:`iter_span_counts`).

    The bound of control point c is ``(M⁻¹)_cc`` of the principal block M of A = BᵀB on
    c − h … c + h (h = :data:`_SCREEN_HALF_WIDTH`), neighbours outside the curve decoupled
    (unit diagonal), which is ``1 / s`` for the Schur complement s of the block onto c:
    symmetric Gaussian elimination of the neighbours, all blocks at once (a few numpy calls
    per pivot, no LAPACK: its batched calls cost more than the arithmetic here).

    Args:
        beta: (r, p+1) basis values of the data rows; cp: (r, p+1) their control points,
            numbered across candidates; weight: (r,) multiplicity of each row;
        cp_start: (k+1,) first control point of each candidate; cp_owner: (N,) candidate
            of each control point; p: degree; max_noise_gain: the limit;
        tested: (T,) the control points to bound, of candidates that satisfy
            Schoenberg–Whitney (so their A is positive definite); the rows must hold all the
            data of the supports of each and of its h neighbours on either side.
    """
    N = cp_owner.shape[0]
    k = cp_start.shape[0] - 1
    h = _SCREEN_HALF_WIDTH
    (r_i, r_j), low, gap, zero, pivots = _screen_plan(p, h)
    # band of A = BᵀB: band[c, e] = A[c, c + e], from each datum's degree + 1 basis values,
    # in one bincount over the (r, r + e) pairs of basis values
    band = np.bincount((cp[:, r_i] * (p + 1) + (r_j - r_i)).ravel(),
                       weights=(weight[:, None] * beta[:, r_i] * beta[:, r_j]).ravel(), minlength=N * (p + 1))
    # the (T, w, w) blocks; neighbours outside the curve become decoupled unit entries,
    # which leave the bound unchanged
    owner = cp_owner[tested]
    c = tested[:, None, None]
    row = c + low                                         # band row of each entry
    inside = (row >= cp_start[owner][:, None, None]) & (c + low + gap < cp_start[owner + 1][:, None, None]) & ~zero
    M = np.where(inside, band.take(row * (p + 1) + gap, mode="clip"), 0.0)   # outside: any entry, masked
    w = 2 * h + 1
    diag = np.arange(w)
    M[:, diag, diag] = np.where(inside[:, diag, diag], M[:, diag, diag] * (1.0 + _SCREEN_SHIFT), 1.0)
    # eliminate the neighbours into the centre: after a pivot its row and column are zero
    # (exactly: x − (x / y)·y with the same operands), so later pivots ignore it
    with np.errstate(all="ignore"):
        for q in pivots:
            col = M[:, :, q]
            M -= col[:, :, None] * (col / col[:, q:q + 1])[:, None, :]
        schur = M[:, h, h]
        # reject only on a finite, positive complement: a breakdown decides nothing
        noisy = (schur > 0) & (schur * (max_noise_gain ** 2 * (1.0 + _SCREEN_MARGIN)) < 1.0)
    return np.bincount(owner, weights=noisy, minlength=k) > 0


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
    fit = _first_fit(pts, t, distinct, iter_span_counts(t, distinct, multiplicity, degree, most, max_noise_gain),
                     degree, max_noise_gain)
    if fit is not None:
        return fit
    raise FitError(
        f"no degree-{degree} spline with 1..{max(most_spans, 1)} spans fits these {pts.shape[0]} points "
        "(Schoenberg–Whitney fails: too few distinct points)")


def _first_fit(pts: np.ndarray, t: np.ndarray, distinct: np.ndarray, counts, degree: int,
               max_noise_gain: float | None) -> FitResult | None:
    """The fit on the first of the span ``counts`` (descending, from the search) that the
    exact test accepts, or None."""
    for spans in counts:
        fit = _fit_with_spans(pts, t, distinct, int(spans), degree, max_noise_gain)
        if isinstance(fit, FitResult):
            return fit
        if fit is _REJECTED:
            continue
        # a knot vector with an empty span: find_span's clamping decides the spans
        knots = clamped_knots_with_spans(float(t[-1] - t[0]), int(spans), degree, start=float(t[0]))
        knots[-degree - 1 :] = t[-1]  # exactly the last parameter, not start + length
        phi = least_squares_operator(collocation_matrix(knots, degree, t), max_noise_gain)
        if phi is None:
            continue
        curve = BSplineCurve.unchecked(phi @ pts, knots, degree)
        return FitResult(curve=curve, phi=phi, params=t)
    return None


def fit_runs(points: np.ndarray, starts: np.ndarray, ends: np.ndarray, degree: int, spacing_m: float, *,
             max_noise_gain: float | None = None) -> list[FitResult | None]:
    """:func:`fit_curve` of each run ``points[starts[i] : ends[i] + 1]`` (default chord-length
    parameters), the same results bit for bit, None where it raises FitError.

    The runs of a scan share degree and spacing, so their parameters, knot vectors,
    Schoenberg–Whitney tests and basis values at the most spans are computed for all runs
    at once; each run then only factorises its collocation matrix. A run whose most spans
    fail (or that is unusual: repeated parameters, an empty knot span) goes through
    :func:`fit_curve`'s search, or fit_curve itself.

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
    # chord lengths of every run: each run's cumulative sum alone (row-wise, so the same
    # sequential sums as _chord_lengths), in a zero-padded (S, longest) table
    step = pts_all[1:] - pts_all[:-1]
    chord = np.hypot(step[:, 0], step[:, 1])
    owner, local = _groups(sizes)
    table = np.zeros((S, int(sizes.max())))
    inner = local > 0
    table[owner[inner], local[inner]] = chord[(starts[owner] + local - 1)[inner]]
    np.cumsum(table, axis=1, out=table)
    t_all = table[owner, local]                          # (Σm,) every run's parameters, from 0
    last = np.cumsum(sizes) - 1                          # each run's last row in t_all
    lengths = t_all[last]
    # usual runs: enough points, distinct parameters (strictly increasing)
    strict = np.ones(t_all.shape[0], dtype=bool)
    strict[1:] = t_all[1:] > t_all[:-1]
    strict[last[:-1] + 1] = True                         # run starts compare with nothing
    distinct_all = np.bincount(owner, weights=~strict, minlength=S) == 0
    usual = distinct_all & (sizes >= p + 1) & (lengths > 0)
    results: list[FitResult | None] = [None] * S
    most = np.zeros(S, dtype=np.intp)
    for i in np.flatnonzero(usual):
        most[i] = min(span_count(float(lengths[i]), spacing_m), int(sizes[i]) - p)
    usual &= most >= 1
    run = np.flatnonzero(usual)
    if run.shape[0]:
        _fit_usual_runs(pts_all, t_all[usual[owner]], run, starts, sizes[run], lengths[run], most[run], p,
                        spacing_m, max_noise_gain, results)
    for i in np.flatnonzero(~usual):
        results[i] = _fit_or_none(pts_all[starts[i]: ends[i] + 1], p, spacing_m, max_noise_gain)
    return results


def _fit_usual_runs(pts_all, t, run, starts, sizes, lengths, most, p, spacing_m, max_noise_gain, results):
    """:func:`fit_runs` of the R runs ``run`` with distinct parameters and most ≥ 1: their
    knot vectors at the most spans, Schoenberg–Whitney and basis values all at once (as
    :func:`_fit_with_spans` computes them for one), then one factorisation each.

    Args:
        pts_all: (M, 2) points; t: (Σ sizes,) the runs' parameters, run after run;
        run: (R,) indices of the runs into ``results``; starts: first point of every run;
        sizes, lengths, most: (R,) points, parameter length and most spans of each run;
        results: the list to fill in.
    """
    R = run.shape[0]
    n = most + p
    # knot vectors, bit for bit as _fit_with_spans builds them (start 0: 0 + x is x)
    k_owner, k_local = _groups(n + p + 1)
    K = lengths[k_owner] * ((k_local - p) / most[k_owner])
    K[k_local <= p] = 0.0
    end_knot = np.flatnonzero(k_local >= n[k_owner])
    K[end_knot] = lengths[k_owner[end_knot]]
    knot_start = np.concatenate([[0], np.cumsum(n + p + 1)])
    domain = (k_local[:-1] >= p) & (k_local[:-1] < n[k_owner[:-1]])
    empty = np.bincount(k_owner[:-1], weights=domain & ~(K[1:] > K[:-1]), minlength=R) > 0
    # Schoenberg–Whitney of every run (as _fit_with_spans), all runs in one searchsorted of
    # complex keys (run, value), which compare run first
    row_owner = np.repeat(np.arange(R), sizes)
    row_start = np.concatenate([[0], np.cumsum(sizes)])
    t_keys = row_owner + 1j * t
    cp_owner, cp_index = _groups(n)
    at = knot_start[cp_owner] + cp_index
    first = np.searchsorted(t_keys, cp_owner + 1j * K[at], side="right") - row_start[cp_owner]
    first[cp_index == 0] = 0
    last = np.searchsorted(t_keys, cp_owner + 1j * K[at + p + 1], side="left") - row_start[cp_owner]
    final = np.cumsum(n) - 1
    last[final] = sizes
    big = int(sizes.max()) + int(n.max()) + 1
    offset = cp_owner * big
    matched = cp_index + np.maximum.accumulate(first - cp_index + offset) - offset
    sw = np.bincount(cp_owner, weights=matched >= last, minlength=R) == 0
    # every row's span (find_span: no span is empty where it is used) and basis values
    span = np.searchsorted(k_owner + 1j * K, t_keys, side="right") - 1
    np.maximum(span, knot_start[row_owner] + p, out=span)
    np.minimum(span, knot_start[row_owner] + n[row_owner] - 1, out=span)
    _, values = basis_functions(K, p, t, span=span)
    beta = values[0]
    col = span - knot_start[row_owner] - p
    failed = []
    for j in range(R):
        i = int(run[j])
        a, b = row_start[j], row_start[j + 1]
        pts = pts_all[starts[i]: starts[i] + (b - a)]
        t_run = t[a:b].copy()
        if empty[j]:  # fit_curve leaves such a count to its search
            results[i] = _fit_or_none(pts, p, spacing_m, max_noise_gain)
            continue
        if sw[j]:
            m = b - a
            collocation = np.zeros((m, int(n[j])))
            collocation[_arange(m)[:, None], col[a:b, None] + _arange(p + 1)] = beta[a:b]
            phi = least_squares_operator(collocation, max_noise_gain)
            if phi is not None:
                knots = K[knot_start[j]: knot_start[j + 1]].copy()
                results[i] = FitResult(curve=BSplineCurve.unchecked(phi @ pts, knots, p), phi=phi, params=t_run)
                continue
        # the most spans fail: fit_curve's search from one fewer, for all such runs at once
        failed.append((i, pts, t_run, int(most[j]) - 1))
    if _DIRECT_TRIES != 1:  # pragma: no cover - fit_curve's further direct tries first
        for i, pts, t_run, fewer in failed:
            try:
                results[i] = _fit_from(pts, t_run, t_run, np.ones(t_run.shape[0], dtype=np.intp), p, fewer,
                                       fewer + 1, max_noise_gain, _DIRECT_TRIES - 1)
            except FitError:
                results[i] = None
        return
    failed = [f for f in failed if f[3] >= 1]          # no count left: FitError (None)
    if not failed:
        return
    searched = _surviving_counts([(t_run, t_run, _ones(t_run.shape[0]), fewer) for _, _, t_run, fewer in failed],
                                 p, max_noise_gain)
    for (i, pts, t_run, _), counts in zip(failed, searched):
        results[i] = _first_fit(pts, t_run, t_run, counts, p, max_noise_gain)


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
def _interior_ratios(spans: int) -> np.ndarray:
    """``np.arange(1, spans) / spans`` (read-only, cached): the interior knots' fractions
    of the length, as clamped_knots_with_spans computes them."""
    ratios = np.arange(1, spans) / spans
    ratios.setflags(write=False)
    return ratios


@functools.lru_cache(maxsize=1024)
def _ones(n: int) -> np.ndarray:
    """``np.ones(n, dtype=np.intp)``, read-only and cached: multiplicities of distinct data."""
    ones = np.ones(n, dtype=np.intp)
    ones.setflags(write=False)
    return ones


@functools.lru_cache(maxsize=1024)
def _arange(n: int) -> np.ndarray:
    """``np.arange(n)``, read-only and cached (fits ask for the same few sizes)."""
    index = np.arange(n)
    index.setflags(write=False)
    return index


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

    Schoenberg–Whitney follows from the knots and the distinct parameters alone (as in
    :func:`iter_span_counts`); one basis evaluation at the m parameters gives the
    collocation matrix.

    Args:
        pts: (m, 2) data points (m); t: (m,) their non-decreasing parameters (m).
        distinct: (d,) the distinct values of ``t``.
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
    knots[p + 1 : n] = start + float(t[-1] - t[0]) * _interior_ratios(spans)
    knots[n:] = t[-1]
    if not np.all(knots[p + 1 : n + 1] > knots[p:n]):
        return None
    # Schoenberg–Whitney: the first and last datum of every support (iter_span_counts)
    first = np.searchsorted(distinct, knots[:n], side="right")
    first[0] = 0
    last = np.searchsorted(distinct, knots[p + 1 :], side="left")
    last[-1] = distinct.shape[0]
    index = _arange(n)
    if not np.all(index + np.maximum.accumulate(first - index) < last):
        return _REJECTED
    # find_span, and the search's lookup, as no span is empty
    span = np.searchsorted(knots, t, side="right") - 1
    np.maximum(span, p, out=span)
    np.minimum(span, n - 1, out=span)
    _, values = basis_functions(knots, p, t, span=span)
    collocation = np.zeros((t.shape[0], n))
    collocation[_arange(t.shape[0])[:, None], span[:, None] - p + _arange(p + 1)] = values[0]
    phi = least_squares_operator(collocation, max_noise_gain)
    if phi is None:
        return _REJECTED
    return FitResult(curve=BSplineCurve.unchecked(phi @ pts, knots, p), phi=phi, params=t)
