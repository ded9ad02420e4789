"""Compiled bookkeeping of the filter's beams: which beams of a scan go to which map spline
(:func:`beam_groups`), the rows the innovation gates keep (:func:`select_rows`) and the
rows whitened against an error the beams on one spline share (:func:`whiten_shared`), and
the covariance of the beams' second-order errors (:func:`half_pair_traces`).

A scan has a handful of observed splines and matches and tens of beams. Written as numpy,
the assignment was a Python loop over the splines and their matches with a few masks,
``np.full``, the map parameter's line and concatenations per match (about 95 Python-level
calls a scan), and the selection seven fancy-indexing copies each time a gate ran. Here
each is one call. The only arithmetic is the map parameter's line, done as
``Match.map_parameter`` did it (strict IEEE, see :mod:`bsslam.compiled`), so the beams are
bit-identical to the numpy form (kept as the oracle in ``tests/slam/beam_groups_oracle.py``).
"""

from __future__ import annotations

import numpy as np

from bsslam.compiled import jit

#: Columns of the match table of :func:`beam_groups`.
MATCH_COLUMNS = ("spline", "beams", "u_ini", "u_fin", "t_ini", "t_fin", "curve")


@jit
def beam_groups(matches, beams, stride):
    """The beams of the matched intervals, each with its map curve and Newton start.

    Each observed spline's beams are assigned match by match, in the table's order (the
    association gives them by ``u_ini``): a beam inside several matched intervals goes to the
    first. With ``stride`` > 1 only every stride-th beam of a spline (its 0th, stride-th …)
    is used. The Newton start on the map spline is linear between the matched ends:
    ``t_ini + (u − u_ini)·(t_fin − t_ini)/(u_fin − u_ini)``.

    Args:
        matches: (M, 7) one row per match (columns :data:`MATCH_COLUMNS`): the observed
            spline (any label; the rows of one spline are consecutive), its number of beams
            n, the interval ``u_ini``, ``u_fin`` on it and ``t_ini``, ``t_fin`` on the map
            spline (m), the map spline's index in the filter's table. Float: the counts and
            indices are small integers, exact.
        beams: for each spline of ``matches`` in turn, its beams' parameters (n,) (m),
            bearings (n,) (rad) and ranges (n,) (m), back to back.
        stride: use every stride-th beam of a spline (≥ 1).

    Returns:
        ``(curve, values)``: the k assigned beams' map curves (k,) and their bearings,
        ranges and Newton starts ``values[0]``, ``values[1]``, ``values[2]`` (k,), spline by
        spline, match by match, in beam order within a match. (Two arrays, not four: each
        array a compiled call returns costs a Python-level call to box it.)
    """
    size = beams.shape[0] // 3
    curve = np.empty(size, dtype=np.intp)
    values = np.empty((3, size))
    k = 0
    start = 0   # the current spline's first entry in ``beams``
    n = 0
    taken = np.zeros(0, dtype=np.bool_)
    for r in range(matches.shape[0]):
        if r == 0 or matches[r, 0] != matches[r - 1, 0]:
            start += 3 * n
            n = int(matches[r, 1])
            taken = np.zeros(n, dtype=np.bool_)
            if stride > 1:
                for b in range(n):
                    taken[b] = b % stride != 0
        u_ini, u_fin, t_ini, t_fin = matches[r, 2], matches[r, 3], matches[r, 4], matches[r, 5]
        c = int(matches[r, 6])
        scale = (t_fin - t_ini) / (u_fin - u_ini)
        for b in range(n):
            u = beams[start + b]
            if not taken[b] and u >= u_ini and u <= u_fin:
                taken[b] = True
                curve[k] = c
                values[0, k] = beams[start + n + b]
                values[1, k] = beams[start + 2 * n + b]
                values[2, k] = t_ini + (u - u_ini) * scale
                k += 1
    return curve[:k], values[:, :k]


