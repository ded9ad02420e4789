"""Compiled steps of limiting what a map spline says along itself to its significant bend
(:mod:`bsslam.slam.bends`): which splines are weighed and where their hits lie
(:func:`hit_groups`), the angle each turns between them and its gradient
(:func:`tangent_turns`), those gradients as rows over the state (:func:`gradient_rows`,
:func:`wall_angle_rows`, both stacked by :func:`along_rows`) and the Jacobian's rows scaled
along their splines or along one direction for all of them (:func:`scale_along_splines`,
:func:`scale_along`, :func:`scale_along_direction`). Written as numpy they were a few dozen
small array calls per linearisation, about a fifth of a simulated run's time; the numpy
forms are the oracles in ``tests/slam/test_bends.py``.
"""

from __future__ import annotations

import math

import numpy as np

from bsslam.compiled import jit
from bsslam.spline.kernels import piece_of


@jit
def tangent_turns(power_basis, window, real, piece_lo, piece_start, lo, hi, curve, t_first, t_last, control_points):
    """The angle Δθ each of g curves turns between two parameters, and its gradient over
    the control points the two tangents depend on.

    Args:
        power_basis, window, real, piece_lo, piece_start, lo, hi: a
            :class:`~bsslam.spline.batch.CurveTable`'s arrays.
        curve: (g,) curve indices; t_first, t_last: (g,) finite parameters on them (m),
            each located as :meth:`CurveTable.locate` does (clamped into its curve's domain,
            the last piece starting at or before it).
        control_points: (N, 2) the table's stacked control points (m).

    Returns:
        ``(bend, rows, grad)``: bend (g,) the tangent angle at the last parameter less that
        at the first, wrapped to (−π, π] (rad); rows (g, 2(p+1)) the control-point rows the
        tangents depend on, the first parameter's window then the last's; grad (g, 2(p+1),
        2) ∂Δθ/∂(x, y) of each (rad/m), zero on a window's padding (a row in both windows:
        its gradients add). The tangent angle of C'(t) = Σ_j β'_j(t) c_j moves by
        δθ = (C'_x δC'_y − C'_y δC'_x)/|C'|².
    """
    g = curve.shape[0]
    n2 = 2 * g
    w = window.shape[1]
    p = power_basis.shape[1] - 1
    angle = np.empty(n2)
    rows = np.empty((g, 2 * w), dtype=window.dtype)
    grad = np.zeros((g, 2 * w, 2))
    d_beta = np.empty(w)
    for m in range(n2):
        i = m % g
        c = curve[i]
        t = min(max(t_first[i] if m < g else t_last[i], lo[c]), hi[c])
        s = piece_of(piece_lo, piece_start[c], piece_start[c + 1] - 1, t)
        u = t - piece_lo[s]
        sign = -1.0 if m < g else 1.0
        offset = 0 if m < g else w
        dx = 0.0
        dy = 0.0
        for r in range(w):
            # β'_r(t) = Σ_k k · power_basis[s, k, r] · u^(k−1)
            value = 0.0
            if real[s, r]:
                power = 1.0
                for k in range(1, p + 1):
                    value += k * power_basis[s, k, r] * power
                    power *= u
            d_beta[r] = value
            row = window[s, r]
            dx += value * control_points[row, 0]
            dy += value * control_points[row, 1]
        scale = 1.0 / (dx * dx + dy * dy)
        angle[m] = math.atan2(dy, dx)
        for r in range(w):
            rows[i, offset + r] = window[s, r]
            grad[i, offset + r, 0] = -sign * d_beta[r] * dy * scale
            grad[i, offset + r, 1] = sign * d_beta[r] * dx * scale
    bend = np.empty(g)
    for i in range(g):
        a = angle[g + i] - angle[i]
        bend[i] = math.pi - (math.pi - a) % (2.0 * math.pi)
    return bend, rows, grad


@jit
def significance(signal, noise):
    """w = max(0, 1 − noise/signal) ∈ [0, 1] (floats): 0 for a signal within what the noise
    alone gives (and for no signal), → 1 for one far beyond it; continuous in both. No
    division by zero is ever made (the weight is 0 there). The numpy form is the oracle in
    ``tests/slam/test_bends.py``."""
    return 0.0 if signal <= noise else 1.0 - noise / signal


@jit
def bend_weights(bend, variance):
    """(g,) w = max(0, 1 − σ²/Δθ²) ∈ [0, 1] of each bend Δθ (g,) (rad) under its variance σ²
    (g,) (rad²) (:func:`significance`): 0 for a bend within its noise (and for no bend at
    all), → 1 for a significant one."""
    out = np.empty(bend.shape[0])
    for i in range(bend.shape[0]):
        out[i] = significance(bend[i] * bend[i], variance[i])
    return out


