"""Compiled steps of the filter: data association (:func:`bsslam.slam.association.associate`,
:func:`match_pairs`) and its inputs (:func:`association_frame`,
:func:`association_thresholds`), the stacked Jacobian of a scan's beams
(:func:`stack_jacobian`) and the covariance's block reads (:func:`take_block`).

A scan's association is tens of (observed, map) spline pairs, each asking a few numbers
(two boxes, a few dozen control-point distances, four curve points). Written as
whole-array numpy, every step is one or more numpy calls of a few microseconds whatever
the number of pairs, and the steps were about two thirds of association's time (the rest
is the closest-point searches, already compiled: :mod:`bsslam.spline.kernels`). These
loops take the pairs one by one and do, for each, the floating-point operations of the
numpy form they replaced, in the same order (numba's strict IEEE arithmetic, see
:mod:`bsslam.compiled`), so the matches and their parameters are bit-identical to it
(checked on every association call of an intel-rawodom run and of the simulated corridor
of ``benchmarks/bench_filter.py``).

Curves are given as in :mod:`bsslam.spline.kernels`: ``coeffs_t`` (p+1, 2, S), pieces
``piece_lo`` (S,) and ``piece_start`` (C+1,), domains ``lo``, ``hi`` (C,), stacked control
points (N, 2) with ``cp_start`` (C+1,).
"""

from __future__ import annotations

import math

import numpy as np

from bsslam.compiled import jit
from bsslam.spline.kernels import bbox, closest_newton, first_per_group, piece_coefficients, point_at, sampled_minima


@jit
def _smallest_gap2(cp_a, first_a, end_a, cp_b, first_b, end_b):
    """Smallest squared distance (m²) between control-point rows first_a … end_a − 1 of
    cp_a and first_b … end_b − 1 of cp_b: dx·dx + dy·dy as numpy's two-term
    ``einsum("ij,ij->i")`` adds it (no fused multiply-add), NaN if any is NaN (as
    np.minimum.reduceat)."""
    best = np.inf
    for i in range(first_a, end_a):
        for j in range(first_b, end_b):
            dx = cp_a[i, 0] - cp_b[j, 0]
            dy = cp_a[i, 1] - cp_b[j, 1]
            d2 = dx * dx + dy * dy
            if d2 < best or math.isnan(d2):    # a NaN best stays: comparisons with it are False
                best = d2
    return best


@jit
def control_point_gaps(cp_a, cp_start_a, cp_b, cp_start_b, ia, ib):
    """(k,) smallest distance (m) between a control point of curve ``ia[j]`` of a and one
    of curve ``ib[j]`` of b, for k pairs."""
    out = np.empty(ia.shape[0])
    for j in range(ia.shape[0]):
        a, b = ia[j], ib[j]
        out[j] = math.sqrt(_smallest_gap2(cp_a, cp_start_a[a], cp_start_a[a + 1], cp_b, cp_start_b[b],
                                          cp_start_b[b + 1]))
    return out


@jit
def _point(coeffs_t, piece_lo, piece_start, lo, hi, c, t):
    """Point (x, y) of curve c at parameter t (m), clamped into its domain."""
    return point_at(coeffs_t, piece_lo, piece_start[c], piece_start[c + 1] - 1, lo[c], hi[c], t)


