"""Compiled linearisation of a scan's beams: the filter's observation model in one call.

The filter linearises the range model two or three times a scan. Written as numpy over the
beams (the observation model over a batch of curves, then the masks and
:func:`bsslam.slam.kernels.stack_jacobian`; that form is the tests' oracle,
``tests/slam/observation_oracle.py``) it was about 140 Python-level calls each time:
the map's coefficients, the ray Newton, the range Jacobians, the basis at the hits and the
stacking are each a handful of small numpy calls over tens of beams. Here the compiled
steps run back to back in one call. Only the transcendentals stay numpy (the cosines and
sines of the pose angle and the beam angles, computed once by the caller and used by the
intersection and the Jacobian alike): numba's may differ from numpy's in the last ulp.

Every other floating-point operation is the numpy form's, in its order (strict IEEE, see
:mod:`bsslam.compiled`), so the linearisation is bit-identical to the numpy path. The
compiled steps that already existed are called as they are
(:func:`bsslam.spline.kernels.ray_newton`, :func:`bsslam.spline.kernels.hit_basis`,
:func:`bsslam.slam.kernels.stack_jacobian`); the global search for beams whose Newton fails
(one or two calls in three on the simulated corridor: beams past a map spline's end) is
:func:`global_search`, loop for loop the numpy search of ``intersect_rays_batch``, now the
tests' oracle ``tests/spline/ray_oracle.py``. The tests check both against the numpy path
(random maps with misses, grazing beams, mixed degrees and fixed splines).

Maps are given as in :class:`~bsslam.slam.map_curves.MapCurves`: the
:class:`~bsslam.spline.batch.CurveTable` fields, ``state_rows`` (N, 2) (−1 for a fixed
control point) and the fixed control points (N, 2).
"""

from __future__ import annotations

import math

import numpy as np

from bsslam.compiled import jit
from bsslam.slam.kernels import stack_jacobian
from bsslam.spline.kernels import first_per_group, hit_basis, ray_newton


@jit
def used_curves(curve):
    """``np.unique`` of the beams' curve indices (m,) (non-negative): the distinct map curves,
    increasing (a mark per curve: a sort and its bookkeeping were ten numpy calls)."""
    if curve.shape[0] == 0:
        return np.empty(0, dtype=np.intp)
    mark = np.zeros(curve.max() + 1, dtype=np.bool_)
    for c in curve:
        mark[c] = True
    return np.flatnonzero(mark)


@jit
def used_coefficients(x, state_rows, fixed, power_basis, window, piece_start, curve):
    """(p+1, 2, S) Taylor coefficients of the pieces of the curves in ``curve`` (m,), the
    control points read from the state mean ``x`` (or fixed) as
    :meth:`MapCurves.control_points` reads them, summed as
    :func:`bsslam.spline.kernels.piece_coefficients` sums them. The other pieces are left
    unset (not even NaN: filling the whole map's pieces cost more than the used ones) and
    must not be read."""
    n_coef = power_basis.shape[1]
    out = np.empty((n_coef, 2, power_basis.shape[0]))
    done = np.zeros(piece_start.shape[0] - 1, dtype=np.bool_)
    for c in curve:
        if done[c]:
            continue
        done[c] = True
        for s in range(piece_start[c], piece_start[c + 1]):
            for k in range(n_coef):
                for d in range(2):
                    acc = power_basis[s, k, 0] * _control_point(x, state_rows, fixed, window[s, 0], d)
                    for r in range(1, n_coef):
                        acc += power_basis[s, k, r] * _control_point(x, state_rows, fixed, window[s, r], d)
                    out[k, d, s] = acc
    return out


@jit
def _control_point(x, state_rows, fixed, row, d):
    """Coordinate d of control point ``row`` (m): from the state when the point is in it
    (by its x row, as ``MapCurves.control_points``), else the fixed one."""
    if state_rows[row, 0] >= 0:
        return x[max(state_rows[row, d], 0)]
    return fixed[row, d]


