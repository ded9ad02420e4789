"""Compiled inner loops of the least-squares spline fits (:mod:`bsslam.spline.fit`).

A scan's few segments are fitted one after another, and each fit asks small questions: a
knot vector, Schoenberg–Whitney, a few dozen basis evaluations, and, when the most spans
fail (as on the simulated corridor, every other scan), the same for up to ~30 smaller
span counts plus a noise-gain screen. Written as whole-array numpy each question was a
few dozen numpy calls of a few microseconds each; these loops answer it in about one.

What stays numpy: every reduction, the QR factorisation and triangular solve (LAPACK) and
``Φ @ points`` (BLAS), so that the results do not depend on how a compiled loop would sum.
The loops here do, per element, exactly the floating-point operations of the numpy forms
they replace, in the same order (strict IEEE, no fused multiply-add: see
:mod:`bsslam.compiled`), so fits are bit-identical to them (checked on ~6000 recorded
``extract_splines`` calls of the simulated corridor and of intel-rawodom; the tests check
them against the numpy forms, kept as oracles in ``tests/spline/fit_oracle.py``).
Binary searches reproduce ``np.searchsorted`` on sorted finite arrays.
"""

from __future__ import annotations

import math

import numpy as np

from bsslam.compiled import jit
from bsslam.spline.kernels import search_left, search_right


@jit
def _search_right(a, v):
    """``np.searchsorted(a, v, side="right")`` of a sorted (k,) a: the first index whose
    value exceeds v (k if none)."""
    return search_right(a, 0, a.shape[0], v)


@jit
def _search_left(a, v):
    """``np.searchsorted(a, v, side="left")`` of a sorted (k,) a: the first index whose
    value is at least v (k if none)."""
    return search_left(a, 0, a.shape[0], v)


@jit
def _span(knots, p, n, t):
    """Knot span of parameter t as the fits find it: the last knot at or before t, kept
    in the domain spans p … n − 1 (``searchsorted(…, side="right") − 1``, clipped)."""
    return min(max(_search_right(knots, t) - 1, p), n - 1)


@jit
def basis_row(knots, p, t, span, left, right, temp, out):
    """The p + 1 non-zero basis values at t on ``span`` into ``out`` (p+1,): the operations
    of :func:`bsslam.spline.basis._basis_values` (Piegl & Tiller A2.2) for one parameter.
    ``left``, ``right`` (p,) and ``temp`` (p,) are scratch."""
    for j in range(1, p + 1):
        left[j - 1] = t - knots[span + 1 - j]
        right[j - 1] = knots[span + j] - t
    out[0] = 1.0
    for j in range(1, p + 1):
        for r in range(j):           # from the values of degree j − 1, before any is replaced
            temp[r] = out[r] / (right[r] + left[j - 1 - r])
        out[j] = left[0] * temp[j - 1]
        for r in range(j - 1, 0, -1):
            out[r] = left[j - r] * temp[r - 1] + right[r] * temp[r]
        out[0] = right[0] * temp[0]


@jit
def _clamped_knots(start, end, length, spans, p):
    """(spans + 2p + 1,) clamped knots: start and end each p + 1 times around
    ``start + length · (j / spans)``, j = 1 … spans − 1, as ``clamped_knots_with_spans``
    computes them (with the exact end)."""
    n = spans + p
    knots = np.empty(n + p + 1)
    for i in range(p + 1):
        knots[i] = start
        knots[n + i] = end
    for j in range(1, spans):
        knots[p + j] = start + length * (j / spans)
    return knots


@jit
def run_parameters(chord, starts, sizes):
    """Chord-length parameters of consecutive point runs, each from 0.

    Args:
        chord: (M−1,) distances between consecutive points (m); starts, sizes: (S,) first
            point and number of points of each run.

    Returns:
        t: (Σ sizes,) every run's parameters, run after run (m), each run's running sum of
        its chords in order (the sums of ``np.cumsum``); distinct: (S,) bool, whether a
        run's parameters strictly increase.
    """
    S = starts.shape[0]
    t = np.empty(sizes.sum())
    distinct = np.ones(S, dtype=np.bool_)
    o = 0
    for i in range(S):
        acc = 0.0
        t[o] = acc
        for j in range(1, sizes[i]):
            step = chord[starts[i] + j - 1]
            if not step > 0.0:       # acc + step > acc exactly when step > 0 (finite)
                distinct[i] = acc + step > acc
            acc = acc + step
            t[o + j] = acc
        o += sizes[i]
    return t, distinct


