"""Compiled inner loops of spline extension (:mod:`bsslam.spline.extend`).

An extension tries span counts from the most down, and for each builds a knot vector,
unclamps the old end (row operations on a small matrix), checks Schoenberg–Whitney for
the new basis functions and evaluates a collocation matrix: as numpy, about three hundred
calls of a few microseconds each on arrays of a few dozen entries. Here it is one call.

What stays numpy: the least-squares operator (LAPACK), every matrix product (BLAS) and
the sort of the parameters. The loops do, per element, the floating-point operations of
the numpy forms they replace in the same order (strict IEEE, no fused multiply-add: see
:mod:`bsslam.compiled`), so the results are bit-identical to them; the tests check them
against those forms, kept as oracles in ``tests/spline/extend_oracle.py``.
"""

from __future__ import annotations

import numpy as np

from bsslam.compiled import jit
from bsslam.spline.fit_kernels import basis_row
from bsslam.spline.kernels import search_left, search_right

# extension_setup's status
READY, NO_SPANS, BAD_UNCLAMP = 0, 1, 2


@jit
def extended_knots(knots, p, right, end, spans):
    """:func:`bsslam.spline.extend.extended_knots`: the (len(knots) + spans,) knots of a
    curve of degree p grown by ``spans`` uniform spans up to ``end`` (m) at the right
    (``right``) or left end."""
    n_old = knots.shape[0] - p - 1
    out = np.empty(knots.shape[0] + spans)
    if right:
        old_end = knots[n_old]
        out[:n_old] = knots[:n_old]
        out[n_old] = old_end
        for j in range(1, spans):
            out[n_old + j] = old_end + (end - old_end) * (j / spans)
        for i in range(p + 1):
            out[n_old + spans + i] = end
    else:
        old_start = knots[p]
        for i in range(p + 1):
            out[i] = end
        for j in range(1, spans):
            out[p + j] = end + (old_start - end) * (j / spans)
        out[p + spans] = old_start
        out[p + spans + 1:] = knots[p + 1:]
    return out


@jit
def unclamp_valid(u, p, right, new):
    """Whether :func:`bsslam.spline.extend.unclamp` accepts ``new`` (p,) as the knots that
    replace the repeated ones of the (n + p + 2,) knot vector u at one end: finite,
    non-decreasing, the end clamped and all new knots beyond it."""
    for i in range(p):
        if not np.isfinite(new[i]):
            return False
        if i > 0 and new[i] - new[i - 1] < 0:
            return False
    n = u.shape[0] - p - 2
    if right:
        end = u[n + 1]
        for i in range(n + 1, u.shape[0]):
            if u[i] != end:
                return False
        return new[0] > end
    start = u[p]
    for i in range(p + 1):
        if u[i] != start:
            return False
    return new[p - 1] < start


@jit
def unclamp_transform(u, p, right, new):
    """The loops of :func:`bsslam.spline.extend.unclamp` (Piegl & Tiller A12.1): u, the
    (n + p + 2,) knot vector, is unclamped in place at one end by the (p,) knots ``new``
    (checked by :func:`unclamp_valid`); returns T (n + 1, n + 1), the map of the control
    points. Each row update is numpy's row expression, element by element."""
    n = u.shape[0] - p - 2
    transform = np.eye(n + 1)
    if right:
        for i in range(p - 1):
            u[n + i + 2] = new[i]
            for j in range(i, -1, -1):
                alpha = (u[n + 1] - u[n - j]) / (u[n - j + i + 2] - u[n - j])
                for c in range(n + 1):
                    transform[n - j, c] = (transform[n - j, c] - (1.0 - alpha) * transform[n - j - 1, c]) / alpha
        u[n + p + 1] = new[p - 1]
    else:
        for i in range(p - 1):
            u[p - i - 1] = new[p - i - 1]
            k = p - 1
            for j in range(i, -1, -1):
                alpha = (u[p] - u[k]) / (u[p + j + 1] - u[k])
                for c in range(n + 1):
                    transform[j, c] = (transform[j, c] - alpha * transform[j + 1, c]) / (1.0 - alpha)
                k -= 1
        u[0] = new[0]
    return transform


@jit
def _domain_spans(knots, p):
    """The first and last non-empty spans of the domain, as ``basis.find_span`` clips to."""
    n_control = knots.shape[0] - p - 1
    first = search_right(knots, 0, knots.shape[0], knots[p]) - 1
    last = search_left(knots, 0, knots.shape[0], knots[n_control]) - 1
    return first, last


@jit
def _span_of(knots, p, first, last, t):
    """``basis.find_span`` of one parameter: the last knot at or before t, clipped to the
    domain's spans."""
    return min(max(search_right(knots, 0, knots.shape[0], t) - 1, first), last)


