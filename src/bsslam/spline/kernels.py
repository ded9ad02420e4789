"""Compiled inner loops of the batched spline searches (:mod:`bsslam.spline.batch`).

The filter asks its curves tens of small questions per scan (a few dozen beams, a few
curves). Written as whole-array numpy, each Newton step of such a question is a dozen numpy
calls of a few microseconds each, whatever the number of rays; compiled, a ray's whole
Newton run costs less than one of those calls. These kernels loop over rays (or starts) and
do, for each, exactly the floating-point operations of the numpy form they replace, in the
same order (no fused multiply-add, no reassociation: numba's default, strict IEEE), so the
results are bit-identical to it (checked on whole intel-rawodom runs, both passes). The
tests check them against the single-curve searches of :mod:`bsslam.spline.intersect` and
:mod:`bsslam.spline.closest`.

Conventions shared with :class:`~bsslam.spline.batch.CurveTable`: ``coeffs_t`` is (p+1, 2, S),
the Taylor coefficients of piece s at its start ``piece_lo[s]``; curve c owns pieces
``piece_start[c] … piece_start[c+1] − 1`` and the domain ``[lo[c], hi[c]]``.
"""

from __future__ import annotations

import math

import numpy as np

from bsslam.compiled import jit



@jit
def search_right(a, lo, hi, v):
    """``lo + np.searchsorted(a[lo:hi], v, side="right")`` for a sorted run a[lo:hi]: the
    first index of the run whose value exceeds v (hi if none)."""
    while lo < hi:
        mid = (lo + hi) >> 1
        if a[mid] <= v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@jit
def search_left(a, lo, hi, v):
    """``lo + np.searchsorted(a[lo:hi], v, side="left")`` for a sorted run a[lo:hi]: the
    first index of the run whose value is at least v (hi if none)."""
    while lo < hi:
        mid = (lo + hi) >> 1
        if a[mid] < v:
            lo = mid + 1
        else:
            hi = mid
    return lo


@jit
def piece_of(piece_lo, first, last, t):
    """Global index of the piece of a curve (pieces first … last) holding t: the last piece
    starting at or before t (t inside the curve's domain), as numpy's
    ``searchsorted(…, side="right") − 1`` finds it (pieces first+1 … last are bisected)."""
    return search_right(piece_lo, first + 1, last + 1, t) - 1


@jit
def _value_and_slope(coeffs_t, piece, u):
    """Point (x, y) and first derivative (x', y') of a piece at local u: Horner on both at
    once, in the order of the numpy form this replaced."""
    p = coeffs_t.shape[0] - 1
    vx, vy = coeffs_t[p, 0, piece], coeffs_t[p, 1, piece]
    dx, dy = 0.0, 0.0
    for i in range(p - 1, -1, -1):
        if i == p - 1:
            dx, dy = vx, vy
        else:
            dx, dy = dx * u + vx, dy * u + vy
        vx, vy = vx * u + coeffs_t[i, 0, piece], vy * u + coeffs_t[i, 1, piece]
    return vx, vy, dx, dy


@jit
def ray_newton(coeffs_t, piece_lo, piece_start, lo, hi, curve, ox, oy, cos, sin, t0, max_range,
               max_newton, step_tolerance, root_tolerance):
    """Newton ``t ← t − ỹ/ỹ'`` on each ray's own curve from finite guesses ``t0`` (k,),
    clamped to the curve's domain; a ray stops at its first step that does not move it (or
    is not finite). ``ox``, ``oy`` (k,) or (1,) ray origins (m), ``cos``, ``sin`` (k,) ray
    directions.

    Returns ok (k,) bool and the rows t, x̃ (range), x̃', ỹ' (4, k) at the final t, x̃ and ỹ
    measured along and across the ray; ok where |ỹ| ≤ root_tolerance and 0 < x̃ ≤ max_range.
    """
    k = t0.shape[0]
    ok = np.zeros(k, dtype=np.bool_)
    out = np.empty((4, k))
    shared = ox.shape[0] == 1
    for r in range(k):
        c = curve[r]
        first, last = piece_start[c], piece_start[c + 1] - 1
        a0, a1 = -sin[r], cos[r]                       # the across-ray row (−sin, cos)
        px, py = (ox[0], oy[0]) if shared else (ox[r], oy[r])
        t = min(max(t0[r], lo[c]), hi[c])
        for _ in range(max_newton):
            piece = piece_of(piece_lo, first, last, t)
            vx, vy, dx, dy = _value_and_slope(coeffs_t, piece, t - piece_lo[piece])
            yt = (vy - py) * a1 + (vx - px) * a0
            yt /= dy * a1 + dx * a0
            t_new = t - yt
            if not math.isnan(t_new):                  # np.maximum/minimum keep a NaN
                t_new = min(max(t_new, lo[c]), hi[c])
            if not math.isfinite(t_new):
                break
            step = abs(t_new - t)
            threshold = (abs(t_new) + 1.0) * step_tolerance
            t = t_new
            if not step > threshold:
                break
        piece = piece_of(piece_lo, first, last, t)
        vx, vy, dx, dy = _value_and_slope(coeffs_t, piece, t - piece_lo[piece])
        sx, sy = vx - px, vy - py
        xt = sx * cos[r] + sy * sin[r]
        yt = sy * a1 + sx * a0
        out[0, r] = t
        out[1, r] = xt
        out[2, r] = dx * cos[r] + dy * sin[r]
        out[3, r] = dy * a1 + dx * a0
        ok[r] = abs(yt) <= root_tolerance and xt > 0 and xt <= max_range
    return ok, out