@jit
def scale_along_splines(H_c, cols, group, labels, weights, state_rows, cp_start):
    """Scale, in place, the part of each weighted spline's Jacobian rows along the spline's
    mean tangent (over its rows) by its weight (:mod:`bsslam.slam.bends`):
    :func:`scale_along` with each spline's :func:`mean_tangents`. The numpy form is the
    oracle in ``tests/slam/test_bends.py``.

    Args:
        H_c: (m, c) the stacked Jacobian on ``cols`` (c,) (state indices, the pose's x, y
            first).
        group: (m,) each row's spline (its curve index).
        labels: (L,) the curves to scale; weights: (L,) their weights w ∈ [0, 1).
        state_rows: (N, 2) the state indices of every curve's control points' x and y, curve
            c at rows ``cp_start[c] … cp_start[c+1]−1`` (:class:`~bsslam.slam.map_curves.MapCurves`).
    """
    scale_along(H_c, cols, group, labels, mean_tangents(H_c, group, labels), weights, state_rows, cp_start)


@jit
def _label_slots(group, labels):
    """(top,) the place of each curve index in ``labels`` (−1 for the others), for every
    index in ``group`` and ``labels``."""
    top = 0
    for i in range(group.shape[0]):
        top = max(top, group[i] + 1)
    for s in range(labels.shape[0]):
        top = max(top, labels[s] + 1)
    slot_of = np.full(top, -1, dtype=np.intp)
    for s in range(labels.shape[0]):
        slot_of[labels[s]] = s
    return slot_of


@jit
def mean_tangents(H_c, group, labels):
    """(L, 2) the unit mean tangent of each of the curves ``labels`` over its rows of
    ``H_c`` (m, c): the mean of its rows' unit normals g/|g| (g = the first two columns)
    turned a quarter left."""
    slot_of = _label_slots(group, labels)
    normal = np.zeros((labels.shape[0], 2))
    for i in range(H_c.shape[0]):
        s = slot_of[group[i]]
        if s >= 0:
            norm = np.sqrt(H_c[i, 0] * H_c[i, 0] + H_c[i, 1] * H_c[i, 1])
            normal[s, 0] += H_c[i, 0] / norm
            normal[s, 1] += H_c[i, 1] / norm
    tangent = np.empty((labels.shape[0], 2))
    for s in range(labels.shape[0]):
        norm = np.sqrt(normal[s, 0] * normal[s, 0] + normal[s, 1] * normal[s, 1])
        tangent[s, 0] = -normal[s, 1] / norm
        tangent[s, 1] = normal[s, 0] / norm
    return tangent


@jit
def scale_along(H_c, cols, group, labels, tangents, weights, state_rows, cp_start):
    """Scale, in place, the part of the Jacobian rows of each curve of ``labels`` along its
    unit direction ``tangents`` (L, 2) by its weight ``weights`` (L,) (rows of other curves
    are left alone). For every row ∂z/∂(x, y) = g and ∂z/∂(x_j, y_j) = −β_j g (paper
    (22)–(27)), so g is scaled in both: the robot and the spline moved along the direction
    alike, which no range sees before or after. One pass over the rows.

    Args: as :func:`scale_along_splines`; every labelled curve's control points must be in
    the state (``state_rows`` ≥ 0).
    """
    m = H_c.shape[0]
    slot_of = _label_slots(group, labels)
    size = 0
    for k in range(cols.shape[0]):
        size = max(size, cols[k] + 1)
    for s in range(labels.shape[0]):
        for k in range(cp_start[labels[s]], cp_start[labels[s] + 1]):
            size = max(size, state_rows[k, 0] + 1, state_rows[k, 1] + 1)
    position = np.full(size, -1, dtype=np.intp)
    for k in range(cols.shape[0]):
        position[cols[k]] = k
    for i in range(m):
        s = slot_of[group[i]]
        if s < 0:
            continue
        gx = H_c[i, 0]
        gy = H_c[i, 1]
        g2 = gx * gx + gy * gy
        tx = tangents[s, 0]
        ty = tangents[s, 1]
        removed = (1.0 - weights[s]) * (gx * tx + gy * ty)
        shift_x = removed * tx
        shift_y = removed * ty
        # β of the row's control points from H = −β g, before g changes
        for k in range(cp_start[labels[s]], cp_start[labels[s] + 1]):
            px = position[state_rows[k, 0]]
            py = position[state_rows[k, 1]]
            if px < 0 or py < 0:
                continue
            beta = -(H_c[i, px] * gx + H_c[i, py] * gy) / g2
            H_c[i, px] += beta * shift_x
            H_c[i, py] += beta * shift_y
        H_c[i, 0] -= shift_x
        H_c[i, 1] -= shift_y


@jit
def scale_along_direction(H_c, cols, group, labels, direction, weight, state_rows, cp_start):
    """:func:`scale_along` with one unit direction (2,) and one weight for every curve of
    ``labels`` (the scan's weakest direction, :func:`bsslam.slam.bends.wall_angle_weight`)."""
    tangents = np.empty((labels.shape[0], 2))
    tangents[:, 0] = direction[0]
    tangents[:, 1] = direction[1]
    scale_along(H_c, cols, group, labels, tangents, np.full(labels.shape[0], weight), state_rows, cp_start)