@jit
def _clamped(knots, p, t):
    """t clamped into the domain as ``basis_functions`` does (``np.clip``)."""
    return min(max(t, knots[p]), knots[knots.shape[0] - p - 1])


@jit
def schoenberg_whitney(knots, p, distinct, c0, c1):
    """``fit.satisfies_schoenberg_whitney(knots, p, distinct, slice(c0, c1))``: whether
    basis functions c0 … c1 − 1 can be matched in order to distinct data parameters in
    their supports (where their computed value is positive), by the greedy running maximum.

    Args:
        knots: knot vector; p: degree; distinct: (d,) strictly increasing parameters (m).
    """
    n_control = knots.shape[0] - p - 1
    d = distinct.shape[0]
    first_row = np.full(n_control, d)
    last_row = np.full(n_control, -1)
    lo_span, hi_span = _domain_spans(knots, p)
    left, right, temp, beta = np.empty(p), np.empty(p), np.empty(p), np.empty(p + 1)
    for r in range(d):
        span = _span_of(knots, p, lo_span, hi_span, distinct[r])
        basis_row(knots, p, _clamped(knots, p, distinct[r]), span, left, right, temp, beta)
        for q in range(p + 1):
            if beta[q] > 0:
                b = span - p + q
                first_row[b] = min(first_row[b], r)
                last_row[b] = max(last_row[b], r)
    if c1 <= c0:
        return False
    for c in range(c0, c1):
        if last_row[c] < 0:
            return False
    top = -(1 << 62)
    for k in range(c1 - c0):
        top = max(top, first_row[c0 + k] - k)
        if k + top > last_row[c0 + k]:
            return False
    return True


@jit
def split_collocation(knots, p, t, c0, c1):
    """``collocation_matrix(knots, p, t)`` split by columns: (m, c1 − c0) columns c0 … c1 − 1
    and (m, n − (c1 − c0)) the others in order, each in Fortran order, as numpy's column
    gathers ``B[:, cols]`` give them (the layout decides how BLAS multiplies them)."""
    n_control = knots.shape[0] - p - 1
    m = t.shape[0]
    inside = np.zeros((c1 - c0, m)).T
    outside = np.zeros((n_control - (c1 - c0), m)).T
    lo_span, hi_span = _domain_spans(knots, p)
    left, right, temp, beta = np.empty(p), np.empty(p), np.empty(p), np.empty(p + 1)
    for j in range(m):
        span = _span_of(knots, p, lo_span, hi_span, t[j])
        basis_row(knots, p, _clamped(knots, p, t[j]), span, left, right, temp, beta)
        for q in range(p + 1):
            col = span - p + q
            if col < c0:
                outside[j, col] = beta[q]
            elif col < c1:
                inside[j, col - c0] = beta[q]
            else:
                outside[j, col - (c1 - c0)] = beta[q]
    return inside, outside


@jit
def extension_setup(knots, p, right, end, t, distinct, below):
    """The search of ``extend_curve`` up to its least squares: the first span count
    ``below … 1`` whose new basis functions pass Schoenberg–Whitney on the distinct
    parameters, with what the fit needs.

    Args:
        knots: the old curve's knots, clamped at the extended end; p: degree;
        right: extend past the end (else before the start); end: the new end (m);
        t: (k,) the new data's parameters; distinct: (d,) their distinct values, sorted.

    Returns:
        status: READY, NO_SPANS (none is left) or BAD_UNCLAMP (the count ``spans``'s new
            knots are refused by unclamping: the caller raises unclamp's error);
        spans; the extended knots; T (n_old, n_old) the unclamping map; the collocation
        matrix of t on the extended knots, split into the new columns (k, spans) and
        the old ones (k, n_old).
    """
    n_old = knots.shape[0] - p - 1
    empty, empty_f = np.zeros((0, 0)), np.zeros((0, 0)).T
    for spans in range(below, 0, -1):
        ext = extended_knots(knots, p, right, end, spans)
        # the degree knots next to the old end, taken from the final vector, drive the
        # unclamping, so the unclamped old part and the extended curve agree on it
        new = ext[n_old + 1:n_old + p + 1] if right else ext[spans:spans + p]
        if not unclamp_valid(knots, p, right, new):
            return BAD_UNCLAMP, spans, ext, empty, empty_f, empty_f
        transform = unclamp_transform(knots.copy(), p, right, new)
        c0 = n_old if right else 0
        if not schoenberg_whitney(ext, p, distinct, c0, c0 + spans):
            continue
        inside, outside = split_collocation(ext, p, t, c0, c0 + spans)
        return READY, spans, ext, transform, inside, outside
    return NO_SPANS, 0, np.zeros(0), empty, empty_f, empty_f
