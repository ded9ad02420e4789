"""The numpy forms of fit_curve's span search (``_surviving_counts`` and its noise-gain
screen) as they were before the search was compiled (bsslam.spline.fit_kernels): the
oracles the compiled search must match bit for bit."""

from __future__ import annotations

import functools

import numpy as np

from bsslam.spline.basis import basis_functions

_SCREEN_MARGIN = 1e-6


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
