"""How much a map spline may tell the filter along itself: only as much as its bend is
significant.

A beam's range constrains the laser along the normal of the wall it hits (∂z/∂p = g, which
is parallel to that normal). The beams on one spline therefore say something along the
spline only through the differences of their normals, i.e. through the spline's bend. Down a
straight corridor the estimated wall is straight up to its own noise: a few milliradians of
fitted wiggle, or of a kink where an extension joined it. A linearised update reads those
as a shape and takes information along the corridor from them — little from one scan, but
with the large along-corridor prior every scan pulls the pose the same way, and the filter
grows overconfident and wrong along the wall (the 80 × 50 m corridor loop: time-averaged
pose NEES 120, against 13 once this information is limited as below; see
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


def spline_bend_weight(hit_t: np.ndarray, knots: np.ndarray, degree: int, control_points: np.ndarray,
                       idx_x: np.ndarray, idx_y: np.ndarray, variance_of) -> float:
    """w of one spline in one scan: Δθ between its first and last hit (``hit_t`` (k,), m)
    and its variance under the prior, ``variance_of(state_indices, row)`` → the prior
    variance of row · x[state_indices] (a window's innovation variance with R = 0).

    Args:
        knots, degree, control_points: the spline at the linearisation point.
        idx_x, idx_y: (n,) the state indices of its control points.
    """
    angle, grad = tangent_angle_rows(knots, degree, control_points, np.array([hit_t.min(), hit_t.max()]))
    bend = float(wrap_angle(angle[1] - angle[0]))
    return bend_weight(bend, float(variance_of(np.concatenate([idx_x, idx_y]), grad[1] - grad[0])))


def scale_along_spline(H_c: np.ndarray, cols: np.ndarray, rows: np.ndarray, w: float,
                       idx_x: np.ndarray, idx_y: np.ndarray) -> None:
    """Scale, in place, the part of the Jacobian rows ``rows`` of one spline's beams along
    the spline's mean tangent (over those beams) by ``w``.

    Args:
        H_c: (m, c) the stacked Jacobian on ``cols`` (c,), the pose's x, y first; for every
            row ∂z/∂(x, y) = g and ∂z/∂(x_j, y_j) = −β_j g (paper (22)–(27)), so g is scaled
            in both: the robot and the spline moved along the spline alike.
        rows: the rows of this spline's beams.
        idx_x, idx_y: (n,) the state indices of its control points.
    """
    g = H_c[rows, :2]
    g2 = np.einsum("ij,ij->i", g, g)
    normal = (g / np.sqrt(g2)[:, None]).sum(axis=0)
    normal /= np.hypot(*normal)
    tangent = np.array([-normal[1], normal[0]])
    removed = (1.0 - w) * (g @ tangent)      # (k,) each row's along-tangent part taken out
    # β of each row's control points, from H = −β g, before g changes
    position = np.full(max(int(cols.max()), int(idx_x.max()), int(idx_y.max())) + 1, -1, dtype=np.intp)
    position[cols] = np.arange(cols.shape[0])
    px, py = position[idx_x], position[idx_y]
    present = (px >= 0) & (py >= 0)
    px, py = px[present], py[present]
    beta = -(H_c[np.ix_(rows, px)] * g[:, :1] + H_c[np.ix_(rows, py)] * g[:, 1:]) / g2[:, None]
    H_c[rows, 0] -= removed * tangent[0]
    H_c[rows, 1] -= removed * tangent[1]
    # −β (g − removed·tangent) = −β g + β·removed·tangent
    H_c[np.ix_(rows, px)] += beta * (removed * tangent[0])[:, None]
    H_c[np.ix_(rows, py)] += beta * (removed * tangent[1])[:, None]