@jit
def gated_pairs(obs_cp, obs_cp_start, obs_coeffs_t, obs_piece_lo, obs_piece_start, obs_lo, obs_hi,
                map_cp, map_cp_start, candidates, gates):
    """The (observed, candidate) pairs that pass the gates, and the observed ends to query.

    A pair passes when its control polygons' bounding boxes are within ``gates[i, j]`` (m)
    of each other and so is its closest pair of control points (the boxes first: cheap,
    and what they reject the control points would too).

    Args:
        obs_*: the k observed curves (control points, their rows, coefficients, pieces,
            domains).
        map_cp, map_cp_start: the map's control points (N, 2) (m) and their rows (C+1,).
        candidates: (F,) map curves to try.
        gates: (k, F) gate of each pair (m).

    Returns:
        ``pairs`` (2, P): observed curve and candidate position of each passing pair,
        observed-major (``np.nonzero``'s order); ``ends`` (2P, 2) the observed curve's
        points at its domain's lower and upper end, pair by pair (m); ``curves`` (2P,) the
        map curve of each end (the closest-point queries). Few arrays: each returned one
        costs about a microsecond.
    """
    k, f = obs_cp_start.shape[0] - 1, candidates.shape[0]
    ob = np.empty((k, 4))
    for i in range(k):
        ob[i, 0], ob[i, 1], ob[i, 2], ob[i, 3] = bbox(obs_cp, obs_cp_start[i], obs_cp_start[i + 1])
    mb = np.empty((f, 4))
    for j in range(f):
        c = candidates[j]
        mb[j, 0], mb[j, 1], mb[j, 2], mb[j, 3] = bbox(map_cp, map_cp_start[c], map_cp_start[c + 1])
    pairs = np.empty((2, k * f), dtype=np.intp)
    n = 0
    for i in range(k):
        for j in range(f):
            g = gates[i, j]
            if (mb[j, 0] - ob[i, 2] > g or ob[i, 0] - mb[j, 2] > g
                    or mb[j, 1] - ob[i, 3] > g or ob[i, 1] - mb[j, 3] > g):
                continue
            c = candidates[j]
            gap = math.sqrt(_smallest_gap2(obs_cp, obs_cp_start[i], obs_cp_start[i + 1], map_cp, map_cp_start[c],
                                           map_cp_start[c + 1]))
            if not gap <= g:
                continue
            pairs[0, n] = i
            pairs[1, n] = j
            n += 1
    ends = np.empty((2 * n, 2))
    curves = np.empty(2 * n, dtype=np.intp)
    for p in range(n):
        i = pairs[0, p]
        for e in range(2):
            t = obs_lo[i] if e == 0 else obs_hi[i]
            ends[2 * p + e, 0], ends[2 * p + e, 1] = _point(obs_coeffs_t, obs_piece_lo, obs_piece_start, obs_lo,
                                                            obs_hi, i, t)
            curves[2 * p + e] = candidates[pairs[1, p]]
    return pairs[:, :n].copy(), ends, curves


@jit
def _at_ends(t, lo, hi):
    """Whether parameter t (m) is at the lower / upper end of the domain [lo, hi]: within
    10⁻⁶ of its length (at least 1 m)."""
    width = hi - lo
    if not (width >= 1.0 or math.isnan(width)):   # np.maximum(1.0, width), NaN kept
        width = 1.0
    tol = 1e-6 * width
    return t <= lo + tol, t >= hi - tol