@jit
def _value_slope_curvature(coeffs_t, piece, u):
    """Point, first and second derivative (x, y each) of a piece at local u: one Horner pass
    for all three, operation for operation the numpy form this replaced."""
    n = coeffs_t.shape[0]
    c0x, c0y = coeffs_t[0, 0, piece], coeffs_t[0, 1, piece]
    if n == 1:
        return c0x, c0y, 0.0, 0.0, 0.0, 0.0
    if n == 2:
        c1x, c1y = coeffs_t[1, 0, piece], coeffs_t[1, 1, piece]
        return c1x * u + c0x, c1y * u + c0y, c1x, c1y, 0.0, 0.0
    vx, vy = coeffs_t[n - 1, 0, piece], coeffs_t[n - 1, 1, piece]
    dx = dy = ddx = ddy = 0.0
    for i in range(n - 2, 0, -1):
        if i <= n - 3:                       # d exists
            if i == n - 3:                   # dd starts as d
                ddx, ddy = dx, dy
            else:
                ddx, ddy = ddx * u + dx, ddy * u + dy
        if i == n - 2:
            dx, dy = vx, vy
        else:
            dx, dy = dx * u + vx, dy * u + vy
        vx, vy = vx * u + coeffs_t[i, 0, piece], vy * u + coeffs_t[i, 1, piece]
    if n == 3:                               # no dd: the curvature is 2 d
        sxx, syy = dx * 2.0, dy * 2.0
    else:
        sxx, syy = (ddx * u + dx) * 2.0, (ddy * u + dy) * 2.0
    return vx * u + c0x, vy * u + c0y, dx * u + vx, dy * u + vy, sxx, syy


@jit
def _point(coeffs_t, piece, u):
    """Point (x, y) of a piece at local u: Horner, the operations of
    ``pieces.horner_with_derivatives`` with nder = 0."""
    n = coeffs_t.shape[0]
    vx, vy = coeffs_t[n - 1, 0, piece], coeffs_t[n - 1, 1, piece]
    if n == 1:
        return vx, vy
    for i in range(n - 2, 0, -1):
        vx, vy = vx * u + coeffs_t[i, 0, piece], vy * u + coeffs_t[i, 1, piece]
    return vx * u + coeffs_t[0, 0, piece], vy * u + coeffs_t[0, 1, piece]