@jit
def fit_setup(t, distinct, spans, p):
    """The fit on ``spans`` spans up to its factorisation: knot vector, Schoenberg–Whitney
    and collocation matrix (what ``fit._fit_with_spans`` needs before the QR).

    Args:
        t: (m,) non-decreasing data parameters (m); distinct: (d,) their distinct values.
        spans: span count ≥ 1; p: degree.

    Returns:
        status: 0 ready, 1 Schoenberg–Whitney fails (no collocation), 2 a domain span of
            the knot vector is empty (undecided: fit_curve's search decides);
        knots: (spans + 2p + 1,) the clamped knots on [t₀, t_m] (exact end);
        collocation: (m, spans + p) basis values B[j, i] (zeros unless status 0).
    """
    m = t.shape[0]
    n = spans + p
    knots = _clamped_knots(t[0], t[m - 1], t[m - 1] - t[0], spans, p)
    for i in range(p, n):
        if not knots[i + 1] > knots[i]:
            return 2, knots, np.zeros((0, n))
    # Schoenberg–Whitney: the greedy match of the support's first and last datum (fit's
    # iter_span_counts), a running maximum
    d = distinct.shape[0]
    top = -(1 << 62)
    for i in range(n):
        first = 0 if i == 0 else _search_right(distinct, knots[i])
        last = d if i == n - 1 else _search_left(distinct, knots[i + p + 1])
        top = max(top, first - i)
        if not i + top < last:
            return 1, knots, np.zeros((0, n))
    collocation = np.zeros((m, n))
    left, right, temp, beta = np.empty(p), np.empty(p), np.empty(p), np.empty(p + 1)
    for j in range(m):
        span = _span(knots, p, n, t[j])
        basis_row(knots, p, t[j], span, left, right, temp, beta)
        for r in range(p + 1):
            collocation[j, span - p + r] = beta[r]
    return 0, knots, collocation


@jit
def _block_bound(band, n, c, p, h, shift):
    """Schur complement s of the principal block of A = BᵀB on control points c − h … c + h
    onto c (neighbours outside 0 … n − 1 decoupled, the diagonal shifted by ``shift``), by
    symmetric elimination of the neighbours −h … −1, then h … 1: ``(M⁻¹)_cc = 1 / s``.

    ``band`` (n, p+1): ``band[i, e] = A[i, i + e]``. The operations of the numpy form,
    entry by entry: M[a, b] ← M[a, b] − M[a, q] · (M[b, q] / M[q, q]).
    """
    w = 2 * h + 1
    M = np.empty((w, w))
    for a in range(w):
        for b in range(w):
            gap = abs(a - b)
            row = c + min(a, b) - h
            inside = row >= 0 and row + gap < n and gap <= p
            if a == b:
                M[a, b] = band[row, 0] * shift if inside else 1.0
            else:
                M[a, b] = band[row, gap] if inside else 0.0
    col = np.empty(w)
    for k in range(2 * h):
        q = k if k < h else 3 * h - k       # pivots 0 … h−1, then 2h … h+1
        for a in range(w):
            col[a] = M[a, q]
        pivot = col[q]
        for b in range(w):
            ratio = col[b] / pivot
            for a in range(w):
                M[a, b] = M[a, b] - col[a] * ratio
    return M[h, h]


@jit
def _has_empty_span(distinct, most, p):
    """Whether the clamped knot vector on ``distinct``'s range of some span count
    ``most … 1`` has an empty domain span (a length of a few ulps of the start): the
    search then decides all the run's candidates from basis values."""
    d = distinct.shape[0]
    start, end = distinct[0], distinct[d - 1]
    length = end - start
    for spans in range(most, 0, -1):
        knots = _clamped_knots(start, end, length, spans, p)
        for i in range(p, spans + p):
            if not knots[i + 1] > knots[i]:
                return True
    return False


@jit
def _survives(distinct, multiplicity, spans, p, by_basis, screen, limit, few_data, h, shift):
    """Whether span count ``spans`` survives the search of :func:`span_survivors` (its
    Schoenberg–Whitney test and noise-gain screen; ``by_basis`` from
    :func:`_has_empty_span` over all the run's candidates)."""
    d = distinct.shape[0]
    start, end = distinct[0], distinct[d - 1]
    length = end - start
    left, right, temp = np.empty(p), np.empty(p), np.empty(p)
    beta = np.empty((d, p + 1))
    spans_at = np.empty(d, dtype=np.intp)
    n = spans + p
    knots = _clamped_knots(start, end, length, spans, p)
    first = np.empty(n, dtype=np.intp)
    last = np.empty(n, dtype=np.intp)
    if by_basis:
        # the data of each support: where its basis function is positive
        first[:] = d
        last[:] = -1
        for j in range(d):
            span = _span(knots, p, n, distinct[j])
            spans_at[j] = span
            basis_row(knots, p, distinct[j], span, left, right, temp, beta[j])
            for r in range(p + 1):
                if beta[j, r] > 0:
                    first[span - p + r] = min(first[span - p + r], j)
                    last[span - p + r] = max(last[span - p + r], j)
    else:
        # function i is non-zero exactly at the data strictly inside (ξ_i, ξ_{i+p+1})
        # (the first also at the start, the last at the end)
        for i in range(n):
            first[i] = 0 if i == 0 else _search_right(distinct, knots[i])
            last[i] = d - 1 if i == n - 1 else _search_left(distinct, knots[i + p + 1]) - 1
    top = -(1 << 62)
    for i in range(n):
        top = max(top, first[i] - i)
        if i + top > last[i] or last[i] < 0:
            return False
    if not screen:
        return True
    # the tested control points and the data their blocks need
    tested = np.zeros(n, dtype=np.bool_)
    needed = np.zeros(d, dtype=np.bool_)
    for i in range(n):
        if by_basis or last[i] - first[i] < few_data:
            tested[i] = True
            for j in range(first[max(i - h, 0)], last[min(i + h, n - 1)] + 1):
                needed[j] = True
    if by_basis:
        needed[:] = True
    # band of A = BᵀB from those data, in datum order (the sums of a bincount)
    band = np.zeros((n, p + 1))
    for j in range(d):
        if not needed[j]:
            continue
        if not by_basis:
            spans_at[j] = _span(knots, p, n, distinct[j])
            basis_row(knots, p, distinct[j], spans_at[j], left, right, temp, beta[j])
        c0 = spans_at[j] - p
        for ri in range(p + 1):
            wb = multiplicity[j] * beta[j, ri]
            for rj in range(ri, p + 1):
                band[c0 + ri, rj - ri] += wb * beta[j, rj]
    for i in range(n):
        if tested[i]:
            s = _block_bound(band, n, i, p, h, shift)
            if s > 0 and s * limit < 1.0:
                return False
    return True


