"""Where laser beams hit a spline curve: the predicted ranges of the observation model (spec §6).

In the frame of a beam (origin at the sensor, x̃ along the beam) the curve is
``(x̃(t), ỹ(t))`` with ``x̃ = cos μ (x − o_x) + sin μ (y − o_y)``,
``ỹ = −sin μ (x − o_x) + cos μ (y − o_y)``; the beam hits where ``ỹ(t) = 0`` and
``x̃(t) > 0``, at range ``x̃(t)``. By affine invariance the rotated control points are the
control points of the rotated curve, which gives the convex-hull test used below.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.errors import SplineError
from bsslam.spline.basis import as_parameters
from bsslam.spline.curve import BSplineCurve
from bsslam.spline.pieces import horner_rows

_MAX_NEWTON = 12
_MAX_REFINE = 60
# A root is accepted when |ỹ| is below this (m): far above rounding for coordinates of a
# few kilometres, far below any laser's resolution.
_ROOT_TOLERANCE_M = 1e-9
# Newton stops when its step is below this relative size (parameters are metres).
_STEP_TOLERANCE = 1e-13


@dataclass(frozen=True, eq=False)
class RayHits:
    """Intersections of m rays with one curve.

    Attributes:
        t: (m,) curve parameter of the hit (m); NaN where no hit.
        range: (m,) distance from the ray origin to the hit along the ray (m); NaN where no hit.
        r: (m,) tangent ratio ``x̃'(t)/ỹ'(t)`` in the beam frame (spec §6); NaN where no hit,
            ±inf for a tangent (grazing) hit.
        hit: (m,) bool, whether the ray hits the curve within the maximum range.
    """

    t: np.ndarray
    range: np.ndarray
    r: np.ndarray
    hit: np.ndarray


def intersect_rays(
    curve: BSplineCurve,
    origins: object,
    angles: object,
    t0: object = None,
    max_range: float = np.inf,
    *,
    samples_per_span: int = 8,
) -> RayHits:
    """Nearest intersection of each ray with the curve.

    With ``t0``: Newton ``t ← t − ỹ/ỹ'`` from the guess, clamped to the domain; it is
    accepted when it converges to a root with ``0 < x̃ ≤ max_range`` (not necessarily the
    nearest one: the guess, from data association, is trusted). Rays where it fails, and
    all rays without ``t0``, go to the global search: spans whose rotated control values ỹ_i
    all share a sign cannot hold a root (convex hull) and are skipped, as are spans entirely
    behind the sensor or beyond ``max_range``; the others are sampled ``samples_per_span``
    times, every sign change is refined by Newton safeguarded with bisection, and the
    nearest root with ``x̃ > 0`` wins. Two roots closer together along the curve than the
    sampling step (a nearly tangent ray) can be missed.

    Args:
        curve: the spline (world frame).
        origins: (2,) or (m, 2) ray origins, world frame (m).
        angles: (m,) ray directions μ, world frame (rad).
        t0: optional (m,) parameter guesses (m); NaN entries mean "no guess".
        max_range: hits farther than this (m) count as misses.
        samples_per_span: samples per knot span in the global search (≥ 2).

    Returns:
        RayHits with (m,) arrays.
    """
    mu = as_parameters(angles)
    m = mu.shape[0]
    origin = np.asarray(origins, dtype=float)
    if origin.shape == (2,):
        origin = np.broadcast_to(origin, (m, 2))
    elif origin.shape != (m, 2):
        raise SplineError(f"origins must have shape (2,) or ({m}, 2), got {origin.shape}")
    if samples_per_span < 2:
        raise SplineError(f"samples_per_span must be ≥ 2, got {samples_per_span}")
    cos_mu, sin_mu = np.cos(mu), np.sin(mu)
    beams = _Beams(origin[:, 0], origin[:, 1], cos_mu, sin_mu)

    t = np.full(m, np.nan)
    rng = np.full(m, np.nan)
    slope_x = np.full(m, np.nan)  # x̃'(t) at the hit
    slope_y = np.full(m, np.nan)  # ỹ'(t) at the hit
    todo = np.ones(m, dtype=bool)
    if t0 is not None:
        guess = as_parameters(t0)
        if guess.shape != (m,):
            raise SplineError(f"t0 must have shape ({m},), got {guess.shape}")
        rays = np.flatnonzero(np.isfinite(guess))
        found = _newton_from_guess(curve, beams.take(rays), guess[rays], max_range)
        ok = rays[found.ok]
        t[ok], rng[ok], slope_x[ok], slope_y[ok] = (a[found.ok] for a in found.values)
        todo[ok] = False
    rays = np.flatnonzero(todo)
    if rays.size:
        found = _global_search(curve, beams.take(rays), max_range, samples_per_span)
        ok = rays[found.ok]
        t[ok], rng[ok], slope_x[ok], slope_y[ok] = (a[found.ok] for a in found.values)
    hit = np.isfinite(rng)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = slope_x / slope_y
    return RayHits(t=t, range=rng, r=r, hit=hit)


@dataclass(frozen=True)
class _Beams:
    """Origins and direction cosines of a set of rays, each (k,)."""

    ox: np.ndarray
    oy: np.ndarray
    cos: np.ndarray
    sin: np.ndarray

    def take(self, index: np.ndarray) -> _Beams:
        return _Beams(self.ox[index], self.oy[index], self.cos[index], self.sin[index])

    def column(self) -> _Beams:
        """The same rays as (k, 1) arrays, to broadcast against a row of points."""
        return _Beams(self.ox[:, None], self.oy[:, None], self.cos[:, None], self.sin[:, None])

    def rotate(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World coordinates to beam-frame (x̃, ỹ), broadcasting against the ray arrays."""
        dx, dy = x - self.ox, y - self.oy
        return self.cos * dx + self.sin * dy, self.cos * dy - self.sin * dx