@jit
def closest_newton(coeffs_t, piece_lo, piece_start, lo, hi, curve, qx, qy, t0, max_newton, step_tolerance):
    """Clamped, downhill-safeguarded Newton on f(t) = (s(t) − q)·s'(t) from K starts ``t0``
    (finite, on their curves ``curve``) for query points (qx, qy) (m): the best parameter
    seen per start and its squared distance, (K,) each.

    All starts are stepped until every one has converged, as the numpy form does (results
    depend on it: a converged start still takes its last tiny steps)."""
    k = t0.shape[0]
    t = t0.copy()
    t_best = t0.copy()
    d2_best = np.full(k, np.inf)
    tolerance = np.empty(k)
    for i in range(k):
        c = curve[i]
        tolerance[i] = step_tolerance * max(hi[c] - lo[c], max(abs(lo[c]), abs(hi[c])))
    for _ in range(max_newton):
        all_done = True
        for i in range(k):
            c = curve[i]
            ti = t[i]
            tc = min(max(ti, lo[c]), hi[c])
            piece = piece_of(piece_lo, piece_start[c], piece_start[c + 1] - 1, tc)
            sx, sy, s1x, s1y, s2x, s2y = _value_slope_curvature(coeffs_t, piece, tc - piece_lo[piece])
            ex, ey = sx - qx[i], sy - qy[i]
            d2 = ex * ex + ey * ey
            f = s1x * ex + s1y * ey
            fp = s2x * ex + s2y * ey
            if d2 < d2_best[i]:
                t_best[i] = ti
                d2_best[i] = d2
            speed2 = s1x * s1x + s1y * s1y
            fp += speed2
            if not fp > 0:
                fp = speed2
            t_new = ti - f / fp
            if math.isnan(t_new):
                t_new = ti
            else:
                t_new = min(max(t_new, lo[c]), hi[c])
            if not abs(t_new - ti) <= tolerance[i]:
                all_done = False
            t[i] = t_new
        if all_done:
            break
    for i in range(k):
        c = curve[i]
        tc = min(max(t[i], lo[c]), hi[c])
        piece = piece_of(piece_lo, piece_start[c], piece_start[c + 1] - 1, tc)
        px, py = _point(coeffs_t, piece, tc - piece_lo[piece])
        dx, dy = px - qx[i], py - qy[i]
        d2 = dx * dx + dy * dy
        if d2 <= d2_best[i] * (1.0 + 1e-12):
            t_best[i] = t[i]
            d2_best[i] = d2
    return t_best, d2_best


@jit
def sampled_minima(coeffs_t, control_points, window, piece_lo, width, piece_start, lo, hi, curve, qx, qy,
                   sample_step, samples_per_span, max_samples):
    """Starts for closest points: each query's curve sampled as one curve's
    ``closest_point`` samples it (every piece cut into ⌈control polygon / sample_step⌉
    equal parts, clipped to [samples_per_span, max_samples], then the curve's end), the
    discrete local minima of the squared distance to the query (strict on the left, loose
    on the right, so a plateau gives one) and both their neighbours.

    Args:
        control_points: (N, 2) stacked (m); window: (S, p+1) control-point rows per piece.
        curve: (q,) curve of each query; qx, qy: (q,) query points (m).

    Returns:
        (K,) start parameters (m) and (K,) their query: first every minimum's left
        neighbour, then the minima, then their right neighbours (queries in order within
        each part), the order of ``batch._sampled_minima``'s numpy form.
    """
    n_curves = lo.shape[0]
    used = np.zeros(n_curves, dtype=np.bool_)
    for c in curve:
        used[c] = True
    counts = np.zeros(piece_lo.shape[0], dtype=np.intp)
    grid_start = np.zeros(n_curves + 1, dtype=np.intp)   # only used curves have samples
    total = 0
    for c in range(n_curves):
        grid_start[c] = total
        if not used[c]:
            continue
        for s in range(piece_start[c], piece_start[c + 1]):
            polygon = 0.0
            for j in range(window.shape[1] - 1):
                dx = control_points[window[s, j + 1], 0] - control_points[window[s, j], 0]
                dy = control_points[window[s, j + 1], 1] - control_points[window[s, j], 1]
                polygon += math.sqrt(dx * dx + dy * dy)
            n = math.ceil(polygon / sample_step)
            if not n >= samples_per_span:          # NaN too: a diverged curve still samples
                n = samples_per_span
            counts[s] = min(n, max_samples)
            total += counts[s]
        total += 1                                 # the curve's end
    grid_start[n_curves] = total
    t_grid = np.empty(total)
    px = np.empty(total)
    py = np.empty(total)
    for c in range(n_curves):
        if not used[c]:
            continue
        g = grid_start[c]
        first, last = piece_start[c], piece_start[c + 1] - 1
        for s in range(first, last + 1):
            for part in range(counts[s]):
                t_grid[g] = piece_lo[s] + width[s] * (part / counts[s])
                g += 1
        t_grid[g] = hi[c]
        for g in range(grid_start[c], grid_start[c + 1]):
            t = min(max(t_grid[g], lo[c]), hi[c])
            piece = piece_of(piece_lo, first, last, t)
            px[g], py[g] = _point(coeffs_t, piece, t - piece_lo[piece])
    # the minima of each query's distances along its curve's samples
    n_q = curve.shape[0]
    size = 0
    for i in range(n_q):
        size += grid_start[curve[i] + 1] - grid_start[curve[i]]
    at = np.empty(size, dtype=np.intp)             # sample index of each minimum
    at_lo = np.empty(size, dtype=np.intp)          # its query's first and last sample
    at_hi = np.empty(size, dtype=np.intp)
    at_owner = np.empty(size, dtype=np.intp)
    found = 0
    for i in range(n_q):
        c = curve[i]
        g0, g1 = grid_start[c], grid_start[c + 1]
        prev = np.inf
        dx = qx[i] - px[g0]
        dy = qy[i] - py[g0]
        d2 = dx * dx + dy * dy
        for g in range(g0, g1):
            if g + 1 < g1:
                dx = qx[i] - px[g + 1]
                dy = qy[i] - py[g + 1]
                nxt = dx * dx + dy * dy
            else:
                nxt = np.inf
            if d2 < prev and d2 <= nxt:
                at[found] = g
                at_lo[found] = g0
                at_hi[found] = g1 - 1
                at_owner[found] = i
                found += 1
            prev = d2
            d2 = nxt
    t_start = np.empty(3 * found)
    owner = np.empty(3 * found, dtype=np.intp)
    for k in range(found):
        t_start[k] = t_grid[max(at[k] - 1, at_lo[k])]
        t_start[found + k] = t_grid[at[k]]
        t_start[2 * found + k] = t_grid[min(at[k] + 1, at_hi[k])]
        owner[k] = owner[found + k] = owner[2 * found + k] = at_owner[k]
    return t_start, owner


