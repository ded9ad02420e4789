"""The numpy form of spline extension (``bsslam.spline.extend``) as it was before its
inner loops were compiled (bsslam.spline.extend_kernels): the oracle the compiled form
must match bit for bit."""

from __future__ import annotations

import numpy as np

from bsslam.errors import FitError
from bsslam.spline.basis import collocation_matrix
from bsslam.spline.curve import BSplineCurve
from bsslam.spline.fit import least_squares_operator, satisfies_schoenberg_whitney
from bsslam.spline.knots import span_count


def unclamp_transform(u: np.ndarray, p: int, side: str, new: np.ndarray) -> np.ndarray:
    """Piegl & Tiller A12.1 by numpy row operations: unclamps the (n + p + 2,) knots u in
    place at ``side`` with the (p,) checked knots ``new``; returns T (n + 1, n + 1)."""
    n = u.shape[0] - p - 2
    transform = np.eye(n + 1)
    if side == "right":
        for i in range(p - 1):
            u[n + i + 2] = new[i]
            for j in range(i, -1, -1):
                alpha = (u[n + 1] - u[n - j]) / (u[n - j + i + 2] - u[n - j])
                transform[n - j] = (transform[n - j] - (1.0 - alpha) * transform[n - j - 1]) / alpha
        u[n + p + 1] = new[p - 1]
    else:
        for i in range(p - 1):
            u[p - i - 1] = new[p - i - 1]
            k = p - 1
            for j in range(i, -1, -1):
                alpha = (u[p] - u[k]) / (u[p + j + 1] - u[k])
                transform[j] = (transform[j] - alpha * transform[j + 1]) / (1.0 - alpha)
                k -= 1
        u[0] = new[0]
    return transform


def extended_knots(knots: np.ndarray, degree: int, side: str, end: float, spans: int) -> np.ndarray:
    """Knot vector of a curve grown by ``spans`` uniform spans up to the new end ``end``."""
    if side == "right":
        old_end = knots[-degree - 1]
        interior = old_end + (end - old_end) * (np.arange(1, spans) / spans)
        return np.concatenate([knots[: -degree - 1], [old_end], interior, np.full(degree + 1, end)])
    old_start = knots[degree]
    interior = end + (old_start - end) * (np.arange(1, spans) / spans)
    return np.concatenate([np.full(degree + 1, end), interior, [old_start], knots[degree + 1 :]])


def extend_curve(curve: BSplineCurve, side: str, pts: np.ndarray, t: np.ndarray, spacing_m: float,
                 max_noise_gain: float | None = None):
    """``extend_curve`` for valid input: (curve, psi, n_added, T), or FitError."""
    p = curve.degree
    k = pts.shape[0]
    lo, hi = curve.domain
    end = float(t.max() if side == "right" else t.min())
    extent = end - hi if side == "right" else lo - end
    distinct = np.unique(t)
    n_old = curve.n_control
    most = min(span_count(extent, spacing_m), distinct.shape[0])
    for spans in range(most, 0, -1):
        knots = extended_knots(curve.knots, p, side, end, spans)
        new_knots = knots[n_old + 1 : n_old + p + 1] if side == "right" else knots[spans : spans + p]
        transform = unclamp_transform(np.array(curve.knots, dtype=float), p, side, new_knots)
        new_cols = np.arange(n_old, n_old + spans) if side == "right" else np.arange(spans)
        old_cols = np.arange(n_old) if side == "right" else np.arange(spans, spans + n_old)
        if not satisfies_schoenberg_whitney(knots, p, distinct, slice(new_cols[0], new_cols[-1] + 1)):
            continue
        colloc = collocation_matrix(knots, p, t)
        g = least_squares_operator(colloc[:, new_cols], max_noise_gain)
        if g is None:
            continue
        psi = np.zeros((n_old + spans, n_old + k))
        psi[old_cols, :n_old] = transform
        psi[new_cols, :n_old] = -g @ colloc[:, old_cols] @ transform
        psi[new_cols, n_old:] = g
        control = psi @ np.concatenate([curve.control_points, pts])
        return BSplineCurve.unchecked(control, knots, p), psi, spans, transform
    raise FitError("no extension fits")