@jit
def hit_groups(group, hit_t, H_c, first_state_row):
    """The map splines a scan's rows hit whose control points are in the state, their
    extreme hits, their rows and what their rows weigh.

    Args:
        group: (m,) each row's spline (its curve index ≥ 0); hit_t: (m,) where each row's
            beam hits its spline (m); H_c: (m, c) the rows, ∂z/∂(x, y) = g first.
        first_state_row: (C,) the state index of each curve's first control point's x (−1
            for the fixed control points of localisation mode).

    Returns:
        ``(labels (L,), t_first (L,), t_last (L,), count (L,), weight (L,))`` in increasing
        curve order: count the rows of each, weight Σ |g|² over them.
    """
    m = group.shape[0]
    top = 0
    for i in range(m):
        top = max(top, group[i] + 1)
    count = np.zeros(top, dtype=np.intp)
    weight = np.zeros(top)
    lo = np.full(top, np.inf)
    hi = np.full(top, -np.inf)
    for i in range(m):
        c = group[i]
        count[c] += 1
        weight[c] += H_c[i, 0] * H_c[i, 0] + H_c[i, 1] * H_c[i, 1]
        lo[c] = min(lo[c], hit_t[i])
        hi[c] = max(hi[c], hit_t[i])
    n = 0
    for c in range(top):
        if count[c] >= 1 and first_state_row[c] >= 0:
            n += 1
    labels = np.empty(n, dtype=np.intp)
    t_first = np.empty(n)
    t_last = np.empty(n)
    rows = np.empty(n, dtype=np.intp)
    weights = np.empty(n)
    n = 0
    for c in range(top):
        if count[c] >= 1 and first_state_row[c] >= 0:
            labels[n] = c
            t_first[n] = lo[c]
            t_last[n] = hi[c]
            rows[n] = count[c]
            weights[n] = weight[c]
            n += 1
    return labels, t_first, t_last, rows, weights


@jit
def gradient_rows(union, state_index, grad, first_weight, last_weight):
    """Gradients as rows over the state indices ``union`` (k,) (sorted, holding every index
    of ``state_index``): A (g, k), A[i, union == s] the weighted sum of ``grad[i]``'s
    entries at state index s, the first half of each row's entries (the first parameter's
    window of :func:`tangent_turns`) weighted by ``first_weight``, the second by
    ``last_weight`` (1, 1: the bends; −½, ½: the mean of the two tangents' angles).

    Args:
        state_index: (g, r) the state index of each gradient entry, r even; grad: (g, r)
            its value.
    """
    g, r = state_index.shape
    half = r // 2
    A = np.zeros((g, union.shape[0]))
    for i in range(g):
        for j in range(r):
            weight = first_weight if j < half else last_weight
            A[i, np.searchsorted(union, state_index[i, j])] += weight * grad[i, j]
    return A


@jit
def wall_angle_rows(union, state_index, grad, info):
    """The walls' mean tangent angles relative to one another as rows over the state indices
    ``union`` (k,): A (g, k), row j the gradient of ψ_j = θ_j − Σ_k s_k θ_k, θ_j the mean of
    wall j's tangent angles at its two parameters (:func:`gradient_rows` with weights −½, ½
    of :func:`tangent_turns`' gradients) and s_k = info_k / Σ info its share (``info`` (g,),
    what each wall's rows weigh)."""
    A = gradient_rows(union, state_index, grad, -0.5, 0.5)
    g, k = A.shape
    total = 0.0
    for i in range(g):
        total += info[i]
    mean = np.zeros(k)
    for i in range(g):
        share = info[i] / total
        for j in range(k):
            mean[j] += share * A[i, j]
    for i in range(g):
        for j in range(k):
            A[i, j] -= mean[j]
    return A


@jit
def along_rows(union, state_index, grad, bent, info, walls):
    """The rows whose prior variances :meth:`~bsslam.slam.measurement.RangeModel.along_limits`
    asks for, stacked (b + g, k) over the state indices ``union`` (k,): the bends of the b
    curves where ``bent`` (g,) is True (:func:`gradient_rows`, weights 1, 1), then, when
    ``walls``, the relative angles of all g (:func:`wall_angle_rows`, with ``info`` (g,)).

    Args: ``state_index``, ``grad`` (g, r) as :func:`gradient_rows` takes them, for all g curves.
    """
    bends = gradient_rows(union, state_index[bent], grad[bent], 1.0, 1.0)
    if not walls:
        return bends
    angles = wall_angle_rows(union, state_index, grad, info)
    b = bends.shape[0]
    out = np.empty((b + angles.shape[0], union.shape[0]))
    out[:b] = bends
    out[b:] = angles
    return out
