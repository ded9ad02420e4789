"""The numpy form of the filter's ray intersection over a batch of curves, as it was in
``bsslam.spline.batch`` before the filter intersected its beams through the compiled
:func:`bsslam.slam.range_kernels.linearize_beams`: the oracle the compiled form must match
bit for bit (:func:`bsslam.slam.range_kernels.global_search` repeats
:func:`_ray_global_search` loop for loop).

The Newton from the guesses and the basis at the hits were already compiled here
(:func:`bsslam.spline.kernels.ray_newton`, :func:`bsslam.spline.kernels.hit_basis`), and the
compiled linearisation calls those same kernels: this form checks the global search and the
way the steps are put together, not those two kernels.

The search follows :func:`bsslam.spline.intersect_rays` step for step (same starts,
iterations, tolerances and acceptance tests); results agree with it up to rounding.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.errors import SplineError
from bsslam.spline import kernels
from bsslam.spline.batch import CurveBatch, CurveTable
from bsslam.spline.intersect import _MAX_NEWTON as _RAY_MAX_NEWTON
from bsslam.spline.intersect import _ROOT_TOLERANCE_M, _STEP_TOLERANCE, RayHits
from bsslam.spline.intersect import beam_frame_polynomials, nearest_crossings


def basis_at(table: CurveTable, curve: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Piece (m,) and values (m, p+1) of the basis functions of its control-point window
    ``table.window[piece]`` at finite parameters ``t`` (m,) of curves ``curve`` (m,), clamped
    as :meth:`CurveTable.locate` clamps them (compiled:
    :func:`bsslam.spline.kernels.hit_basis`; formerly ``CurveTable.basis_at``)."""
    return kernels.hit_basis(table.power_basis, table.piece_lo, table.piece_start, table.lo, table.hi,
                             np.asarray(curve, dtype=np.intp), np.asarray(t, dtype=float))


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
    origin = np.asarray(origins, dtype=float)
    # one origin for all rays (the filter's case) stays a (2, 1) column
    origin = origin[:, None] if origin.shape == (2,) else np.broadcast_to(origin, (m, 2)).T
    if curve.shape != (m,):
        raise SplineError(f"curve must have shape ({m},), got {curve.shape}")
    if samples_per_span < 2:
        raise SplineError(f"samples_per_span must be ≥ 2, got {samples_per_span}")
    rays = _Rays(curve, origin, np.cos(mu), np.sin(mu))
    with np.errstate(divide="ignore", invalid="ignore"):
        if t0 is None:
            out = np.full((4, m), np.nan)      # rows t, range, x̃', ỹ'; NaN where no hit
            todo = np.arange(m)
        else:
            guess = np.asarray(t0, dtype=float)
            if guess.shape != (m,):
                raise SplineError(f"t0 must have shape ({m},), got {guess.shape}")
            finite = np.isfinite(guess)
            if np.count_nonzero(finite) == m:  # the filter's case: every beam has a guess
                ok, out = _ray_newton(batch, rays, guess, max_range)
                missed = ~ok
                np.copyto(out, np.nan, where=missed)
                todo = missed.nonzero()[0]
            else:
                out = np.full((4, m), np.nan)
                idx = finite.nonzero()[0]
                ok, values = _ray_newton(batch, rays.take(idx), guess[idx], max_range)
                out[:, idx[ok]] = values[:, ok]
                left = np.ones(m, dtype=bool)
                left[idx[ok]] = False
                todo = left.nonzero()[0]
        if todo.size:
            ok, values = _ray_global_search(batch, rays.take(todo), max_range, samples_per_span)
            out[:, todo[ok]] = values[:, ok]
        t, rng, slope_x, slope_y = out
        r = slope_x / slope_y
    return RayHits(t=t, range=rng, r=r, hit=np.isfinite(rng))