@jit
def linearize_beams(x, state_rows, fixed, power_basis, window, real, piece_lo, width, piece_start, lo, hi, curve,
                    ranges, t0, cos_mu, sin_mu, cos_phi, sin_phi, offset, max_tan, max_range, max_newton,
                    step_tolerance, root_tolerance, grid, max_refine):
    """Ranges and stacked Jacobian of m beams, each against its own map curve, at the state
    mean ``x`` (n,): ``intersect_rays_batch`` of ``tests/spline/ray_oracle.py`` (Newton from
    the guesses, the global search where it fails), then :func:`stack_ranges`.

    Args:
        x: (n,) state mean; the robot pose is x[0:3].
        state_rows, fixed: (N, 2) state rows (−1: fixed) and fixed control points (m).
        power_basis, window, real, piece_lo, width, piece_start, lo, hi: the map's table.
        curve: (m,) map curve of each beam; ranges: (m,) measured ranges (m);
        t0: (m,) Newton start on the curve (m); a non-finite one goes to the global search.
        cos_mu, sin_mu: (m,) cosines and sines of the world beam angles
            μ = φ + φ_o + bearing; cos_phi, sin_phi: of the robot's heading φ = x[2].
        offset: (3,) laser pose in the robot frame (m, m, rad).
        max_tan: beams whose tangent ratio |r| exceeds it are grazing (dropped).
        max_range: hits farther than this (m) are misses.
        max_newton, step_tolerance, root_tolerance: the ray Newton's settings;
        grid: the global search's samples of a unit piece; max_refine: its bracketed
            Newton's iterations.

    Returns:
        As :func:`stack_ranges`.
    """
    m = curve.shape[0]
    coeffs_t = used_coefficients(x, state_rows, fixed, power_basis, window, piece_start, curve)
    # the laser's position, as bsslam.slam.measurement.laser_pose sums it; one for all rays
    ox = np.empty(1)
    oy = np.empty(1)
    ox[0] = x[0] + cos_phi * offset[0] - sin_phi * offset[1]
    oy[0] = x[1] + sin_phi * offset[0] + cos_phi * offset[1]
    ok, hits = ray_newton(coeffs_t, piece_lo, piece_start, lo, hi, curve, ox, oy, cos_mu, sin_mu, t0, max_range,
                          max_newton, step_tolerance, root_tolerance)
    todo = np.empty(m, dtype=np.intp)
    n_todo = 0
    for j in range(m):
        if not (ok[j] and math.isfinite(t0[j])):
            for i in range(4):
                hits[i, j] = np.nan
            todo[n_todo] = j
            n_todo += 1
    if n_todo:
        global_search(hits, todo[:n_todo], x, state_rows, fixed, coeffs_t, window, piece_lo, width, piece_start,
                      curve, ox[0], oy[0], cos_mu, sin_mu, grid, max_range, max_refine, step_tolerance)
    return stack_ranges(hits, x.shape[0], state_rows, power_basis, window, real, piece_lo, piece_start, lo, hi,
                        curve, ranges, cos_mu, sin_mu, cos_phi, sin_phi, offset, max_tan)