@jit
def span_survivors(distinct, multiplicity, most, p, screen, limit, few_data, h, shift):
    """Which span counts ``most … 1`` fit_curve's search must still try (the decision of
    ``fit.iter_span_counts``): Schoenberg–Whitney on the distinct parameters and, with
    ``screen``, no tested control point whose local noise-gain bound surely exceeds the
    limit.

    Where every candidate's domain knots strictly increase, each support's first and last
    datum follow from the knots; a control point with fewer than ``few_data`` data in its
    support is tested, from the band of A built from the data of the supports of its
    block (all of them: fewer would bound too high). If some candidate has an empty span
    (a length of a few ulps of the start), all candidates of the run are decided from the
    basis values at every datum instead, and every control point is tested.

    Args:
        distinct: (d,) strictly increasing parameters (m); multiplicity: (d,) their counts.
        most: the largest span count ≥ 1; p: degree.
        screen: whether to screen; limit: ``max_noise_gain² · (1 + margin)``, a bound s of
            a control point is noisy when 0 < s and s · limit < 1.
        few_data, h, shift: fit's ``_SCREEN_FEW_DATA``, ``_SCREEN_HALF_WIDTH`` and
            ``1 + _SCREEN_SHIFT``.

    Returns:
        (most,) bool: whether span count ``most − i`` survives.
    """
    by_basis = _has_empty_span(distinct, most, p)
    keep = np.zeros(most, dtype=np.bool_)
    for spans in range(most, 0, -1):
        keep[most - spans] = _survives(distinct, multiplicity, spans, p, by_basis, screen, limit, few_data, h, shift)
    return keep


@jit
def next_fit_setup(t, distinct, multiplicity, most, below, p, screen, limit, few_data, h, shift):
    """The search of fit_curve one step at a time: the first span count ``below … 1``
    that survives :func:`span_survivors` (candidates ``most … 1``) and whose
    :func:`fit_setup` does not fail Schoenberg–Whitney, with that setup. The counts after
    the accepted one are never screened.

    Args:
        t: (m,) non-decreasing data parameters (m); distinct, multiplicity: (d,) their
            distinct values and counts; most: the search's largest count ≥ 1; below: the
            count to start from (≤ most); the rest as :func:`span_survivors`.

    Returns:
        spans: the count (0 if none is left); then :func:`fit_setup`'s status (0 ready,
        2 undecided), knots and collocation matrix for it.
    """
    by_basis = _has_empty_span(distinct, most, p)
    for spans in range(below, 0, -1):
        if not _survives(distinct, multiplicity, spans, p, by_basis, screen, limit, few_data, h, shift):
            continue
        status, knots, collocation = fit_setup(t, distinct, spans, p)
        if status != 1:
            return spans, status, knots, collocation
    return 0, 1, np.zeros(0), np.zeros((0, 0))


@jit
def rank_deficient(r, tolerance):
    """Whether R's smallest diagonal magnitude is at most ``tolerance`` times its largest:
    ``diag = np.abs(r.diagonal()); diag.min() <= tolerance * diag.max()`` of an (n, n) r,
    n ≥ 1, in one call instead of eight (a min or max does not round; a NaN on the
    diagonal makes both NaN, and the comparison False, as in numpy)."""
    lo = hi = abs(r[0, 0])
    for i in range(min(r.shape[0], r.shape[1])):
        v = abs(r[i, i])
        if math.isnan(v):
            return False
        if v < lo:
            lo = v
        if v > hi:
            hi = v
    return lo <= tolerance * hi
