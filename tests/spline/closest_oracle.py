"""The numpy closest-point search on one curve, formerly ``bsslam.spline.closest_point``:
the oracle the compiled search (:func:`bsslam.spline.batch.closest_points_batch`, which the
library's ``closest_point`` now calls) follows step for step, equal to rounding."""

from __future__ import annotations

import numpy as np

from bsslam.errors import SplineError
from bsslam.spline.basis import as_parameters
from bsslam.spline.batch import _CLOSEST_MAX_NEWTON as _MAX_NEWTON
from bsslam.spline.batch import _CLOSEST_STEP_TOLERANCE as _STEP_TOLERANCE
from bsslam.spline.batch import MAX_SAMPLES_PER_SPAN
from bsslam.spline.curve import BSplineCurve, as_points


def closest_point(
    curve: BSplineCurve,
    queries: object,
    t0: object = None,
    *,
    sample_step_m: float = 0.1,
    samples_per_span: int = 4,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`bsslam.spline.closest_point` in numpy (its docstring says what it does)."""
    q = as_points(queries, "queries")
    pieces = curve.pieces
    lo, hi = pieces.breaks[0], pieces.breaks[-1]
    guess = np.full(q.shape[0], np.nan) if t0 is None else as_parameters(t0)
    if guess.shape != (q.shape[0],):
        raise SplineError(f"t0 must have shape ({q.shape[0]},), got {guess.shape}")
    given = np.flatnonzero(np.isfinite(guess))
    unguessed = np.flatnonzero(~np.isfinite(guess))
    t_start, owner = np.clip(guess[given], lo, hi), given
    if unguessed.size:
        t_sampled, owner_sampled = _starts_at_sampled_minima(curve, q[unguessed], sample_step_m, samples_per_span)
        t_start = np.concatenate([t_start, t_sampled])
        owner = np.concatenate([owner, unguessed[owner_sampled]])
    t, d2 = _newton(curve, q[owner], t_start)
    # Best candidate of each query: sort by (query, squared distance), keep the first.
    order = np.lexsort((d2, owner))
    _, first = np.unique(owner[order], return_index=True)
    best = order[first]
    t_best = t[best]
    points = pieces.evaluate(t_best)[0]
    return t_best, points, np.sqrt(d2[best])



def _starts_at_sampled_minima(
    curve: BSplineCurve, q: np.ndarray, sample_step_m: float, samples_per_span: int
) -> tuple[np.ndarray, np.ndarray]:
    """(K,) starting parameters and (K,) owning query index: the discrete local minima of
    the distance along the coarse sampling (ends included) and their neighbours."""
    if samples_per_span < 2:
        raise SplineError(f"samples_per_span must be ≥ 2, got {samples_per_span}")
    if not sample_step_m > 0:
        raise SplineError(f"sample_step_m must be > 0, got {sample_step_m}")
    pieces = curve.pieces
    # The control polygon of a span is at least as long as the curve over it.
    window = curve.control_points[pieces.spans[:, None] - curve.degree + np.arange(curve.degree + 1)]
    polygon = np.sum(np.linalg.norm(np.diff(window, axis=1), axis=2), axis=1)
    # Capped: a wildly long control polygon (a diverged estimate) must cost bounded memory;
    # past the cap the result is still a true local minimum, just not always the global one.
    counts = np.clip(np.ceil(polygon / sample_step_m), samples_per_span, MAX_SAMPLES_PER_SPAN).astype(np.intp)
    t_grid = pieces.subdivide(counts)
    samples = curve.pieces.evaluate(t_grid)[0]
    d2 = np.sum((q[:, None, :] - samples[None, :, :]) ** 2, axis=2)  # (q, G)
    padded = np.pad(d2, ((0, 0), (1, 1)), constant_values=np.inf)
    # Strict on the left, loose on the right: a plateau yields one start, not many.
    is_min = (d2 < padded[:, :-2]) & (d2 <= padded[:, 2:])
    owner, index = np.nonzero(is_min)
    # Start also from both neighbours: the minimum lies between them, and at a knot where
    # the curve has a corner (repeated knots) Newton from the sample itself sees one side only.
    index = np.clip(np.concatenate([index - 1, index, index + 1]), 0, t_grid.shape[0] - 1)
    return t_grid[index], np.tile(owner, 3)


def _newton(curve: BSplineCurve, q: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Clamped, downhill-safeguarded Newton on f(t) = (s(t) − q)·s'(t) for (K,) starts.

    Returns the best parameter seen for each start and its squared distance, so the
    result is never worse than the start.
    """
    pieces = curve.pieces
    lo, hi = pieces.breaks[0], pieces.breaks[-1]
    tolerance = _STEP_TOLERANCE * max(hi - lo, abs(lo), abs(hi))
    t_best = t.copy()
    d2_best = np.full(t.shape, np.inf)
    for _ in range(_MAX_NEWTON):
        s, ds, dds = pieces.evaluate(t, 2)
        diff = s - q
        d2 = np.sum(diff * diff, axis=1)
        better = d2 < d2_best
        t_best[better] = t[better]
        d2_best[better] = d2[better]
        speed2 = np.sum(ds * ds, axis=1)
        f = np.sum(diff * ds, axis=1)
        fp = speed2 + np.sum(diff * dds, axis=1)
        fp = np.where(fp > 0, fp, speed2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_new = np.clip(t - f / fp, lo, hi)
        t_new = np.where(np.isfinite(t_new), t_new, t)  # a cusp (s' = 0) stops that start
        done = np.abs(t_new - t) <= tolerance
        t = t_new
        if np.all(done):
            break
    diff = pieces.evaluate(t)[0] - q
    d2 = np.sum(diff * diff, axis=1)
    # Near the minimum d² is flat to rounding, so "best seen" alone would pick any iterate
    # within ~1e-8 of it; keep the converged iterate unless it is really worse.
    final = d2 <= d2_best * (1.0 + 1e-12)
    t_best[final] = t[final]
    d2_best[final] = d2[final]
    return t_best, d2_best