@jit
def point_at(coeffs_t, piece_lo, first, last, lo, hi, t):
    """Point (x, y) at parameter t (m) of the curve of pieces first … last and domain
    [lo, hi], t clamped into it: the operations of ``CurveBatch.evaluate`` for one
    parameter (np.minimum/np.maximum keep a NaN, which then gives a NaN point on whichever
    piece). The curve comes as scalars: every array argument of a call between compiled
    functions costs a reference count up and down (tens of ns each, more than the point)."""
    if not math.isnan(t):
        t = min(max(t, lo), hi)
    piece = piece_of(piece_lo, first, last, t)
    return _point(coeffs_t, piece, t - piece_lo[piece])


@jit
def evaluate_points(coeffs_t, piece_lo, piece_start, lo, hi, curve, t):
    """(m, 2) points (m) of curves ``curve`` (m,) at parameters t (m,) (clamped)."""
    out = np.empty((t.shape[0], 2))
    for i in range(t.shape[0]):
        c = curve[i]
        out[i, 0], out[i, 1] = point_at(coeffs_t, piece_lo, piece_start[c], piece_start[c + 1] - 1, lo[c], hi[c],
                                        t[i])
    return out


@jit
def bbox(control_points, first, end):
    """``x_min, y_min, x_max, y_max`` of control-point rows first … end − 1 (m). A NaN
    coordinate makes its bound NaN, as np.minimum / np.maximum propagate it (exact:
    a min or max does not round, so the order of the rows does not matter)."""
    x0 = x1 = control_points[first, 0]
    y0 = y1 = control_points[first, 1]
    for r in range(first + 1, end):
        x, y = control_points[r, 0], control_points[r, 1]
        # a NaN bound stays (every comparison with it is False); a NaN coordinate is taken
        if x < x0 or math.isnan(x):
            x0 = x
        if x > x1 or math.isnan(x):
            x1 = x
        if y < y0 or math.isnan(y):
            y0 = y
        if y > y1 or math.isnan(y):
            y1 = y
    return x0, y0, x1, y1


@jit
def bboxes(control_points, cp_start):
    """(C, 4) ``x_min, y_min, x_max, y_max`` (m) of the control points (N, 2) of each of
    the C curves, curve c owning rows ``cp_start[c] … cp_start[c+1] − 1``."""
    n = cp_start.shape[0] - 1
    out = np.empty((n, 4))
    for c in range(n):
        out[c, 0], out[c, 1], out[c, 2], out[c, 3] = bbox(control_points, cp_start[c], cp_start[c + 1])
    return out


