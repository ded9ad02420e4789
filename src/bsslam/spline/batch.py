"""Many spline curves at once: evaluation, ray intersection and closest points over a
table of the polynomial pieces of all of them.

The filter asks the same questions of dozens of curves per scan (where does each beam hit
its map spline, which map point is closest to each observed spline end). Asked one curve
at a time, each question costs a fixed ~1 ms of Python and numpy call overhead. Here every
query carries the index of its own curve, the pieces of all curves sit in one array, and
each search is a single vectorised computation whatever the mix of curves.

Two layers:

* :class:`CurveTable` — what depends on the knots only: the pieces of every curve, and for
  each piece the power-basis form of its degree + 1 non-zero basis functions. It survives
  any change of the control points (the filter moves them at every update).
* :class:`CurveBatch` — a table plus control points: the per-piece polynomial coefficients,
  one tensor contraction away from the table.

Curves may differ in degree: the table is padded to the largest degree p with zero
coefficients (which Horner evaluates exactly), and a padded piece's control-point window
repeats its last real control point with zero weight.

The searches follow :func:`bsslam.spline.intersect_rays` and
:func:`bsslam.spline.closest_point` step for step (same starts, iterations, tolerances and
acceptance tests); results agree with them up to rounding.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bsslam.errors import SplineError
from bsslam.spline.basis import basis_functions
from bsslam.spline.closest import MAX_SAMPLES_PER_SPAN
from bsslam.spline.closest import _MAX_NEWTON as _CLOSEST_MAX_NEWTON
from bsslam.spline.closest import _STEP_TOLERANCE as _CLOSEST_STEP_TOLERANCE
from bsslam.spline.intersect import _MAX_NEWTON as _RAY_MAX_NEWTON
from bsslam.spline.intersect import _ROOT_TOLERANCE_M, _STEP_TOLERANCE, RayHits
from bsslam.spline.intersect import beam_frame_polynomials, nearest_crossings
from bsslam.spline.pieces import horner_with_derivatives


@dataclass(frozen=True, eq=False)
class CurveTable:
    """The knot structure of C curves with N control points in all and S pieces in all.

    Attributes:
        degree: (C,) polynomial degree of each curve; ``p`` is the largest.
        p: the padded degree of the table.
        cp_start: (C+1,) curve c owns control-point rows ``cp_start[c] … cp_start[c+1]−1``
            of a batch's stacked (N, 2) control points.
        piece_start: (C+1,) curve c owns pieces ``piece_start[c] … piece_start[c+1]−1``.
        lo, hi: (C,) parameter domain of each curve (m).
        piece_lo: (S,) parameter where each piece starts (m); width: (S,) its length (m).
        piece_curve: (S,) owning curve of each piece.
        window: (S, p+1) control-point rows of each piece (padding repeats the last row).
        real: (S, p+1) bool, False on padded window entries.
        power_basis: (S, p+1, p+1) ``power_basis[s, k, r]`` is the k-th Taylor coefficient
            at ``piece_lo[s]`` of the basis function of control point ``window[s, r]``
            (1/mᵏ): on piece s, ``β_r(piece_lo + u) = Σ_k power_basis[s, k, r] uᵏ``.
        keys: (S+C,) complex search keys ``curve + 1j·break`` of every curve's breaks in
            order; numpy orders complex numbers lexicographically, so one searchsorted
            finds the piece of (curve, t) for any mix of curves, exactly.
        break_start: (C+1,) offsets of each curve's S_c + 1 breaks in ``keys``.
    """

    degree: np.ndarray
    p: int
    cp_start: np.ndarray
    piece_start: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    piece_lo: np.ndarray
    width: np.ndarray
    piece_curve: np.ndarray
    window: np.ndarray
    real: np.ndarray
    power_basis: np.ndarray
    keys: np.ndarray
    break_start: np.ndarray

    @property
    def n_curves(self) -> int:
        return self.lo.shape[0]

    def with_control_points(self, control_points: np.ndarray, curves: np.ndarray | None = None) -> CurveBatch:
        """The curves with stacked control points (N, 2) (m), rows ordered as ``cp_start``.

        With ``curves`` (indices), only those curves get polynomial coefficients (the
        others' stay NaN and must not be queried): the filter queries the few splines near
        the robot of a map of hundreds, and the coefficients are recomputed whenever the
        state moves.
        """
        cp = np.asarray(control_points, dtype=float)
        if cp.shape != (self.cp_start[-1], 2):
            raise SplineError(f"control points must have shape ({self.cp_start[-1]}, 2), got {cp.shape}")
        if curves is None:
            return CurveBatch(self, cp, _piece_coeffs(self.power_basis, cp[self.window]))
        curves = np.asarray(curves, dtype=np.intp)
        first = self.piece_start[curves]
        count = self.piece_start[curves + 1] - first
        owner = np.repeat(np.arange(curves.shape[0]), count)
        piece = np.arange(owner.shape[0]) - np.repeat(np.cumsum(count) - count, count) + first[owner]
        coeffs = np.full((self.piece_lo.shape[0], self.p + 1, 2), np.nan)
        coeffs[piece] = _piece_coeffs(self.power_basis[piece], cp[self.window[piece]])
        return CurveBatch(self, cp, coeffs)

    def bboxes(self, control_points: np.ndarray) -> np.ndarray:
        """(C, 4) ``xmin, ymin, xmax, ymax`` of each control polygon (m), from stacked
        control points (N, 2); the box contains the curve."""
        starts = self.cp_start[:-1]
        return np.hstack([np.minimum.reduceat(control_points, starts, axis=0),
                          np.maximum.reduceat(control_points, starts, axis=0)])

    def extreme_control_points(self, control_points: np.ndarray, curves: np.ndarray, point: np.ndarray,
                               farthest: bool = False) -> np.ndarray:
        """(len(curves),) row of each curve's control point nearest to (or farthest from)
        ``point`` (2,), among stacked control points (N, 2) (m)."""
        curves = np.asarray(curves, dtype=np.intp)
        count = self.cp_start[curves + 1] - self.cp_start[curves]
        owner = np.repeat(np.arange(curves.shape[0]), count)
        rows = np.arange(owner.shape[0]) - np.repeat(np.cumsum(count) - count, count) + self.cp_start[curves][owner]
        d2 = np.sum((control_points[rows] - point) ** 2, axis=1)
        order = np.lexsort((-d2 if farthest else d2, owner))
        return rows[order[np.cumsum(count) - count]]

    def locate(self, curve: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Global piece (m,), local parameter u = t − piece_lo (m,) and the clamped t (m,)
        of parameters ``t`` (m,) on curves ``curve`` (m,). As for one curve, ``t`` is
        clamped into its curve's domain and the domain end belongs to the last piece."""
        t = np.clip(t, self.lo[curve], self.hi[curve])
        key = curve + 1j * t
        b = np.searchsorted(self.keys, key, side="right") - 1
        # break b is curve c's local break b − break_start[c]; its last break (hi) starts no piece
        piece = np.minimum(b - curve, self.piece_start[curve + 1] - 1)
        return piece, t - self.piece_lo[piece], t

    def basis_values(self, piece: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(m, p+1) values of the basis functions of ``window[piece]`` at local ``u`` (m,)."""
        return horner_with_derivatives(self.power_basis[piece], u, 0)[0]


@dataclass(frozen=True, eq=False)
class CurveBatch:
    """A :class:`CurveTable` with control points.

    Attributes:
        table: the knot structure.
        control_points: (N, 2) stacked control points (m).
        coeffs: (S, p+1, 2) Taylor coefficients of each piece at its start (m / mᵏ), as
            :class:`~bsslam.spline.pieces.PolynomialPieces` has them for one curve.
    """

    table: CurveTable
    control_points: np.ndarray
    coeffs: np.ndarray

    def evaluate(self, curve: np.ndarray, t: np.ndarray, nder: int = 0) -> np.ndarray:
        """Points and derivatives 0 … nder at parameters t (m,) (clamped) on curves (m,):
        (nder+1, m, 2)."""
        piece, u, _ = self.table.locate(np.asarray(curve), np.asarray(t, dtype=float))
        return horner_with_derivatives(self.coeffs[piece], u, nder)

    def bboxes(self) -> np.ndarray:
        """(C, 4) ``xmin, ymin, xmax, ymax`` of each control polygon (m); contains the curve."""
        return self.table.bboxes(self.control_points)


def curve_table(knots: list[np.ndarray], degrees: list[int] | np.ndarray) -> CurveTable:
    """Build the table of C curves from their knot vectors and degrees.

    Args:
        knots: C valid knot vectors (m), curve c having ``len(knots[c]) − degree − 1``
            control points.
        degrees: (C,) polynomial degrees.
    """
    degrees = np.asarray(degrees, dtype=np.intp).reshape(-1)
    if degrees.shape[0] != len(knots) or not knots:
        raise SplineError("curve_table needs one degree per knot vector, and at least one curve")
    p = int(degrees.max())
    n_knots = np.array([k.shape[0] for k in knots], dtype=np.intp)
    n_cp = n_knots - degrees - 1
    K = np.concatenate(knots).astype(float, copy=False)
    knot_start = np.concatenate([[0], np.cumsum(n_knots)])
    cp_start = np.concatenate([[0], np.cumsum(n_cp)])
    # Spans degree … n_cp − 1 of each curve cover its domain; the non-empty ones are its pieces.
    n_dom = n_cp - degrees
    owner = np.repeat(np.arange(len(knots)), n_dom)
    local_span = np.arange(owner.shape[0]) - np.repeat(np.cumsum(n_dom) - n_dom, n_dom) + degrees[owner]
    span = knot_start[owner] + local_span                     # global index into K
    nonempty = K[span] < K[span + 1]
    span, owner, local_span = span[nonempty], owner[nonempty], local_span[nonempty]
    n_pieces = np.bincount(owner, minlength=len(knots))
    if np.any(n_pieces == 0):
        raise SplineError("every curve needs a non-empty domain")
    piece_start = np.concatenate([[0], np.cumsum(n_pieces)])
    piece_lo = K[span]
    width = K[span + 1] - piece_lo
    lo = K[knot_start[:-1] + degrees]
    hi = K[knot_start[:-1] + n_cp]

    S = span.shape[0]
    power_basis = np.zeros((S, p + 1, p + 1))
    window = np.empty((S, p + 1), dtype=np.intp)
    real = np.zeros((S, p + 1), dtype=bool)
    factorials = np.array([math.factorial(k) for k in range(p + 1)], dtype=float)
    r = np.arange(p + 1)
    for d in np.unique(degrees):  # usually a single degree
        sel = np.flatnonzero(degrees[owner] == d)
        d = int(d)
        # Derivatives of the degree + 1 basis functions at each piece's start; the span is
        # given, so the global knot array serves every curve at once.
        _, values = basis_functions(K, d, piece_lo[sel], d, span=span[sel])   # (d+1, s, d+1)
        power_basis[sel[:, None, None], r[None, : d + 1, None], r[None, None, : d + 1]] = (
            values.transpose(1, 0, 2) / factorials[None, : d + 1, None])
        first = cp_start[owner[sel]] + local_span[sel] - d
        window[sel] = first[:, None] + np.minimum(r, d)[None, :]
        real[sel, : d + 1] = True

    n_breaks = n_pieces + 1
    break_curve = np.repeat(np.arange(len(knots)), n_breaks)
    last = piece_start[1:] - 1
    breaks = np.insert(piece_lo, piece_start[1:], piece_lo[last] + width[last])
    keys = break_curve + 1j * breaks
    break_start = np.concatenate([[0], np.cumsum(n_breaks)])
    return CurveTable(degree=degrees, p=p, cp_start=cp_start, piece_start=piece_start, lo=lo, hi=hi,
                      piece_lo=piece_lo, width=width, piece_curve=owner, window=window, real=real,
                      power_basis=power_basis, keys=keys, break_start=break_start)


def _piece_coeffs(power_basis: np.ndarray, window_points: np.ndarray) -> np.ndarray:
    """(S, p+1, 2) Taylor coefficients Σ_r power_basis[s, k, r] · window_points[s, r] of
    pieces from their (S, p+1, p+1) power-basis matrices and (S, p+1, 2) control points.
    (Written out: numpy's einsum and batched matmul are slow on many 4 × 4 products.)"""
    out = power_basis[:, :, 0, None] * window_points[:, None, 0, :]
    for r in range(1, power_basis.shape[2]):
        out += power_basis[:, :, r, None] * window_points[:, None, r, :]
    return out


# -- ray intersection ------------------------------------------------------------------------

def intersect_rays_batch(batch: CurveBatch, curve: np.ndarray, origins: np.ndarray, angles: np.ndarray,
                         t0: np.ndarray | None = None, max_range: float = np.inf,
                         *, samples_per_span: int = 8) -> RayHits:
    """Nearest intersection of each ray with its own curve: :func:`bsslam.spline.intersect_rays`
    for rays that each name their curve.

    Args:
        batch: the curves.
        curve: (m,) curve index of each ray.
        origins: (2,) or (m, 2) ray origins (m).
        angles: (m,) ray directions μ (rad).
        t0: optional (m,) parameter guesses (m); NaN means no guess.
        max_range: hits farther than this (m) count as misses.
        samples_per_span: samples per piece in the global search (≥ 2).

    Returns:
        RayHits with (m,) arrays.
    """
    curve = np.asarray(curve, dtype=np.intp)
    mu = np.asarray(angles, dtype=float)
    m = mu.shape[0]
    origin = np.broadcast_to(np.asarray(origins, dtype=float), (m, 2))
    if curve.shape != (m,):
        raise SplineError(f"curve must have shape ({m},), got {curve.shape}")
    if samples_per_span < 2:
        raise SplineError(f"samples_per_span must be ≥ 2, got {samples_per_span}")
    rays = _Rays(curve, origin[:, 0], origin[:, 1], np.cos(mu), np.sin(mu))
    t = np.full(m, np.nan)
    rng = np.full(m, np.nan)
    slope_x = np.full(m, np.nan)
    slope_y = np.full(m, np.nan)
    todo = np.ones(m, dtype=bool)
    if t0 is not None:
        guess = np.asarray(t0, dtype=float)
        if guess.shape != (m,):
            raise SplineError(f"t0 must have shape ({m},), got {guess.shape}")
        idx = np.flatnonzero(np.isfinite(guess))
        ok, values = _ray_newton(batch, rays.take(idx), guess[idx], max_range)
        done = idx[ok]
        t[done], rng[done], slope_x[done], slope_y[done] = (v[ok] for v in values)
        todo[done] = False
    idx = np.flatnonzero(todo)
    if idx.size:
        ok, values = _ray_global_search(batch, rays.take(idx), max_range, samples_per_span)
        done = idx[ok]
        t[done], rng[done], slope_x[done], slope_y[done] = (v[ok] for v in values)
    hit = np.isfinite(rng)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = slope_x / slope_y
    return RayHits(t=t, range=rng, r=r, hit=hit)


@dataclass(frozen=True)
class _Rays:
    """Curve index, origin and direction cosines of k rays, each (k,)."""

    curve: np.ndarray
    ox: np.ndarray
    oy: np.ndarray
    cos: np.ndarray
    sin: np.ndarray

    def take(self, index: np.ndarray) -> _Rays:
        return _Rays(self.curve[index], self.ox[index], self.oy[index], self.cos[index], self.sin[index])


def _ray_newton(batch: CurveBatch, rays: _Rays, t: np.ndarray, max_range: float):
    """Newton ``t ← t − ỹ/ỹ'`` from the guesses, clamped to each curve's domain (as for one
    curve). Returns ok (k,) and (t, x̃, x̃', ỹ') (k,) each."""
    table = batch.table
    lo, hi = table.lo[rays.curve], table.hi[rays.curve]
    t = np.clip(t, lo, hi)
    active = np.arange(t.shape[0])
    sub = rays
    sub_lo, sub_hi = lo, hi
    for _ in range(_RAY_MAX_NEWTON):
        # only rays still moving are evaluated: most converge in three or four steps
        t_a = t[active]
        piece, u, _ = table.locate(sub.curve, t_a)
        s, ds = _value_and_slope(batch.coeffs[piece], u)
        yt = sub.cos * (s[:, 1] - sub.oy) - sub.sin * (s[:, 0] - sub.ox)
        dyt = sub.cos * ds[:, 1] - sub.sin * ds[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t_new = np.clip(t_a - yt / dyt, sub_lo, sub_hi)
        finite = np.isfinite(t_new)
        moving = finite & (np.abs(t_new - t_a) > _STEP_TOLERANCE * (1.0 + np.abs(t_new)))
        t[active] = np.where(finite, t_new, t_a)
        if not moving.any():
            break
        if not moving.all():
            keep = np.flatnonzero(moving)
            active = active[keep]
            sub = sub.take(keep)
            sub_lo, sub_hi = sub_lo[keep], sub_hi[keep]
    piece, u, _ = table.locate(rays.curve, t)
    s, ds = _value_and_slope(batch.coeffs[piece], u)
    dx, dy = s[:, 0] - rays.ox, s[:, 1] - rays.oy
    xt = rays.cos * dx + rays.sin * dy
    yt = rays.cos * dy - rays.sin * dx
    dxt = rays.cos * ds[:, 0] + rays.sin * ds[:, 1]
    dyt = rays.cos * ds[:, 1] - rays.sin * ds[:, 0]
    ok = (np.abs(yt) <= _ROOT_TOLERANCE_M) & (xt > 0) & (xt <= max_range)
    return ok, (t, xt, dxt, dyt)


def _value_slope_curvature(coeffs: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points, first and second derivatives (m, 2) each of pieces (m, p+1, 2) at local u
    (m,): :func:`_value_and_slope` with the second derivative (inner loop of closest points)."""
    uu = u[:, None]
    v, d, dd = coeffs[:, -1], None, None
    for i in range(coeffs.shape[1] - 2, -1, -1):
        if d is not None:
            dd = d if dd is None else dd * uu + d
        d = v if d is None else d * uu + v
        v = v * uu + coeffs[:, i]
    zero = np.zeros_like(v)
    return v, (zero if d is None else d), (zero if dd is None else 2.0 * dd)


def _value_and_slope(coeffs: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (m, 2) and first derivatives (m, 2) of pieces with coefficients (m, p+1, 2)
    at local parameters u (m,): Horner on both at once (as horner_with_derivatives with
    nder = 1, with fewer temporaries — this is the inner loop of the ray search)."""
    uu = u[:, None]
    v, d = coeffs[:, -1], None
    for i in range(coeffs.shape[1] - 2, -1, -1):
        d = v if d is None else d * uu + v
        v = v * uu + coeffs[:, i]
    return v, (np.zeros_like(v) if d is None else d)


def _ray_global_search(batch: CurveBatch, rays: _Rays, max_range: float, samples_per_span: int):
    """The global search of one curve's ``intersect_rays`` over (ray, piece of its curve)
    pairs: convex-hull culling, sampling, bracketed Newton, nearest root per ray."""
    table = batch.table
    k = rays.curve.shape[0]
    first = table.piece_start[rays.curve]
    count = table.piece_start[rays.curve + 1] - first
    ray = np.repeat(np.arange(k), count)
    piece = np.arange(ray.shape[0]) - np.repeat(np.cumsum(count) - count, count) + first[ray]
    # Convex hull: rotated control points of each candidate piece, (K, p+1).
    cp = batch.control_points[table.window[piece]]
    c, s = rays.cos[ray, None], rays.sin[ray, None]
    dx, dy = cp[:, :, 0] - rays.ox[ray, None], cp[:, :, 1] - rays.oy[ray, None]
    xw, yw = c * dx + s * dy, c * dy - s * dx
    straddles = (yw.min(axis=1) <= 0) & (yw.max(axis=1) >= 0)
    reachable = (xw.max(axis=1) > 0) & (xw.min(axis=1) <= max_range)
    keep = straddles & reachable
    ray, piece = ray[keep], piece[keep]

    cx, cy = beam_frame_polynomials(batch.coeffs[piece], rays.cos[ray], rays.sin[ray], rays.ox[ray], rays.oy[ray])

    ok, hit_rays, best_pair, values = nearest_crossings(cx, cy, table.width[piece], ray, k,
                                                        samples_per_span, max_range)
    t, rng, dxt, dyt = (np.full(k, np.nan) for _ in range(4))
    t[hit_rays] = table.piece_lo[piece[best_pair]] + values[0]
    rng[hit_rays], dxt[hit_rays], dyt[hit_rays] = values[1:]
    return ok, (t, rng, dxt, dyt)


# -- closest points --------------------------------------------------------------------------

def closest_points_batch(batch: CurveBatch, curve: np.ndarray, queries: np.ndarray,
                         t0: np.ndarray | None = None, *, sample_step_m: float = 0.1,
                         samples_per_span: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point of its own curve nearest to each query point: :func:`bsslam.spline.closest_point`
    for queries that each name their curve (same sampling, starts and Newton).

    Args:
        batch: the curves.
        curve: (q,) curve index of each query.
        queries: (q, 2) query points (m).
        t0: optional (q,) starting parameters (m); NaN means sample the curve.
        sample_step_m: largest arc length between coarse samples (m).
        samples_per_span: fewest coarse samples per piece (≥ 2).

    Returns:
        ``(t, points, distance)``: (q,) parameters (m), (q, 2) points (m), (q,) distances (m).
    """
    table = batch.table
    curve = np.asarray(curve, dtype=np.intp)
    q = np.asarray(queries, dtype=float)
    if q.ndim != 2 or q.shape[1] != 2 or curve.shape != (q.shape[0],):
        raise SplineError(f"queries must be (q, 2) with one curve each, got {q.shape} and {curve.shape}")
    if samples_per_span < 2:
        raise SplineError(f"samples_per_span must be ≥ 2, got {samples_per_span}")
    if not sample_step_m > 0:
        raise SplineError(f"sample_step_m must be > 0, got {sample_step_m}")
    guess = np.full(q.shape[0], np.nan) if t0 is None else np.asarray(t0, dtype=float)
    given = np.flatnonzero(np.isfinite(guess))
    unguessed = np.flatnonzero(~np.isfinite(guess))
    t_start = np.clip(guess[given], table.lo[curve[given]], table.hi[curve[given]])
    owner = given
    if unguessed.size:
        t_s, owner_s = _sampled_minima(batch, curve[unguessed], q[unguessed], sample_step_m, samples_per_span)
        t_start = np.concatenate([t_start, t_s])
        owner = np.concatenate([owner, unguessed[owner_s]])
    t, d2 = _closest_newton(batch, curve[owner], q[owner], t_start)
    order = np.lexsort((d2, owner))
    _, first = np.unique(owner[order], return_index=True)
    best = order[first]
    t_best = t[best]
    points = batch.evaluate(curve, t_best)[0]
    return t_best, points, np.sqrt(d2[best])


def _sampled_minima(batch: CurveBatch, curve: np.ndarray, q: np.ndarray, sample_step_m: float,
                    samples_per_span: int) -> tuple[np.ndarray, np.ndarray]:
    """(K,) starts and their (K,) query index: discrete local minima of the distance along
    each query's curve sampled as one curve's ``closest_point`` samples it, and their
    neighbours."""
    table = batch.table
    used, inverse = np.unique(curve, return_inverse=True)
    # pieces of the used curves, curve by curve
    first = table.piece_start[used]
    n_pieces = table.piece_start[used + 1] - first
    piece = np.arange(n_pieces.sum()) - np.repeat(np.cumsum(n_pieces) - n_pieces, n_pieces) + np.repeat(first, n_pieces)
    window = batch.control_points[table.window[piece]]          # padding repeats: adds no length
    polygon = np.sum(np.linalg.norm(np.diff(window, axis=1), axis=2), axis=1)
    counts = np.clip(np.ceil(polygon / sample_step_m), samples_per_span, MAX_SAMPLES_PER_SPAN).astype(np.intp)
    # Grid of each used curve: every piece cut in equal parts, then the curve's end.
    piece_of = np.repeat(piece, counts)
    part = np.arange(piece_of.shape[0]) - np.repeat(np.cumsum(counts) - counts, counts)
    t_in = table.piece_lo[piece_of] + table.width[piece_of] * (part / np.repeat(counts, counts))
    per_curve = np.add.reduceat(counts, np.cumsum(n_pieces) - n_pieces)   # samples before the end
    ends = np.cumsum(per_curve)
    t_grid = np.insert(t_in, ends, table.hi[used])
    grid_curve = np.repeat(used, per_curve + 1)
    samples = batch.evaluate(grid_curve, t_grid)[0]
    grid_start = np.concatenate([[0], np.cumsum(per_curve + 1)])
    # distances of each query to its curve's samples, flattened query by query
    g0 = grid_start[inverse]
    size = grid_start[inverse + 1] - g0
    owner = np.repeat(np.arange(q.shape[0]), size)
    local = np.arange(owner.shape[0]) - np.repeat(np.cumsum(size) - size, size)
    index = g0[owner] + local
    diff = q[owner] - samples[index]
    d2 = np.einsum("ij,ij->i", diff, diff)
    prev = np.where(local > 0, np.roll(d2, 1), np.inf)
    nxt = np.where(local < size[owner] - 1, np.roll(d2, -1), np.inf)
    # strict on the left, loose on the right: a plateau yields one start, not many
    is_min = (d2 < prev) & (d2 <= nxt)
    at = np.flatnonzero(is_min)
    lo_i, hi_i = g0[owner[at]], g0[owner[at]] + size[owner[at]] - 1
    # start also from both neighbours (a corner at repeated knots is seen from one side only)
    starts = np.concatenate([np.clip(index[at] + d, lo_i, hi_i) for d in (-1, 0, 1)])
    return t_grid[starts], np.tile(owner[at], 3)


def _closest_newton(batch: CurveBatch, curve: np.ndarray, q: np.ndarray, t: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Clamped, downhill-safeguarded Newton on f(t) = (s(t) − q)·s'(t) for (K,) starts on
    their curves; the best parameter seen per start and its squared distance."""
    table = batch.table
    lo, hi = table.lo[curve], table.hi[curve]
    tolerance = _CLOSEST_STEP_TOLERANCE * np.maximum(hi - lo, np.maximum(np.abs(lo), np.abs(hi)))
    t_best = t.copy()
    d2_best = np.full(t.shape, np.inf)
    for _ in range(_CLOSEST_MAX_NEWTON):
        piece, u, _ = table.locate(curve, t)
        s, ds, dds = _value_slope_curvature(batch.coeffs[piece], u)
        diff = s - q
        d2 = np.einsum("ij,ij->i", diff, diff)
        better = d2 < d2_best
        t_best[better] = t[better]
        d2_best[better] = d2[better]
        speed2 = np.einsum("ij,ij->i", ds, ds)
        f = np.einsum("ij,ij->i", diff, ds)
        fp = speed2 + np.einsum("ij,ij->i", diff, dds)
        fp = np.where(fp > 0, fp, speed2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_new = np.clip(t - f / fp, lo, hi)
        t_new = np.where(np.isfinite(t_new), t_new, t)
        done = np.abs(t_new - t) <= tolerance
        t = t_new
        if np.all(done):
            break
    diff = batch.evaluate(curve, t)[0] - q
    d2 = np.einsum("ij,ij->i", diff, diff)
    final = d2 <= d2_best * (1.0 + 1e-12)
    t_best[final] = t[final]
    d2_best[final] = d2[final]
    return t_best, d2_best
