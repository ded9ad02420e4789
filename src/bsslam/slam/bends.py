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

from bsslam.slam import bend_kernels
from bsslam.spline.batch import CurveTable


def spline_bends(table: CurveTable, control_points: np.ndarray, curve: np.ndarray, t_first: np.ndarray,
                 t_last: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The angle Δθ each of g curves of ``table`` turns between two parameters, and its
    gradient over the curves' control points, for all of them at once.

    Args:
        table: the curves' knot structure; control_points: (N, 2) its stacked control
            points at the linearisation point (m).
        curve: (g,) curve indices; t_first, t_last: (g,) the parameters of each curve's
            first and last hit (m).

    Returns:
        ``(bend, rows, grad)``: bend (g,) the tangent angle at ``t_last`` less that at
        ``t_first``, wrapped (rad); rows (g, 2(p+1)) the control-point rows (of
        ``control_points``) the tangents depend on, the first parameter's window then the
        last's; grad (g, 2(p+1), 2) ∂Δθ/∂(x, y) of each of those rows (rad/m), zero on a
        window's padding. A row may appear twice (both windows); its gradients then add.
        The tangent angle of C'(t) = Σ_j β'_j(t) c_j moves by
        δθ = (C'_x δC'_y − C'_y δC'_x)/|C'|².
    """
    piece, u, _ = table.locate(np.concatenate([curve, curve]), np.concatenate([t_first, t_last]))
    return bend_kernels.tangent_turns(table.power_basis, table.window, table.real, piece, u,
                                      np.ascontiguousarray(control_points, dtype=float))


def bend_weights(bend_rad: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """w = max(0, 1 − σ²/Δθ²) ∈ [0, 1] of each bend (g,) (rad) under its variance (g,)
    (rad²): 0 for a bend within its noise, → 1 for a significant one (0 for no bend at all)."""
    b2 = np.square(np.asarray(bend_rad, dtype=float))
    v = np.asarray(variance, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(b2 <= v, 0.0, 1.0 - v / b2)