@jit
def piece_coefficients(power_basis, window, control_points, curves, piece_start):
    """(p+1, 2, S) Taylor coefficients of the pieces of ``curves`` (NaN for every other
    piece): Σ_r power_basis[s, k, r] · control_points[window[s, r]], summed in order
    r = 0, 1, … as a numpy sum over r adds them (the tests keep that form as the oracle).

    Args:
        power_basis: (S, p+1, p+1); window: (S, p+1) control-point rows of each piece;
        control_points: (N, 2) (m); curves: (u,) curve indices; piece_start: (C+1,).
    """
    n_coef = power_basis.shape[1]
    out = np.full((n_coef, 2, power_basis.shape[0]), np.nan)
    for c in curves:
        for s in range(piece_start[c], piece_start[c + 1]):
            for k in range(n_coef):
                for d in range(2):
                    acc = power_basis[s, k, 0] * control_points[window[s, 0], d]
                    for r in range(1, n_coef):
                        acc += power_basis[s, k, r] * control_points[window[s, r], d]
                    out[k, d, s] = acc
    return out


@jit
def hit_basis(power_basis, piece_lo, piece_start, lo, hi, curve, t):
    """The piece (m,) holding each finite parameter ``t`` (m,) of curve ``curve`` (m,)
    (clamped into the curve's domain) and the values (m, p+1) of the basis functions of
    that piece's control-point window there: ``CurveTable.locate`` then
    ``basis_values``, the same Horner operations in the same order."""
    m = t.shape[0]
    n_coef = power_basis.shape[1]
    piece = np.empty(m, dtype=np.intp)
    beta = np.empty((m, n_coef))
    for j in range(m):
        c = curve[j]
        tc = min(max(t[j], lo[c]), hi[c])
        s = piece_of(piece_lo, piece_start[c], piece_start[c + 1] - 1, tc)
        piece[j] = s
        u = tc - piece_lo[s]
        for r in range(n_coef):
            v = power_basis[s, n_coef - 1, r]
            for i in range(n_coef - 2, -1, -1):
                v = v * u + power_basis[s, i, r]
            beta[j, r] = v
    return piece, beta


@jit
def first_per_group(key, group, n_groups):
    """Index of each group's smallest ``key`` among (k,) keys in groups ``group`` (k,)
    (values 0 … n_groups − 1), ties to the earlier entry and NaN keys last, as
    :func:`bsslam.spline.intersect.first_per_group`'s stable lexsort picks it; groups with
    no entry are left out (the result lists the others in increasing order)."""
    best = np.full(n_groups, -1, dtype=np.intp)
    for i in range(key.shape[0]):
        g = group[i]
        b = best[g]
        if b < 0 or key[i] < key[b] or (math.isnan(key[b]) and not math.isnan(key[i])):
            best[g] = i
    count = 0
    for g in range(n_groups):
        if best[g] >= 0:
            best[count] = best[g]
            count += 1
    return best[:count]


@jit
def basis_derivatives(knots, degree, t, span, nder):
    """Derivatives 0 … nder (per mᵏ) of the degree + 1 non-zero basis functions at each
    parameter, shape (nder+1, m, degree+1): Piegl & Tiller A2.3 per parameter, with the
    operations of the whole-array form (the tests' oracle) in its order, so bit for bit the
    same. ``span`` (m,) must be non-empty knot spans; orders above ``degree`` are zero."""
    p = degree
    m = t.shape[0]
    ders = np.zeros((nder + 1, m, p + 1))
    top = min(nder, p)  # derivatives of order > degree vanish
    ndu = np.empty((p + 1, p + 1))
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    a = np.empty((2, p + 1))
    for i in range(m):
        ti, s = t[i], span[i]
        # the triangle: upper part the basis functions of each degree, lower part the
        # knot differences (denominators, > 0 on a non-empty span)
        ndu[0, 0] = 1.0
        for j in range(1, p + 1):
            left[j] = ti - knots[s + 1 - j]
            right[j] = knots[s + j] - ti
            saved = 0.0
            for r in range(j):
                ndu[j, r] = right[r + 1] + left[j - r]
                temp = ndu[r, j - 1] / ndu[j, r]
                ndu[r, j] = saved + right[r + 1] * temp
                saved = left[j - r] * temp
            ndu[j, j] = saved
        for r in range(p + 1):
            ders[0, i, r] = ndu[r, p]
        for r in range(p + 1):
            a[:, :] = 0.0
            prev, nxt = 0, 1
            a[prev, 0] = 1.0
            for k in range(1, top + 1):
                d = 0.0
                rk, pk = r - k, p - k
                if r >= k:
                    a[nxt, 0] = a[prev, 0] / ndu[pk + 1, rk]
                    d = a[nxt, 0] * ndu[rk, pk]
                j1 = 1 if rk >= -1 else -rk
                j2 = k - 1 if r - 1 <= pk else p - r
                for j in range(j1, j2 + 1):
                    a[nxt, j] = (a[prev, j] - a[prev, j - 1]) / ndu[pk + 1, rk + j]
                    d = d + a[nxt, j] * ndu[rk + j, pk]
                if r <= pk:
                    a[nxt, k] = -a[prev, k - 1] / ndu[pk + 1, r]
                    d = d + a[nxt, k] * ndu[r, pk]
                ders[k, i, r] = d
                prev, nxt = nxt, prev
    factor = float(p)
    for k in range(1, top + 1):
        for i in range(m):
            for r in range(p + 1):
                ders[k, i, r] *= factor
        factor *= p - k
    return ders