@jit
def global_search(hits, rays, x, state_rows, fixed, coeffs_t, window, piece_lo, width, piece_start, curve, ox, oy,
                  cos_mu, sin_mu, grid, max_range, max_refine, step_tolerance):
    """The global search of ``intersect_rays_batch`` (``_ray_global_search`` of
    ``tests/spline/ray_oracle.py``, then ``intersect.nearest_crossings``) for the beams
    ``rays`` (k,) from the laser at (ox, oy) (m): convex-hull culling of the (ray, piece)
    pairs, sampling at ``grid`` (of a unit piece), bracketed Newton (all brackets iterated
    until every one has converged, as the numpy form does: results depend on it) and each
    ray's nearest forward root. Writes the rows t, range, x̃', ỹ' of each hit into ``hits``
    (4, m) (the other columns are left)."""
    k = rays.shape[0]
    n_coef = coeffs_t.shape[0]
    total = 0
    for i in range(k):
        c = curve[rays[i]]
        total += piece_start[c + 1] - piece_start[c]
    pair_ray = np.empty(total, dtype=np.intp)      # position in ``rays``
    pair_piece = np.empty(total, dtype=np.intp)
    n_pairs = 0
    for i in range(k):
        j = rays[i]
        c = curve[j]
        cs, sn = cos_mu[j], sin_mu[j]
        for s in range(piece_start[c], piece_start[c + 1]):
            # the rotated control points of the piece: a NaN fails every test (as np.min/max)
            x_min, y_min, x_max, y_max = np.inf, np.inf, -np.inf, -np.inf
            finite = True
            for q in range(n_coef):
                dx = _control_point(x, state_rows, fixed, window[s, q], 0) - ox
                dy = _control_point(x, state_rows, fixed, window[s, q], 1) - oy
                xw = cs * dx + sn * dy
                yw = cs * dy - sn * dx
                if math.isnan(xw) or math.isnan(yw):
                    finite = False
                x_min, x_max = min(x_min, xw), max(x_max, xw)
                y_min, y_max = min(y_min, yw), max(y_max, yw)
            if finite and y_min <= 0 and y_max >= 0 and x_max > 0 and x_min <= max_range:
                pair_ray[n_pairs] = i
                pair_piece[n_pairs] = s
                n_pairs += 1
    # each pair's piece in its beam's frame (intersect.beam_frame_polynomials)
    cx = np.empty((n_coef, n_pairs))
    cy = np.empty((n_coef, n_pairs))
    for p in range(n_pairs):
        j = rays[pair_ray[p]]
        s = pair_piece[p]
        cs, sn = cos_mu[j], sin_mu[j]
        for q in range(n_coef):
            cx[q, p] = cs * coeffs_t[q, 0, s] + sn * coeffs_t[q, 1, s]
            cy[q, p] = cs * coeffs_t[q, 1, s] - sn * coeffs_t[q, 0, s]
        cx[0, p] -= cs * ox + sn * oy
        cy[0, p] -= cs * oy - sn * ox
    # sign changes of ỹ between samples, then exact zeros: the brackets, in that order
    n_grid = grid.shape[0]
    u = np.empty((n_pairs, n_grid))
    y = np.empty((n_pairs, n_grid))
    for p in range(n_pairs):
        w = width[pair_piece[p]]
        for g in range(n_grid):
            u[p, g] = w * grid[g]
            y[p, g] = _poly(cy, p, u[p, g])
    size = n_pairs * (2 * n_grid - 1)
    bracket = np.empty(size, dtype=np.intp)
    a = np.empty(size)
    b = np.empty(size)
    n_br = 0
    for p in range(n_pairs):
        for g in range(n_grid - 1):
            if (y[p, g] > 0) != (y[p, g + 1] > 0):
                bracket[n_br], a[n_br], b[n_br] = p, u[p, g], u[p, g + 1]
                n_br += 1
    for p in range(n_pairs):
        for g in range(n_grid):
            if y[p, g] == 0:
                bracket[n_br], a[n_br], b[n_br] = p, u[p, g], u[p, g]
                n_br += 1
    root = _refine_brackets(cy, bracket[:n_br], a[:n_br], b[:n_br], max_refine, step_tolerance)
    # the forward roots within range, and each ray's nearest
    kept = np.empty(n_br, dtype=np.intp)
    xt = np.empty(n_br)
    owner = np.empty(n_br, dtype=np.intp)
    n_kept = 0
    for e in range(n_br):
        v = _poly(cx, bracket[e], root[e])
        if v > 0 and v <= max_range:
            kept[n_kept] = e
            xt[n_kept] = v
            owner[n_kept] = pair_ray[bracket[e]]
            n_kept += 1
    best = first_per_group(xt[:n_kept], owner[:n_kept], k)
    for e in best:
        p = bracket[kept[e]]
        j = rays[owner[e]]
        r = root[kept[e]]
        hits[0, j] = piece_lo[pair_piece[p]] + r
        hits[1, j] = xt[e]
        hits[2, j] = _poly_derivative(cx, p, r)
        hits[3, j] = _poly_derivative(cy, p, r)


@jit
def _refine_brackets(c, pair, a, b, max_refine, step_tolerance):
    """``intersect._refine_brackets``: a root of polynomial ``c[:, pair[e]]`` in each bracket
    [a, b] (e,), Newton from the midpoint, bisection where a step leaves the shrinking
    bracket; every bracket is stepped until all have converged."""
    n = pair.shape[0]
    a = a.copy()
    b = b.copy()
    fa_positive = np.empty(n, dtype=np.bool_)
    x = np.empty(n)
    for e in range(n):
        fa_positive[e] = _poly(c, pair[e], a[e]) > 0
        x[e] = 0.5 * (a[e] + b[e])
    for _ in range(max_refine):
        converged = 0
        for e in range(n):
            xe = x[e]
            f = _poly(c, pair[e], xe)
            fp = _poly_derivative(c, pair[e], xe)
            if (f > 0) == fa_positive[e]:
                a[e] = xe
            else:
                b[e] = xe
            step = f / fp
            x_new = xe - step                  # Newton, kept where it stays inside (a, b)
            if not (x_new > a[e] and x_new < b[e]):
                x_new = 0.5 * (a[e] + b[e])
            at_root = abs(step) <= (abs(xe) + 1.0) * step_tolerance or f == 0
            if at_root:
                x_new = xe
            if at_root or x_new == xe:
                converged += 1
            x[e] = x_new
        if converged == n:
            break
    return x