@dataclass(frozen=True)
class _Found:
    """Per-ray outcome of one search: ok (k,) bool; values = (t, range, x̃', ỹ'), each (k,)."""

    ok: np.ndarray
    values: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _newton_from_guess(curve: BSplineCurve, beams: _Beams, t: np.ndarray, max_range: float) -> _Found:
    pieces = curve.pieces
    lo, hi = pieces.breaks[0], pieces.breaks[-1]
    t = np.clip(t, lo, hi)
    active = np.arange(t.shape[0])
    for _ in range(_MAX_NEWTON):
        # Only rays still moving are evaluated: most converge in three or four steps.
        sub = beams.take(active)
        s, ds = pieces.evaluate(t[active], 1)
        _, yt = sub.rotate(s[:, 0], s[:, 1])
        dyt = sub.cos * ds[:, 1] - sub.sin * ds[:, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t_new = np.clip(t[active] - yt / dyt, lo, hi)
        finite = np.isfinite(t_new)
        # Iterate to full precision, not just to the acceptance tolerance: the filter's
        # Jacobians are checked by finite differences of these ranges.
        moving = finite & (np.abs(t_new - t[active]) > _STEP_TOLERANCE * (1.0 + np.abs(t_new)))
        t[active] = np.where(finite, t_new, t[active])
        active = active[moving]
        if active.size == 0:
            break
    s, ds = pieces.evaluate(t, 1)
    xt, yt = beams.rotate(s[:, 0], s[:, 1])
    dxt = beams.cos * ds[:, 0] + beams.sin * ds[:, 1]
    dyt = beams.cos * ds[:, 1] - beams.sin * ds[:, 0]
    ok = (np.abs(yt) <= _ROOT_TOLERANCE_M) & (xt > 0) & (xt <= max_range)
    return _Found(ok, (t, xt, dxt, dyt))


def _global_search(curve: BSplineCurve, beams: _Beams, max_range: float, samples_per_span: int) -> _Found:
    pieces = curve.pieces
    k = beams.ox.shape[0]
    degree = pieces.degree
    # Convex-hull culling with the rotated control points of every span: (k, S, degree+1).
    window = pieces.spans[:, None] - degree + np.arange(degree + 1)
    cp = curve.control_points
    xc, yc = beams.column().rotate(cp[:, 0], cp[:, 1])  # (k, n_control) each
    yw = yc[:, window]
    xw = xc[:, window]
    straddles = (yw.min(axis=2) <= 0) & (yw.max(axis=2) >= 0)
    reachable = (xw.max(axis=2) > 0) & (xw.min(axis=2) <= max_range)
    ray, piece = np.nonzero(straddles & reachable)

    # Beam-frame polynomial of each candidate (ray, span) pair, ascending powers of u.
    cx, cy = beam_frame_polynomials(pieces.coeffs[piece].transpose(1, 2, 0), beams.cos[ray], beams.sin[ray],
                                    beams.ox[ray], beams.oy[ray])

    ok, rays, best_pair, values = nearest_crossings(cx, cy, pieces.widths[piece], ray, k,
                                                    samples_per_span, max_range)
    t, rng, dxt, dyt = (np.full(k, np.nan) for _ in range(4))
    t[rays] = pieces.breaks[piece[best_pair]] + values[0]
    rng[rays], dxt[rays], dyt[rays] = values[1:]
    return _Found(ok, (t, rng, dxt, dyt))


def beam_frame_polynomials(coeffs: np.ndarray, cos: np.ndarray, sin: np.ndarray, ox: np.ndarray,
                           oy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World pieces (degree+1, 2, K) in ascending powers (the piece axis last), moved into
    the frames of K beams starting at (ox, oy) with direction (cos, sin): (degree+1, K)
    rows of x̃ along each beam and of ỹ across it (m). ``ox``, ``oy`` may be (1,), one
    origin shared by all the beams."""
    cx = cos * coeffs[:, 0] + sin * coeffs[:, 1]
    cy = cos * coeffs[:, 1] - sin * coeffs[:, 0]
    cx[0] -= cos * ox + sin * oy
    cy[0] -= cos * oy - sin * ox
    return cx, cy


def nearest_crossings(cx: np.ndarray, cy: np.ndarray, width: np.ndarray, ray: np.ndarray, k: int,
                      samples_per_span: int, max_range: float):
    """Each ray's nearest forward crossing among candidate (ray, piece) pairs.

    Args:
        cx, cy: (degree+1, K) ascending beam-frame polynomials of each pair's piece in the
            local parameter u ∈ [0, width] (x along the beam, y across it; m), laid out
            so that every Horner step works on a contiguous (K,) row.
        width: (K,) parameter length of each pair's piece (m).
        ray: (K,) ray of each pair, in 0 … k−1.
        samples_per_span: sign-change samples per piece.
        max_range: crossings beyond this range (m) are ignored.

    Returns:
        ok: (k,) the ray crosses some piece ahead of it; rays: (h,) those rays;
        best_pair: (h,) the pair of each one's nearest crossing; values: (4, h) its local
        parameter u, range, and dx̃/du, dỹ/du there.
    """
    u = width[:, None] * _unit_grid(samples_per_span)                    # (K, samples+1)
    y = horner_rows(cy[:, :, None], u)
    positive = y > 0
    pair, j = (positive[:, :-1] != positive[:, 1:]).nonzero()
    zero_pair, zero_j = (y == 0).nonzero()   # exact zeros are roots already
    if zero_pair.size:
        pair = np.concatenate([pair, zero_pair])
        a = np.concatenate([u[pair[: j.size], j], u[zero_pair, zero_j]])
        b = np.concatenate([u[pair[: j.size], j + 1], u[zero_pair, zero_j]])
    else:
        a, b = u[pair, j], u[pair, j + 1]
    root = _refine_brackets(cy.take(pair, axis=1), a, b)
    xt = horner_rows(cx.take(pair, axis=1), root)
    keep = xt > 0
    keep &= xt <= max_range
    keep = keep.nonzero()[0]
    pair, root, xt = pair.take(keep), root.take(keep), xt.take(keep)
    ok = np.zeros(k, dtype=bool)
    if pair.size == 0:
        return ok, pair, pair, np.empty((4, 0))
    owner = ray.take(pair)
    best = first_per_group(xt, owner)    # the nearest root of every ray
    rays = owner.take(best)
    ok[rays] = True
    best_pair = pair.take(best)
    root = root.take(best)
    powers = np.arange(1, cx.shape[0], dtype=float)[:, None]
    values = np.stack([root, xt.take(best), horner_rows(cx.take(best_pair, axis=1)[1:] * powers, root),
                       horner_rows(cy.take(best_pair, axis=1)[1:] * powers, root)])
    return ok, rays, best_pair, values


def first_per_group(key: np.ndarray, group: np.ndarray) -> np.ndarray:
    """For (k,) keys in (k,) groups (k ≥ 1): the index of each group's smallest key, groups
    in increasing order. The sort is stable, so ties go to the earlier entry."""
    order = np.lexsort((key, group))
    sorted_group = group.take(order)
    first = np.empty(order.shape, dtype=bool)
    first[0] = True
    np.not_equal(sorted_group[1:], sorted_group[:-1], out=first[1:])
    return order[first]


_UNIT_GRIDS: dict[int, np.ndarray] = {}


def _unit_grid(samples: int) -> np.ndarray:
    """np.linspace(0, 1, samples + 1), computed once per count."""
    grid = _UNIT_GRIDS.get(samples)
    if grid is None:
        grid = _UNIT_GRIDS[samples] = np.linspace(0.0, 1.0, samples + 1)
    return grid


def _refine_brackets(c: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A root of each polynomial c (degree+1, B) inside its bracket [a, b] (sign change).

    Newton from the bracket's midpoint; a step that leaves the bracket is replaced by
    bisection, and the bracket shrinks around the sign change every iteration, so the
    iteration always converges. Every bracket is iterated until all have converged.
    """
    fa_positive = horner_rows(c, a) > 0
    x = 0.5 * (a + b)
    a, b = a.copy(), b.copy()
    derivative = c[1:] * np.arange(1, c.shape[0], dtype=float)[:, None]
    n = x.shape[0]
    for _ in range(_MAX_REFINE):
        f = horner_rows(c, x)
        fp = horner_rows(derivative, x)
        same = (f > 0) == fa_positive
        np.copyto(a, x, where=same)
        np.copyto(b, x, where=~same)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = f / fp
        x_new = x - step                       # Newton, kept where it stays inside (a, b)
        outside = ~((x_new > a) & (x_new < b))
        np.copyto(x_new, 0.5 * (a + b), where=outside)
        # converged to rounding: stay (a bisection step from a root would leave it)
        tolerance = np.abs(x)
        tolerance += 1.0
        tolerance *= _STEP_TOLERANCE
        at_root = np.abs(step) <= tolerance
        at_root |= f == 0
        np.copyto(x_new, x, where=at_root)
        at_root |= x_new == x
        x = x_new
        if np.count_nonzero(at_root) == n:
            break
    return x