@jit
def curve_table_arrays(K, n_knots, degrees):
    """All the arrays of :func:`bsslam.spline.batch.curve_table` in one call: C curves with
    knot vectors stacked in K (n_knots (C,) each) and degrees (C,), padded to the largest
    degree p. Each array a compiled function returns costs its caller a Python call, so
    the 1-D fields come packed by dtype and the caller slices them apart.

    Returns ``(ok, ints, floats, keys, window, real, power_basis)``:

    * ints (intp): ``cp_start (C+1) | piece_start (C+1) | break_start (C+1) |
      piece_curve (S) | last_piece (C)``;
    * floats: ``lo (C) | hi (C) | piece_lo (S) | width (S)``;
    * keys (complex): ``keys (S+C) | piece_keys (S)``, each ``curve + 1j·break`` with the
      operations numpy does for that sum (complex product (0 + 1j)·(x + 0j), then the sum);
    * window (S, p+1), real (S, p+1), power_basis (S, p+1, p+1): the table's fields;

    ok is False when a curve has no non-empty span (the other outputs are then
    meaningless). power_basis[s, k] is the k-th derivative of the basis functions of the
    piece's own degree at its start (:func:`basis_derivatives`, the curves of one degree
    in one call) divided by k!, as a float division by ``float(math.factorial(k))``: the
    running float product below is that number exactly up to 27!.
    """
    C = n_knots.shape[0]
    p = 0
    for c in range(C):
        p = max(p, degrees[c])
    total = 0
    for c in range(C):
        total += max(n_knots[c] - 2 * degrees[c] - 1, 0)   # spans degree … n_cp − 1: an upper bound
    span = np.empty(total, dtype=np.intp)
    local = np.empty(total, dtype=np.intp)
    owner = np.empty(total, dtype=np.intp)
    cp_start = np.zeros(C + 1, dtype=np.intp)
    piece_start = np.zeros(C + 1, dtype=np.intp)
    break_start = np.zeros(C + 1, dtype=np.intp)
    S = 0
    k0 = 0
    ok = True
    for c in range(C):
        d = degrees[c]
        n_cp = n_knots[c] - d - 1
        cp_start[c + 1] = cp_start[c] + n_cp
        first = S
        for j in range(d, n_cp):                      # the non-empty spans are the pieces
            if K[k0 + j] < K[k0 + j + 1]:
                span[S] = k0 + j
                owner[S] = c
                local[S] = j
                S += 1
        if S == first:
            ok = False
        piece_start[c + 1] = S
        break_start[c + 1] = break_start[c] + (S - first) + 1
        k0 += n_knots[c]
    ints = np.empty(3 * (C + 1) + S + C, dtype=np.intp)
    ints[: C + 1] = cp_start
    ints[C + 1: 2 * (C + 1)] = piece_start
    ints[2 * (C + 1): 3 * (C + 1)] = break_start
    ints[3 * (C + 1): 3 * (C + 1) + S] = owner[:S]
    for c in range(C):
        ints[3 * (C + 1) + S + c] = piece_start[c + 1] - 1
    floats = np.empty(2 * C + 2 * S)
    k0 = 0
    for c in range(C):
        floats[c] = K[k0 + degrees[c]]                           # lo
        floats[C + c] = K[k0 + n_knots[c] - degrees[c] - 1]      # hi
        k0 += n_knots[c]
    piece_lo = floats[2 * C: 2 * C + S]
    width = floats[2 * C + S:]
    window = np.empty((S, p + 1), dtype=np.intp)
    real = np.zeros((S, p + 1), dtype=np.bool_)
    breaks = np.empty(S + C)
    for s in range(S):
        c = owner[s]
        d = degrees[c]
        piece_lo[s] = K[span[s]]
        width[s] = K[span[s] + 1] - piece_lo[s]
        first_row = cp_start[c] + local[s] - d
        for r in range(p + 1):                        # padding repeats the last real row
            window[s, r] = first_row + min(r, d)
            real[s, r] = r <= d
        breaks[s + c] = piece_lo[s]                   # every curve's breaks in order, then its end
    for c in range(C):
        if piece_start[c + 1] > piece_start[c]:
            last = piece_start[c + 1] - 1
            breaks[last + c + 1] = piece_lo[last] + width[last]
    keys = np.empty(2 * S + C, dtype=np.complex128)
    for c in range(C):
        for i in range(break_start[c], break_start[c + 1]):
            x = breaks[i]
            keys[i] = complex(c + (0.0 * x - 0.0), 0.0 + (0.0 + x))
    for s in range(S):
        x = piece_lo[s]
        keys[S + C + s] = complex(owner[s] + (0.0 * x - 0.0), 0.0 + (0.0 + x))
    power_basis = np.zeros((S, p + 1, p + 1))
    if not ok:
        return ok, ints, floats, keys, window, real, power_basis
    factorials = np.empty(p + 1)
    factorials[0] = 1.0
    for k in range(1, p + 1):
        factorials[k] = factorials[k - 1] * k
    for d in range(p + 1):
        sel = np.empty(S, dtype=np.intp)
        n = 0
        for s in range(S):
            if degrees[owner[s]] == d:
                sel[n] = s
                n += 1
        if n == 0:
            continue
        sel = sel[:n]
        values = basis_derivatives(K, d, piece_lo[sel], span[sel], d)   # (d+1, n, d+1)
        for i in range(n):
            for k in range(d + 1):
                for r in range(d + 1):
                    power_basis[sel[i], k, r] = values[k, i, r] / factorials[k]
    return ok, ints, floats, keys, window, real, power_basis


