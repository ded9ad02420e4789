""":func:`bsslam.spline.batch.curve_table` as it was written before its arrays came from one
compiled call: the layout loop (the former ``kernels.table_layout``, here in plain Python),
the power basis by :func:`bsslam.spline.basis.basis_functions` divided by the factorials,
the keys by ``np.repeat`` and a complex sum. The oracle the compiled form must match field
for field, bit for bit."""

import math

import numpy as np

from bsslam.spline.basis import basis_functions


def _layout(K, n_knots, degrees, p):
    C = n_knots.shape[0]
    cp_start = np.zeros(C + 1, dtype=np.intp)
    piece_start = np.zeros(C + 1, dtype=np.intp)
    break_start = np.zeros(C + 1, dtype=np.intp)
    lo, hi = np.empty(C), np.empty(C)
    span, owner, local = [], [], []
    k0 = 0
    ok = True
    for c in range(C):
        d = degrees[c]
        n_cp = n_knots[c] - d - 1
        cp_start[c + 1] = cp_start[c] + n_cp
        lo[c] = K[k0 + d]
        hi[c] = K[k0 + n_cp]
        first = len(span)
        for j in range(d, n_cp):
            if K[k0 + j] < K[k0 + j + 1]:
                span.append(k0 + j)
                owner.append(c)
                local.append(j)
        ok = ok and len(span) > first
        piece_start[c + 1] = len(span)
        break_start[c + 1] = break_start[c] + (len(span) - first) + 1
        k0 += n_knots[c]
    span, owner, local = (np.array(a, dtype=np.intp) for a in (span, owner, local))
    S = span.shape[0]
    piece_lo, width = np.empty(S), np.empty(S)
    window = np.empty((S, p + 1), dtype=np.intp)
    real = np.zeros((S, p + 1), dtype=np.bool_)
    breaks = np.empty(S + C)
    for s in range(S):
        c, d = owner[s], degrees[owner[s]]
        piece_lo[s] = K[span[s]]
        width[s] = K[span[s] + 1] - piece_lo[s]
        for r in range(p + 1):
            window[s, r] = cp_start[c] + local[s] - d + min(r, d)
            real[s, r] = r <= d
        breaks[s + c] = piece_lo[s]
    for c in range(C):
        last = piece_start[c + 1] - 1
        breaks[last + c + 1] = piece_lo[last] + width[last]
    return ok, cp_start, piece_start, lo, hi, span, owner, piece_lo, width, window, real, breaks, break_start


def curve_table_fields(knots, degrees) -> dict:
    """The table's fields (and ``piece_keys``, ``last_piece``) by name, or None when a curve
    has no non-empty domain."""
    degrees = np.asarray(degrees, dtype=np.intp).reshape(-1)
    p = int(degrees.max())
    n_knots = np.array([k.shape[0] for k in knots], dtype=np.intp)
    K = np.concatenate(knots).astype(float, copy=False)
    (ok, cp_start, piece_start, lo, hi, span, owner, piece_lo, width, window, real, breaks,
     break_start) = _layout(K, n_knots, degrees, p)
    if not ok:
        return None
    S = span.shape[0]
    factorials = np.array([math.factorial(k) for k in range(p + 1)], dtype=float)
    r = np.arange(p + 1)
    if degrees.min() == p:
        _, values = basis_functions(K, p, piece_lo, p, span=span)
        power_basis = np.empty((S, p + 1, p + 1))
        np.divide(values.transpose(1, 0, 2), factorials[None, :, None], out=power_basis)
    else:
        power_basis = np.zeros((S, p + 1, p + 1))
        for d in np.unique(degrees):
            sel = np.flatnonzero(degrees[owner] == d)
            d = int(d)
            _, values = basis_functions(K, d, piece_lo[sel], d, span=span[sel])
            power_basis[sel[:, None, None], r[None, : d + 1, None], r[None, None, : d + 1]] = (
                values.transpose(1, 0, 2) / factorials[None, : d + 1, None])
    C = len(knots)
    keys = np.repeat(np.arange(C), np.diff(break_start)) + 1j * breaks
    return dict(degree=degrees, p=p, cp_start=cp_start, piece_start=piece_start, lo=lo, hi=hi,
                piece_lo=piece_lo, width=width, piece_curve=owner, window=window, real=real,
                power_basis=power_basis, keys=keys, break_start=break_start,
                piece_keys=owner + 1j * piece_lo, last_piece=piece_start[1:] - 1)
