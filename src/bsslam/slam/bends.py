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

The same holds between the walls of one scan. Two straight walls a few milliradians from
parallel say, to first order, where along them the robot is (moving along the corridor
brings it nearer one and farther from the other); but the walls' relative tilt is their
fits' noise, and with the large along-corridor prior the linearised update reads it as
information (the simulated long corridor: the estimate pushed ahead by about 4 mm a step,
docs/consistency.md, "Between the walls"). So, after the per-spline weights, the scan's
weakest direction e (the smaller eigenvector of Σ g gᵀ over its rows, g = ∂z/∂(x, y)) is
weighed the same way: its information S = λ_min against what walls truly parallel would
give it through their directions' noise, N = Σ_j I_j Var(ψ_j), ψ_j the mean tangent angle of
wall j less the walls' I-weighted mean (I_j = Σ |g|² over its rows), and what every row says
along e is scaled by w = max(0, 1 − N/S) (:func:`wall_angle_weight`). A corner, an arc or a
wall across the corridor in view gives S ≫ N and keeps everything; parallel walls alone
give S ≈ N and say little along themselves.
"""

from __future__ import annotations

import math

import numpy as np

from bsslam.slam import bend_kernels
from bsslam.slam.bend_kernels import significance
from bsslam.spline.batch import CurveTable


def spline_bends(table: CurveTable, control_points: np.ndarray, curve: np.ndarray, t_first: np.ndarray,
                 t_last: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The angle Δθ each of g curves of ``table`` turns between two parameters, and its
    gradient over the curves' control points, for all of them at once.

    Args:
        table: the curves' knot structure; control_points: (N, 2) its stacked control
            points at the linearisation point (m).
        curve: (g,) curve indices; t_first, t_last: (g,) the parameters of each curve's
            first and last hit (m), finite.

    Returns:
        ``(bend, rows, grad)``: bend (g,) the tangent angle at ``t_last`` less that at
        ``t_first``, wrapped (rad); rows (g, 2(p+1)) the control-point rows (of
        ``control_points``) the tangents depend on, the first parameter's window then the
        last's; grad (g, 2(p+1), 2) ∂Δθ/∂(x, y) of each of those rows (rad/m), zero on a
        window's padding. A row may appear twice (both windows); its gradients then add.
        The tangent angle of C'(t) = Σ_j β'_j(t) c_j moves by
        δθ = (C'_x δC'_y − C'_y δC'_x)/|C'|².
    """
    return bend_kernels.tangent_turns(table.power_basis, table.window, table.real, table.piece_lo, table.piece_start,
                                      table.lo, table.hi, np.asarray(curve, dtype=np.intp),
                                      np.asarray(t_first, dtype=float), np.asarray(t_last, dtype=float),
                                      np.ascontiguousarray(control_points, dtype=float))


def weakest_direction(H_c: np.ndarray) -> tuple[np.ndarray, float]:
    """``(e (2,), λ)``: the unit direction along which the rows' robot-position Jacobians
    (the first two columns of H_c (m, c)) say least, and what they say along it, λ the
    smaller eigenvalue of Σ g gᵀ (dimensionless, as g is); in closed form for the 2 × 2
    (numpy's ``eigh`` is the oracle in the tests): the larger eigenvector lies at half the
    angle atan2(2 b, a − c) of [[a, b], [b, c]], and e a quarter turn from it."""
    g = H_c[:, :2]
    (a, b), (_, c) = (g.T @ g).tolist()
    angle = 0.5 * math.atan2(2.0 * b, a - c)
    smaller = 0.5 * (a + c) - math.hypot(0.5 * (a - c), b)
    return np.array([-math.sin(angle), math.cos(angle)]), max(smaller, 0.0)


def wall_angle_weight(H_c: np.ndarray, noise: float) -> tuple[np.ndarray, float]:
    """``(e (2,), w)``: the scan's weakest direction (:func:`weakest_direction` of the rows
    H_c, after the per-spline weights) and the weight of what the rows say along it, w =
    max(0, 1 − N/λ) for the ``noise`` N = Σ_j I_j Var(ψ_j) that walls truly parallel would
    give λ through their directions' uncertainty (the module docstring, :func:`~bsslam.slam.bend_kernels.significance`)."""
    e, signal = weakest_direction(H_c)
    return e, significance(signal, float(noise))