@dataclass(frozen=True)
class _Rays:
    """Curve index (k,), origins (2, k) or one shared origin (2, 1) (m), direction
    cosines cos, sin (k,) of k rays."""

    curve: np.ndarray
    origin: np.ndarray
    cos: np.ndarray
    sin: np.ndarray

    def take(self, index: np.ndarray) -> _Rays:
        origin = self.origin if self.origin.shape[1] == 1 else self.origin[:, index]
        return _Rays(self.curve[index], origin, self.cos[index], self.sin[index])

    def origin_of(self, index: np.ndarray) -> np.ndarray:
        """(2, len(index)) or the shared (2, 1) origin of rays ``index``."""
        return self.origin if self.origin.shape[1] == 1 else self.origin[:, index]


def _ray_newton(batch: CurveBatch, rays: _Rays, t: np.ndarray, max_range: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """Newton ``t ← t − ỹ/ỹ'`` from the guesses, clamped to each curve's domain (as for one
    curve). Returns ok (k,) and the rows t, x̃, x̃', ỹ' (4, k).

    A ray stops (keeps its t) at the first step that does not move it; compiled, ray by ray
    (:func:`bsslam.spline.kernels.ray_newton`)."""
    table = batch.table
    ox, oy = rays.origin
    return kernels.ray_newton(batch.coeffs_t, table.piece_lo, table.piece_start, table.lo, table.hi,
                              rays.curve, np.ascontiguousarray(ox), np.ascontiguousarray(oy), rays.cos, rays.sin,
                              np.asarray(t, dtype=float), float(max_range), _RAY_MAX_NEWTON, _STEP_TOLERANCE,
                              _ROOT_TOLERANCE_M)


def _ray_global_search(batch: CurveBatch, rays: _Rays, max_range: float, samples_per_span: int):
    """The global search of one curve's ``intersect_rays`` over (ray, piece of its curve)
    pairs: convex-hull culling, sampling, bracketed Newton, nearest root per ray.
    Returns ok (k,) and the rows t, range, x̃', ỹ' (4, k), NaN where no hit.

    The candidate pairs come from the curves' table; the crossings are found by the same
    :func:`~bsslam.spline.intersect.nearest_crossings` as for one curve."""
    table = batch.table
    k = rays.curve.shape[0]
    # (ray, piece of its curve) pairs, ray by ray: rays sharing a curve repeat its pieces
    first = table.piece_start.take(rays.curve)
    count = table.piece_start.take(rays.curve + 1) - first
    ray = np.repeat(np.arange(k), count)
    piece = np.arange(ray.shape[0]) - np.repeat(np.cumsum(count) - count, count) + first.take(ray)
    # Convex hull: rotated control points of each candidate piece, (K, p+1).
    cp = batch.control_points.take(table.window.take(piece, axis=0), axis=0)
    c, s = rays.cos.take(ray)[:, None], rays.sin.take(ray)[:, None]
    ox, oy = rays.origin_of(ray)
    dx, dy = cp[:, :, 0] - ox[:, None], cp[:, :, 1] - oy[:, None]
    xw, yw = c * dx + s * dy, c * dy - s * dx
    keep = yw.min(axis=1) <= 0
    keep &= yw.max(axis=1) >= 0
    keep &= xw.max(axis=1) > 0
    keep &= xw.min(axis=1) <= max_range
    keep = keep.nonzero()[0]
    ray, piece = ray.take(keep), piece.take(keep)
    out = np.full((4, k), np.nan)
    if ray.size == 0:
        return np.zeros(k, dtype=bool), out
    cx, cy = beam_frame_polynomials(batch.coeffs_t.take(piece, axis=2), rays.cos.take(ray), rays.sin.take(ray),
                                    *rays.origin_of(ray))
    ok, hit_rays, best_pair, values = nearest_crossings(cx, cy, table.width.take(piece), ray, k, samples_per_span,
                                                        max_range)
    out[0, hit_rays] = table.piece_lo.take(piece.take(best_pair)) + values[0]
    out[1:, hit_rays] = values[1:]
    return ok, out
