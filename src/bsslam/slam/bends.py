"""How much a map spline may tell the filter along itself: only as much as its bend is
significant.

A beam's range constrains the laser along the normal of the wall it hits (∂z/∂p = g, which
is parallel to that normal). The beams on one spline therefore say something along the
spline only through the differences of their normals, i.e. through the spline's bend. Down a
straight corridor the estimated wall is straight up to its own noise: a few milliradians of
fitted wiggle, or of a kink where an extension joined it. A linearised update reads those
as a shape and takes information along the corridor from them — little from one scan, but
with the large along-corridor prior every scan pulls the pose the same way, and the filter
grows overconfident and wrong along the wall (the 80 × 50 m corridor loop, 5 seeds:
time-averaged pose NEES 12.9 without spline extension, 7.7 once this information is
limited as below; with extension 85 and 75, extension being the larger fault there; see
``benchmarks/corridor_consistency.py``).

So per matched spline and scan the component of each beam's Jacobian along the spline's
mean tangent (over those beams) is scaled by w = max(0, 1 − σ²/Δθ²), where Δθ is the angle
the spline turns between its first and last hit and σ² its variance under the prior
covariance (the spline's shape and its correlation with everything else): a straight wall
(Δθ within its noise) gives nothing along itself; a corner or a curved wall (Δθ ≫ σ) keeps
all it has. w is continuous in the data, so no tiny change of the input flips it.
"""

from __future__ import annotations

import numpy as np

from bsslam.spline.basis import basis_functions
from bsslam.trajectory import wrap_angle


def tangent_angle_rows(knots: np.ndarray, degree: int, control_points: np.ndarray,
                       t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tangent angle of a B-spline at parameters ``t`` and its gradient.

    Args:
        knots, degree: the spline's knots and degree; control_points: (n, 2) (m).
        t: (k,) parameters within the domain (m).

    Returns:
        ``(angle, rows)``: angle (k,) of C'(t) (rad), rows (k, 2n) ∂angle/∂[x_0 … x_{n−1},
        y_0 … y_{n−1}] (rad/m): δθ = (C'_x δC'_y − C'_y δC'_x)/|C'|², δC' = Σ_j β'_j(t) δc_j.
    """
    span, values = basis_functions(knots, degree, np.asarray(t, dtype=float), 1)
    n = control_points.shape[0]
    rows = np.zeros((len(span), 2 * n))
    angle = np.empty(len(span))
    for i, s in enumerate(span):
        cols = np.arange(s - degree, s + 1)
        d_beta = values[1, i]
        d = d_beta @ control_points[cols]
        scale = 1.0 / (d @ d)
        angle[i] = np.arctan2(d[1], d[0])
        rows[i, cols] = -d_beta * d[1] * scale
        rows[i, n + cols] = d_beta * d[0] * scale
    return angle, rows


def bend_weight(bend_rad: float, variance: float) -> float:
    """w = max(0, 1 − σ²/Δθ²) ∈ [0, 1]: 0 for a bend within its noise, → 1 for a
    significant one (0 for no bend at all)."""
    if bend_rad * bend_rad <= variance:
        return 0.0
    return 1.0 - variance / (bend_rad * bend_rad)


def spline_bend(hit_t: np.ndarray, knots: np.ndarray, degree: int,
                control_points: np.ndarray) -> tuple[float, np.ndarray]:
    """The angle Δθ (rad) one spline turns between its first and last hit (``hit_t`` (k,),
    m) and its gradient (2n,) over the spline's [x_0 … x_{n−1}, y_0 … y_{n−1}] (rad/m).

    Args:
        knots, degree, control_points: the spline at the linearisation point, (n, 2) (m).
    """
    angle, grad = tangent_angle_rows(knots, degree, control_points, np.array([hit_t.min(), hit_t.max()]))
    return float(wrap_angle(angle[1] - angle[0])), grad[1] - grad[0]


def scale_along_splines(H_c: np.ndarray, cols: np.ndarray, group: np.ndarray, weights: dict[int, float],
                        control_indices: dict[int, tuple[np.ndarray, np.ndarray]]) -> None:
    """Scale, in place, the part of each spline's Jacobian rows along the spline's mean
    tangent (over its rows) by its weight; one pass over all rows.

    Args:
        H_c: (m, c) the stacked Jacobian on ``cols`` (c,), the pose's x, y first; for every
            row ∂z/∂(x, y) = g and ∂z/∂(x_j, y_j) = −β_j g (paper (22)–(27)), so g is scaled
            in both: the robot and the spline moved along the spline alike.
        group: (m,) each row's spline (its curve index).
        weights: {curve index: w} of the splines to scale (others are left as they are).
        control_indices: {curve index: (idx_x, idx_y)} the state indices of each weighted
            spline's control points.
    """
    g = H_c[:, :2]
    g2 = np.einsum("ij,ij->i", g, g)
    labels = np.array(sorted(weights), dtype=np.intp)
    slot = np.searchsorted(labels, group)
    slot[slot == labels.shape[0]] = 0
    weighted = labels[slot] == group
    unit = g / np.sqrt(g2)[:, None]
    normal = np.zeros((labels.shape[0], 2))
    np.add.at(normal, slot[weighted], unit[weighted])
    normal /= np.hypot(normal[:, 0], normal[:, 1])[:, None]
    tangent = np.column_stack([-normal[:, 1], normal[:, 0]])[slot]      # (m, 2) each row's
    keep = np.array([weights[int(c)] for c in labels])[slot]
    removed = np.where(weighted, (1.0 - keep) * np.einsum("ij,ij->i", g, tangent), 0.0)
    # β of each row's control points, from H = −β g, before g changes (zero off its spline)
    idx_x = np.concatenate([control_indices[int(c)][0] for c in labels])
    idx_y = np.concatenate([control_indices[int(c)][1] for c in labels])
    position = np.full(max(int(cols.max()), int(idx_x.max()), int(idx_y.max())) + 1, -1, dtype=np.intp)
    position[cols] = np.arange(cols.shape[0])
    px, py = position[idx_x], position[idx_y]
    present = (px >= 0) & (py >= 0)
    px, py = px[present], py[present]
    beta = -(H_c[:, px] * g[:, :1] + H_c[:, py] * g[:, 1:]) / g2[:, None]
    shift = removed[:, None] * tangent
    H_c[:, :2] -= shift
    # −β (g − removed·tangent) = −β g + β·removed·tangent
    H_c[:, px] += beta * shift[:, :1]
    H_c[:, py] += beta * shift[:, 1:]