@jit
def select_rows(keep, beam, curve, bearings, ranges, H_c, residual, hit_t):
    """The rows in ``keep`` of a linearisation and their beams, Newton restarted from the
    rows' hit parameters.

    Args:
        keep: (m,) bool, the rows to keep; beam: (m,) each row's beam (index into
            ``curve``, ``bearings``, ``ranges``).
        curve, bearings, ranges: (b,) the linearised beams' map curves, bearings (rad) and
            ranges (m).
        H_c: (m, c) Jacobian rows; residual: (m,) (m); hit_t: (m,) hit parameters (m).

    Returns:
        ``(index, values, H_c)`` of the k kept rows: ``index`` (2, k) their beams' curves and
        their beam (0 … k−1: row j is beam j); ``values`` (5, k) their beams' bearings,
        ranges and Newton starts (the rows' hit parameters), the rows' residuals and hit
        parameters (the last a copy apart from the Newton starts); H_c (k, c) their
        Jacobian rows.
    """
    k = 0
    for j in range(keep.shape[0]):
        if keep[j]:
            k += 1
    n_cols = H_c.shape[1]
    index = np.empty((2, k), dtype=np.intp)
    values = np.empty((5, k))
    out_H = np.empty((k, n_cols))
    i = 0
    for j in range(keep.shape[0]):
        if keep[j]:
            b = beam[j]
            index[0, i] = curve[b]
            index[1, i] = i
            values[0, i] = bearings[b]
            values[1, i] = ranges[b]
            values[2, i] = hit_t[j]
            values[3, i] = residual[j]
            values[4, i] = hit_t[j]
            for col in range(n_cols):
                out_H[i, col] = H_c[j, col]
            i += 1
    return index, values, out_H


@jit
def whiten_shared(group, ratio, H_c, residual):
    """Rows whitened against noise R = r (I + ratio · Σ_g 1_g 1_gᵀ): independent beams of
    variance r plus an error of variance ratio·r shared by the beams of each group.

    Per group of n rows, W = I − α 1 1ᵀ with α = (1 − 1/√(1 + ratio·n))/n is the inverse
    square root of I + ratio 1 1ᵀ (W² (I + ratio 1 1ᵀ) = I), so W H and W ν with noise r I
    give the same update, NIS and gains as H and ν with the block R, at O(m c) instead of
    factorising an (m, m) R. The numpy oracle (an eigendecomposition of the dense R) is in
    ``tests/slam/test_beam_kernels.py``.

    Args:
        group: (m,) each row's group (small non-negative integers: map curve indices).
        ratio: shared variance over the independent one (≥ 0).
        H_c: (m, c) Jacobian rows; residual: (m,) (m).

    Returns:
        (W H_c (m, c), W residual (m,)).
    """
    m, n_cols = H_c.shape
    n_groups = 0
    for i in range(m):
        n_groups = max(n_groups, group[i] + 1)
    count = np.zeros(n_groups)
    sum_H = np.zeros((n_groups, n_cols))
    sum_r = np.zeros(n_groups)
    for i in range(m):
        g = group[i]
        count[g] += 1.0
        sum_r[g] += residual[i]
        for j in range(n_cols):
            sum_H[g, j] += H_c[i, j]
    alpha = np.zeros(n_groups)
    for g in range(n_groups):
        if count[g] > 0:
            alpha[g] = (1.0 - 1.0 / np.sqrt(1.0 + ratio * count[g])) / count[g]
    out_H = np.empty((m, n_cols))
    out_r = np.empty(m)
    for i in range(m):
        g = group[i]
        out_r[i] = residual[i] - alpha[g] * sum_r[g]
        for j in range(n_cols):
            out_H[i, j] = H_c[i, j] - alpha[g] * sum_H[g, j]
    return out_H, out_r


@jit
def half_pair_traces(Y, local):
    """(m, m) ½ tr(H_i P_{L_i L_j} H_j P_{L_j L_i}) of m functions, each with its symmetric
    Hessian H_i on its own L variables, under N(0, P): the covariance of their second-order
    errors (m²). Given ``Y`` (m, L, w) = H_i P[L_i, :] and ``local`` (m, L) each function's
    columns of P, it is ½ Σ_ac Y[i, a, L_j c] Y[j, c, L_i a]: L² products a pair, reading
    only the two functions' own columns. Exactly symmetric (each pair computed once). The
    numpy form (the (m L)² products gathered) is the oracle in
    ``tests/slam/second_order_oracle.py``."""
    m, L = local.shape
    out = np.empty((m, m))
    for i in range(m):
        for j in range(i, m):
            s = 0.0
            for a in range(L):
                la = local[i, a]
                for c in range(L):
                    s += Y[i, a, local[j, c]] * Y[j, c, la]
            out[i, j] = 0.5 * s
            out[j, i] = 0.5 * s
    return out