@jit
def curve_points(knots, degree, control_points, t):
    """(m, 2) points (m) of one B-spline curve at parameters t (m,), clamped into its
    domain: the body of :meth:`BSplineCurve.evaluate <bsslam.spline.BSplineCurve.evaluate>`.

    Per parameter, the operations of the whole-array form (the tests' oracle: the span of
    :func:`~bsslam.spline.basis.find_span`, the values of
    :func:`~bsslam.spline.basis.basis_functions`, then ``einsum("mr,mrd->md")``, which sums
    over r in order) in its order, so bit for bit the same; a NaN parameter gives a NaN
    point on the last span, as there."""
    p = degree
    m = t.shape[0]
    n_knots = knots.shape[0]
    n_control = n_knots - p - 1
    lo, hi = knots[p], knots[n_control]
    first = search_right(knots, 0, n_knots, lo) - 1
    last = search_left(knots, 0, n_knots, hi) - 1
    out = np.empty((m, 2))
    n = np.empty(p + 1)
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    for i in range(m):
        ti = t[i]
        if math.isnan(ti):
            span = last        # numpy sorts NaN after every knot; np.clip keeps it NaN
        else:
            span = min(max(search_right(knots, 0, n_knots, ti) - 1, first), last)
            ti = min(max(ti, lo), hi)
        # Piegl & Tiller A2.2, as basis._basis_values does it (up and down products, the
        # first value the bare up product)
        n[0] = 1.0
        for j in range(1, p + 1):
            left[j] = ti - knots[span + 1 - j]
            right[j] = knots[span + j] - ti
            saved = 0.0
            for r in range(j):
                temp = n[r] / (right[r + 1] + left[j - r])
                up = right[r + 1] * temp
                n[r] = up if r == 0 else saved + up
                saved = left[j - r] * temp
            n[j] = saved
        base = span - p
        x = n[0] * control_points[base, 0]
        y = n[0] * control_points[base, 1]
        for r in range(1, p + 1):
            x = x + n[r] * control_points[base + r, 0]
            y = y + n[r] * control_points[base + r, 1]
        out[i, 0] = x
        out[i, 1] = y
    return out