@jit
def _poly(c, q, x):
    """Polynomial ``c[:, q]`` (ascending powers) at x: ``pieces.horner_rows``' Horner."""
    n = c.shape[0]
    if n == 1:
        return c[0, q]
    v = c[n - 1, q] * x + c[n - 2, q]
    for i in range(n - 3, -1, -1):
        v = v * x + c[i, q]
    return v


@jit
def _poly_derivative(c, q, x):
    """Derivative of polynomial ``c[:, q]`` at x: Horner on the coefficients i·c_i, as
    ``horner_rows(c[1:] * powers, x)`` (the products rounded alike)."""
    n = c.shape[0]
    if n == 2:
        return c[1, q] * 1.0
    v = c[n - 1, q] * float(n - 1) * x + c[n - 2, q] * float(n - 2)
    for i in range(n - 3, 0, -1):
        v = v * x + c[i, q] * float(i)
    return v


@jit
def stack_ranges(hits, n_state, state_rows, power_basis, window, real, piece_lo, piece_start, lo, hi, curve,
                 ranges, cos_mu, sin_mu, cos_phi, sin_phi, offset, max_tan):
    """The linearisation of m beams from their hits: the masks, the range Jacobians of
    ``_range_jacobians`` (tests/slam/observation_oracle.py) and the stacked Jacobian of the kept beams.

    Args:
        hits: (4, m) rows t, range, x̃', ỹ' of each beam's hit, NaN where it has none.
        n_state: the state size n. The other arguments: as :func:`linearize_beams`.

    Returns:
        ``(missed, grazing, cols, H_c, rows, values)``: the beams without a hit and the
        grazing ones (counts); the pose indices 0, 1, 2 and the touched state indices
        (c,) and the Jacobian (k, c) of the k kept beams ``rows`` (k,) (increasing);
        ``values`` (2, k) their residuals z − h(x) (m) and hit parameters (m).
    """
    m = curve.shape[0]
    keep = np.empty(m, dtype=np.intp)
    k = 0
    missed = 0
    grazing = 0
    for j in range(m):
        if not math.isfinite(hits[1, j]):
            missed += 1
        elif abs(hits[2, j] / hits[3, j]) > max_tan:    # NaN (0/0) is not grazing
            grazing += 1
        else:
            keep[k] = j
            k += 1
    rows = keep[:k].copy()
    t_kept = np.empty(k)
    curve_kept = np.empty(k, dtype=np.intp)
    for a in range(k):
        t_kept[a] = hits[0, rows[a]]
        curve_kept[a] = curve[rows[a]]
    piece, beta = hit_basis(power_basis, piece_lo, piece_start, lo, hi, curve_kept, t_kept)
    # ∂p_l/∂φ, the lever arm of an offset laser
    lever_x = -sin_phi * offset[0] - cos_phi * offset[1]
    lever_y = cos_phi * offset[0] - sin_phi * offset[1]
    n_coef = window.shape[1]
    win = np.empty((k, n_coef), dtype=np.intp)
    is_real = np.empty((k, n_coef), dtype=np.bool_)
    H_cp_x = np.empty((k, n_coef))
    H_cp_y = np.empty((k, n_coef))
    H_pose = np.empty((k, 3))
    values = np.empty((2, k))
    for a in range(k):
        j = rows[a]
        z = hits[1, j]
        r = hits[2, j] / hits[3, j]
        gx = -cos_mu[j] - r * sin_mu[j]
        gy = -sin_mu[j] + r * cos_mu[j]
        H_pose[a, 0] = gx
        H_pose[a, 1] = gy
        H_pose[a, 2] = z * r + gx * lever_x + gy * lever_y
        s = piece[a]
        for q in range(n_coef):
            win[a, q] = window[s, q]
            is_real[a, q] = real[s, q]
            H_cp_x[a, q] = -beta[a, q] * gx
            H_cp_y[a, q] = -beta[a, q] * gy
        values[0, a] = ranges[j] - z
        values[1, a] = hits[0, j]
    cols, H_c = stack_jacobian(np.arange(k), win, is_real, state_rows, H_cp_x, H_cp_y, H_pose, n_state)
    return missed, grazing, cols, H_c, rows, values