@jit
def map_end_queries(t_ends, pairs, curves, map_coeffs_t, map_piece_lo, map_piece_start, map_lo, map_hi):
    """Where the closest map point to an observed end is its map spline's end: the map
    point there, to look up the observed point closest to it instead.

    Args:
        t_ends: (2P,) map parameter closest to each observed end (m), pair by pair.
        pairs: (2, P) observed curve (and candidate) of each pair; curves: (2P,) map curve
            of each end.
        map_*: the map curves' coefficients, pieces and domains.

    Returns:
        ``points`` (R, 2) the map end points (m) and ``observed`` (R,) their observed
        curves, for the R ends at either end of their map spline, in order of the ends.
    """
    m = t_ends.shape[0]
    at = np.empty(m, dtype=np.intp)
    r = 0
    for e in range(m):
        c = curves[e]
        low, high = _at_ends(t_ends[e], map_lo[c], map_hi[c])
        if low or high:
            at[r] = e
            r += 1
    points = np.empty((r, 2))
    observed = np.empty(r, dtype=np.intp)
    for j in range(r):
        e = at[j]
        points[j, 0], points[j, 1] = _point(map_coeffs_t, map_piece_lo, map_piece_start, map_lo, map_hi, curves[e],
                                            t_ends[e])
        observed[j] = pairs[0, e // 2]
    return points, observed


@jit
def accepted_pairs(t_ends, u_requeried, pairs, curves, feature_ids, deltas, obs_coeffs_t, obs_piece_lo,
                   obs_piece_start, obs_lo, obs_hi, map_coeffs_t, map_piece_lo, map_piece_start, map_lo, map_hi):
    """The pairs that match, with their parameters.

    Each pair's observed interval runs between its observed spline's ends, except where an
    end's closest map point is a map spline end: there it is the observed parameter closest
    to that map end (``u_requeried``, (R,), in the order of :func:`map_end_queries`). A
    pair matches when it is ordered alike (``t`` and ``u`` both increase from the first end
    to the second: not the far side of a wall, and some overlap) and both ends' observed
    and map points are within ``deltas[i, j]`` (m).

    Args:
        t_ends: (2P,) map parameters of each pair's two ends (m).
        pairs: (2, P) observed curve i and candidate position j of each pair; curves: (2P,)
            map curve of each end; feature_ids: (C,) id of each map curve.
        deltas: (k, F) match distance of each pair (m).

    Returns:
        The A accepted pairs, by observed curve then by u of their first end (stably: ties
        keep the pairs' order, as sorting each curve's matches did): ``values`` (A, 4)
        ``u_ini, u_fin, t_ini, t_fin`` (m); ``labels`` (A, 2) observed curve and feature
        id; ``at_end`` (A, 2) whether the first end is the map spline's lower end and the
        second its upper end.
    """
    n = pairs.shape[1]
    u_ends = np.empty(2 * n)
    at_end = np.empty((n, 2), dtype=np.bool_)
    r = 0
    for e in range(2 * n):
        i, c = pairs[0, e // 2], curves[e]
        low, high = _at_ends(t_ends[e], map_lo[c], map_hi[c])
        if e % 2 == 0:
            at_end[e // 2, 0] = low
        else:
            at_end[e // 2, 1] = high
        if low or high:
            u_ends[e] = u_requeried[r]
            r += 1
        else:
            u_ends[e] = obs_lo[i] if e % 2 == 0 else obs_hi[i]
    order = np.empty(n, dtype=np.intp)
    a = 0
    for p in range(n):
        i = pairs[0, p]
        u0, u1, t0, t1 = u_ends[2 * p], u_ends[2 * p + 1], t_ends[2 * p], t_ends[2 * p + 1]
        if not (t1 > t0 and u1 > u0):
            continue
        delta = deltas[i, pairs[1, p]]
        ok = True
        for e in range(2):
            ox, oy = _point(obs_coeffs_t, obs_piece_lo, obs_piece_start, obs_lo, obs_hi, i, u_ends[2 * p + e])
            mx, my = _point(map_coeffs_t, map_piece_lo, map_piece_start, map_lo, map_hi, curves[2 * p + e],
                            t_ends[2 * p + e])
            # both within δ is max(…) ≤ δ, NaN failing either way
            if not math.hypot(ox - mx, oy - my) <= delta:
                ok = False
        if not ok:
            continue
        # insertion into the observed curve's run, after any equal u (stable); pairs
        # come observed-major, so the run is the tail of ``order``
        j = a
        while j > 0 and pairs[0, order[j - 1]] == i and u_ends[2 * order[j - 1]] > u0:
            order[j] = order[j - 1]
            j -= 1
        order[j] = p
        a += 1
    values = np.empty((a, 4))
    labels = np.empty((a, 2), dtype=np.intp)
    flags = np.empty((a, 2), dtype=np.bool_)
    for q in range(a):
        p = order[q]
        values[q, 0], values[q, 1] = u_ends[2 * p], u_ends[2 * p + 1]
        values[q, 2], values[q, 3] = t_ends[2 * p], t_ends[2 * p + 1]
        labels[q, 0], labels[q, 1] = pairs[0, p], feature_ids[curves[2 * p]]
        flags[q, 0], flags[q, 1] = at_end[p, 0], at_end[p, 1]
    return values, labels, flags


@jit
def closest_parameters(coeffs_t, control_points, window, piece_lo, width, piece_start, lo, hi, curve, queries,
                       sample_step, samples_per_span, max_samples, max_newton, step_tolerance):
    """(q,) parameter (m) of the point of curve ``curve[j]`` closest to ``queries[j]``
    ((q, 2), m): ``closest_points_batch(batch, curve, queries)[0]`` with its sampling and
    Newton settings passed in, the same compiled steps in the same order (sampled starts,
    Newton from each, each query's best start)."""
    qx = queries[:, 0].copy()
    qy = queries[:, 1].copy()
    t_start, owner = sampled_minima(coeffs_t, control_points, window, piece_lo, width, piece_start, lo, hi, curve,
                                    qx, qy, sample_step, samples_per_span, max_samples)
    t, d2 = closest_newton(coeffs_t, piece_lo, piece_start, lo, hi, curve[owner], qx[owner], qy[owner], t_start,
                           max_newton, step_tolerance)
    return t[first_per_group(d2, owner, queries.shape[0])]


@jit
def match_pairs(obs_cp, obs_cp_start, obs_coeffs_t, obs_window, obs_piece_lo, obs_width, obs_piece_start, obs_lo,
                obs_hi, map_cp, map_cp_start, map_coeffs_t, map_window, map_piece_lo, map_width, map_piece_start,
                map_lo, map_hi, candidates, feature_ids, gates, deltas, sample_step, samples_per_span, max_samples,
                max_newton, step_tolerance):
    """Fig. 6 for every (observed, candidate) pair in one call: :func:`gated_pairs`, the
    closest map points to the observed ends (:func:`closest_parameters`),
    :func:`map_end_queries` and the observed points closest to those map ends, then
    :func:`accepted_pairs`, whose ``values``, ``labels`` and ``at_end`` it returns. Each
    step was one Python call of ``associate`` (with its arrays boxed and unboxed), the
    closest points several.

    Args:
        obs_*, map_*: the observed and map curves as :class:`~bsslam.spline.batch.CurveTable`
            and :class:`~bsslam.spline.batch.CurveBatch` hold them (stacked control
            points (N, 2), their rows, coefficients (p+1, 2, S), windows, pieces, domains).
        candidates: (F,) map curves to try; feature_ids: (C,) id of each map curve.
        gates, deltas: (k, F) control-point gate and match distance of each pair (m).
        sample_step … step_tolerance: the closest-point searches' settings
            (:func:`closest_parameters`).
    """
    pairs, ends, curves = gated_pairs(obs_cp, obs_cp_start, obs_coeffs_t, obs_piece_lo, obs_piece_start, obs_lo,
                                      obs_hi, map_cp, map_cp_start, candidates, gates)
    t_ends = closest_parameters(map_coeffs_t, map_cp, map_window, map_piece_lo, map_width, map_piece_start, map_lo,
                                map_hi, curves, ends, sample_step, samples_per_span, max_samples, max_newton,
                                step_tolerance)
    map_end, requeried = map_end_queries(t_ends, pairs, curves, map_coeffs_t, map_piece_lo, map_piece_start,
                                         map_lo, map_hi)
    u_requeried = np.empty(0)
    if requeried.shape[0]:
        u_requeried = closest_parameters(obs_coeffs_t, obs_cp, obs_window, obs_piece_lo, obs_width,
                                         obs_piece_start, obs_lo, obs_hi, requeried, map_end, sample_step,
                                         samples_per_span, max_samples, max_newton, step_tolerance)
    return accepted_pairs(t_ends, u_requeried, pairs, curves, feature_ids, deltas, obs_coeffs_t, obs_piece_lo,
                          obs_piece_start, obs_lo, obs_hi, map_coeffs_t, map_piece_lo, map_piece_start, map_lo,
                          map_hi)


# -- the filter's inputs to association --------------------------------------------------------

@jit
def _nan_max(a, b):
    """np.maximum of two numbers: NaN if either is, else the larger (the first if equal)."""
    if math.isnan(a) or a >= b:
        return a
    return b


@jit
def _nan_min(a, b):
    """np.minimum of two numbers: NaN if either is, else the smaller (the first if equal)."""
    if math.isnan(a) or a <= b:
        return a
    return b


@jit
def extreme_row(control_points, first, end, px, py, farthest):
    """Row of the control point nearest to (or farthest from) (px, py) (m) among rows
    first … end − 1: the smallest key d² (or −d²), d² = dx·dx + dy·dy, ties to the earlier
    row and NaN keys last, as a stable lexsort of the keys picks it."""
    best, best_key = -1, np.nan
    for r in range(first, end):
        dx = control_points[r, 0] - px
        dy = control_points[r, 1] - py
        d2 = dx * dx + dy * dy
        key = -d2 if farthest else d2
        if best < 0 or key < best_key or (math.isnan(best_key) and not math.isnan(key)):
            best, best_key = r, key
    return best


@jit
def _set_point_jacobian(J, i, pose, px, py):
    """J[i] (2, 3) = ∂p/∂(x, y, φ) of a point (px, py) (m) that moves rigidly with the pose."""
    J[i, 0, 0] = 1.0
    J[i, 1, 1] = 1.0
    J[i, 0, 2] = -(py - pose[1])
    J[i, 1, 2] = px - pose[0]


@jit
def point_jacobians(pose, points):
    """(k, 2, 3) ∂p/∂(x, y, φ) of k points (k, 2) (m) that move rigidly with the pose (3,):
    the identity, and the lever arm p − (x, y) turned by 90° in the last column."""
    J = np.zeros((points.shape[0], 2, 3))
    for i in range(points.shape[0]):
        _set_point_jacobian(J, i, pose, points[i, 0], points[i, 1])
    return J


@jit
def association_frame(map_cp, map_cp_start, map_power_basis, map_window, map_piece_start, state_rows, obs_cp,
                      obs_cp_start, obs_power_basis, obs_window, obs_piece_start, laser_pose, radius2, pose):
    """What association needs of a scan besides covariances, in one call.

    Args:
        map_cp: (N, 2) the map's control points (m); map_cp_start, map_power_basis,
            map_window, map_piece_start: its table; state_rows: (N, 2) their state rows
            (−1: fixed).
        obs_cp: (n, 2) the observed splines' control points in the world frame (m), with
            their table's obs_cp_start, obs_power_basis, obs_window, obs_piece_start.
        laser_pose: (3,) (m, m, rad); radius2: squared map radius (m²); pose: (3,) robot pose.

    Returns:
        ``candidates`` (F,) the map curves whose control-polygon box is within the map
        radius of the laser; ``near`` (F, 2) the state rows of each one's control point
        nearest to the laser; ``J`` (k, 2, 3) the pose Jacobian
        (:func:`point_jacobians`) of each observed spline's control point farthest from
        the laser; the coefficients (p+1, 2, S) of the candidates' pieces (NaN elsewhere)
        and of every observed piece (:func:`~bsslam.spline.kernels.piece_coefficients`).
    """
    lx, ly = laser_pose[0], laser_pose[1]
    n_map = map_cp_start.shape[0] - 1
    found = np.empty(n_map, dtype=np.intp)
    f = 0
    for c in range(n_map):
        x0, y0, x1, y1 = bbox(map_cp, map_cp_start[c], map_cp_start[c + 1])
        # distance from the laser to the box, as the numpy form's two np.maximum
        dx = _nan_max(_nan_max(x0 - lx, 0.0), lx - x1)
        dy = _nan_max(_nan_max(y0 - ly, 0.0), ly - y1)
        if dx * dx + dy * dy <= radius2:
            found[f] = c
            f += 1
    candidates = found[:f].copy()
    near = np.empty((f, 2), dtype=np.intp)
    for j in range(f):
        c = candidates[j]
        r = extreme_row(map_cp, map_cp_start[c], map_cp_start[c + 1], lx, ly, False)
        near[j, 0], near[j, 1] = state_rows[r, 0], state_rows[r, 1]
    k = obs_cp_start.shape[0] - 1
    J = np.zeros((k, 2, 3))
    for i in range(k):
        r = extreme_row(obs_cp, obs_cp_start[i], obs_cp_start[i + 1], lx, ly, True)
        _set_point_jacobian(J, i, pose, obs_cp[r, 0], obs_cp[r, 1])
    map_coeffs_t = piece_coefficients(map_power_basis, map_window, map_cp, candidates, map_piece_start)
    obs_coeffs_t = piece_coefficients(obs_power_basis, obs_window, obs_cp, np.arange(k), obs_piece_start)
    return candidates, near, J, map_coeffs_t, obs_coeffs_t


@jit
def _sigma(own, coupled, map_variance):
    """√max(own − 2·coupled + map_variance, 0), NaN kept, as relative_sigma's numpy form."""
    return math.sqrt(_nan_max(own - 2.0 * coupled + map_variance, 0.0))


@jit
def offset_sigma(own, coupled, map_variance):
    """(k, F) σ (m) of each (point, control point) offset from J P_pp Jᵀ's trace ``own``
    (k,), tr(J P_pc) ``coupled`` (k, F) and ``map_variance`` (F,) (m²)."""
    k, f = coupled.shape
    out = np.empty((k, f))
    for i in range(k):
        for j in range(f):
            out[i, j] = _sigma(own[i], coupled[i, j], map_variance[j])
    return out


@jit
def association_thresholds(own, coupled, map_diagonal, near, sigmas, match_m, max_match_m, gate_m):
    """(2, k, F) the control-point gate and the match distance (m) of each (observed,
    candidate) pair, both grown by ``sigmas`` σ of the pair's offset (:func:`offset_sigma`),
    the match distance capped at ``max_match_m``.

    Args:
        own, coupled: as :func:`offset_sigma`; map_diagonal: (2F,) the variances of the
            candidates' nearest control points' x and y (m²; anything where fixed);
            near: (F, 2) their state rows (−1: fixed, no variance).
        sigmas: σ multiple; match_m, gate_m: the thresholds before growing (m).
    """
    k, f = coupled.shape
    map_variance = np.zeros(f)
    for j in range(f):
        if near[j, 0] >= 0:
            map_variance[j] = map_diagonal[2 * j] + map_diagonal[2 * j + 1]
    out = np.empty((2, k, f))
    for i in range(k):
        for j in range(f):
            grow = sigmas * _sigma(own[i], coupled[i, j], map_variance[j])
            out[0, i, j] = gate_m + grow
            out[1, i, j] = _nan_min(match_m + grow, max_match_m)
    return out


# -- the stacked Jacobian ---------------------------------------------------------------------

@jit
def stack_jacobian(rows, window, real, state_rows, H_cp_x, H_cp_y, H_pose, n_state):
    """The columns and rows of the stacked range Jacobian of the beams ``rows``.

    Args:
        rows: (m,) the beams kept, indices into the per-beam arrays below.
        window: (k, p+1) control-point rows (in the map table) of each beam's hit piece;
            real: (k, p+1) False on padding entries.
        state_rows: (N, 2) state index of each control point's x and y (−1: not in the
            state, e.g. a fixed spline).
        H_cp_x, H_cp_y: (k, p+1) ∂z/∂x and ∂z/∂y of those control points; H_pose: (k, 3).
        n_state: the state size n.

    Returns:
        cols: (c,) the pose indices 0, 1, 2 then every state index the beams touch, in
        increasing order; H_c: (m, c) the Jacobian restricted to them (zeros elsewhere).
    """
    n_coef = window.shape[1]
    mark = np.zeros(n_state, dtype=np.bool_)
    for j in rows:
        for r in range(n_coef):
            if real[j, r]:
                for d in range(2):
                    idx = state_rows[window[j, r], d]
                    if idx >= 0:
                        mark[idx] = True
    pos = np.full(n_state, -1, dtype=np.intp)
    count = 3
    for i in range(3, n_state):          # control points are never the pose
        if mark[i]:
            pos[i] = count
            count += 1
    cols = np.empty(count, dtype=np.intp)
    cols[0], cols[1], cols[2] = 0, 1, 2
    for i in range(3, n_state):
        if pos[i] >= 0:
            cols[pos[i]] = i
    H_c = np.zeros((rows.shape[0], count))
    for a in range(rows.shape[0]):
        j = rows[a]
        H_c[a, 0], H_c[a, 1], H_c[a, 2] = H_pose[j, 0], H_pose[j, 1], H_pose[j, 2]
        for r in range(n_coef):
            if real[j, r]:
                idx = state_rows[window[j, r], 0]
                if idx >= 0:
                    H_c[a, pos[idx]] = H_cp_x[j, r]
                idx = state_rows[window[j, r], 1]
                if idx >= 0:
                    H_c[a, pos[idx]] = H_cp_y[j, r]
    return cols, H_c


@jit
def take_block(P, rows, cols):
    """(r, c) ``P[np.ix_(rows, cols)]`` (a new array): the filter reads blocks of tens of rows
    of its covariance several times a scan, where numpy's open-mesh indexing costs 4–6× this
    loop (53 × 75 entries: 36 µs against 8 µs). The indices must be valid: they are not
    checked."""
    out = np.empty((rows.shape[0], cols.shape[0]))
    for i in range(rows.shape[0]):
        r = rows[i]
        for j in range(cols.shape[0]):
            out[i, j] = P[r, cols[j]]
    return out


@jit
def curve_state_indices(state_rows, cp_start, curves, n):
    """(k,) sorted distinct state indices of the control points of ``curves`` (stacked rows
    ``cp_start[c] … cp_start[c+1] − 1`` of ``state_rows`` (N, 2); −1, a fixed control point,
    has none), for a state of size n: ``np.unique`` of those rows, by one mark per index."""
    mark = np.zeros(n, dtype=np.bool_)
    for i in range(curves.shape[0]):
        c = curves[i]
        for r in range(cp_start[c], cp_start[c + 1]):
            for k in range(2):
                if state_rows[r, k] >= 0:
                    mark[state_rows[r, k]] = True
    return np.flatnonzero(mark)
