"""Closest point on a spline curve to query points (spec §4, data association): the
compiled search of :func:`bsslam.spline.batch.closest_points_batch` on a one-curve table.
The numpy form it follows step for step is the tests' oracle (``tests/spline/closest_oracle.py``)."""

from __future__ import annotations

import numpy as np

from bsslam.errors import SplineError
from bsslam.spline.basis import as_parameters
from bsslam.spline.batch import closest_points_batch, curve_table
from bsslam.spline.curve import BSplineCurve, as_points


def closest_point(
    curve: BSplineCurve,
    queries: object,
    t0: object = None,
    *,
    sample_step_m: float = 0.1,
    samples_per_span: int = 4,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point of ``curve`` nearest to each query point (spec §4).

    Without ``t0`` the curve is sampled about every ``sample_step_m`` of arc length (at
    least ``samples_per_span`` times per knot span); Newton on ``f(t) = (s(t) − q)·s'(t)``
    starts from every local minimum of the sampled distance and from both its neighbouring
    samples, and the best result wins. That finds the global minimum unless another basin
    comes within the sampling resolution of it: the distance returned is at most the true
    one plus ``sample_step_m``, and exact in all ordinary cases. With ``t0`` Newton starts
    from it alone: a local refinement.

    Iterates are clamped to the domain, so an end of the curve is returned when the nearest
    point is there (where f ≠ 0). Where ``f'(t) = |s'|² + (s − q)·s''`` is not positive
    (near a distance maximum) the Gauss–Newton step ``−f/|s'|²`` is taken, which always
    points downhill.

    Args:
        curve: the spline.
        queries: (q, 2) query points (m).
        t0: optional (q,) starting parameters (m); NaN entries mean "no guess".
        sample_step_m: largest arc length between coarse samples (m), when ``t0`` is None.
        samples_per_span: fewest coarse samples per knot span (≥ 2).

    Returns:
        ``(t, points, distance)``: t (q,) parameters (m), points (q, 2) on the curve (m),
        distance (q,) Euclidean distances (m).
    """
    q = as_points(queries, "queries")
    guess = None if t0 is None else as_parameters(t0)
    if guess is not None and guess.shape != (q.shape[0],):
        raise SplineError(f"t0 must have shape ({q.shape[0]},), got {guess.shape}")
    batch = curve_table([curve.knots], [curve.degree]).with_control_points(curve.control_points)
    return closest_points_batch(batch, np.zeros(q.shape[0], dtype=np.intp), q, guess,
                                sample_step_m=sample_step_m, samples_per_span=samples_per_span)
