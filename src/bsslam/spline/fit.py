"""Least-squares fitting of a clamped B-spline to an ordered run of laser points (spec §2).

The control points are a fixed linear map of the data, ``X = Φ D`` with
``Φ = (BᵀB)⁻¹Bᵀ`` (paper (11)); the filter's Jacobians reuse Φ, so it is returned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from bsslam.errors import FitError, SplineError
from bsslam.spline.basis import basis_functions, collocation_matrix
from bsslam.spline.curve import BSplineCurve, as_points
from bsslam.spline.knots import check_degree, clamped_knots_with_spans, span_count

# Relative size of R's smallest diagonal entry (QR of the collocation matrix) below which
# the least-squares problem counts as singular even though Schoenberg–Whitney holds: data
# that barely touch a basis function's support would give huge, noise-amplifying Φ.
_RANK_TOLERANCE = 1e-10


def chord_length_parameters(points: object, start: float = 0.0) -> np.ndarray:
    """Cumulative chord length of an ordered point run (paper (9)).

    Args:
        points: (m, 2) points (m), m ≥ 1.
        start: parameter of the first point (m).

    Returns:
        (m,) non-decreasing parameters, ``t_0 = start``, ``t_j = start + Σ_{s≤j} |d_s − d_{s−1}|``.
    """
    pts = as_points(points)
    if pts.shape[0] < 1:
        raise SplineError("need at least one point")
    steps = np.hypot(*np.diff(pts, axis=0).T)
    return start + np.concatenate([[0.0], np.cumsum(steps)])


def satisfies_schoenberg_whitney(
    knots: np.ndarray, degree: int, params: np.ndarray, columns: slice = slice(None)
) -> bool:
    """Whether the collocation matrix's ``columns`` have full column rank in exact arithmetic.

    Schoenberg–Whitney: the basis functions can be matched to distinct data parameters in
    order, each inside the support of its function. With sorted data every support holds a
    contiguous run of data ``[first_i, last_i]`` and both ends grow with i, so the greedy
    match (earliest free datum) decides it; it is a running maximum, so no loop is needed.

    Args:
        knots: knot vector.
        degree: polynomial degree p.
        params: (m,) strictly increasing data parameters inside the domain (m).
        columns: which basis functions must be determined by the data.
    """
    span, values = basis_functions(knots, degree, params)
    n_control = knots.shape[0] - degree - 1
    m = params.shape[0]
    nonzero = values[0] > 0
    basis = (span[:, None] - degree + np.arange(degree + 1))[nonzero]
    rows = np.broadcast_to(np.arange(m)[:, None], nonzero.shape)[nonzero]
    first = np.full(n_control, m)
    last = np.full(n_control, -1)
    np.minimum.at(first, basis, rows)
    np.maximum.at(last, basis, rows)
    first, last = first[columns], last[columns]
    if first.size == 0 or np.any(last < 0):
        return False
    k = np.arange(first.shape[0])
    matched = k + np.maximum.accumulate(first - k)
    return bool(np.all(matched <= last))


def least_squares_operator(collocation: np.ndarray, max_noise_gain: float | None = None) -> np.ndarray | None:
    """``(BᵀB)⁻¹Bᵀ`` for an (m, n) collocation matrix B, by QR; None if B is rank deficient
    or, with ``max_noise_gain``, if some row of the result has a larger 2-norm.

    A row's norm is how much it amplifies independent noise on the data into its control
    point (σ_cp = norm · σ_data). Well-posed fits stay below about 2.5; a basis function
    barely touched by data passes the rank test yet amplifies noise by 10⁶ or more, and such
    a control point would wreck a covariance it enters.
    """
    m, n = collocation.shape
    if m < n:
        return None
    q, r = np.linalg.qr(collocation)
    diag = np.abs(np.diag(r))
    if diag.min() <= _RANK_TOLERANCE * diag.max():
        return None
    phi = scipy.linalg.solve_triangular(r, q.T, check_finite=False)
    if max_noise_gain is not None and np.max(np.einsum("ij,ij->i", phi, phi)) > max_noise_gain ** 2:
        return None
    return phi


def check_params(params: object, m: int) -> np.ndarray:
    """Data parameters as a finite, non-decreasing float64 (m,) array, or SplineError."""
    t = np.asarray(params, dtype=float)
    if t.shape != (m,):
        raise SplineError(f"params must have shape ({m},), got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise SplineError("params must be finite")
    if np.any(np.diff(t) < 0):
        raise SplineError("params must be non-decreasing (an ordered point run)")
    return t


@dataclass(frozen=True, eq=False)
class FitResult:
    """A least-squares spline fit.

    Attributes:
        curve: the fitted clamped curve.
        phi: (n_control, m) ``Φ``: ``curve.control_points == phi @ points`` (x and y alike).
        params: (m,) parameter of each data point (m).
    """

    curve: BSplineCurve
    phi: np.ndarray
    params: np.ndarray


def fit_curve(points: object, degree: int, spacing_m: float, params: object = None, *,
              max_noise_gain: float | None = None) -> FitResult:
    """Least-squares clamped B-spline through an ordered point run (spec §2).

    Args:
        points: (m, 2) data points d_j in order along the run (m).
        degree: polynomial degree p (order κ = p + 1).
        spacing_m: target knot spacing ρ (m).
        params: optional (m,) non-decreasing parameters; default chord length from 0.
        max_noise_gain: if given, a number of spans whose Φ amplifies data noise more than
            this (largest row 2-norm) counts as ill-posed, like a Schoenberg–Whitney failure.

    Returns:
        FitResult on ``clamped_knots(params[-1] − params[0], spacing_m, degree,
        start=params[0])``, or on fewer spans if that knot vector violates
        Schoenberg–Whitney (e.g. a gap in the data).

    Raises:
        FitError: fewer distinct parameters than degree + 1, all points at one parameter,
            or no number of spans ≥ 1 gives a well-posed fit.
        SplineError: malformed input (shapes, non-finite values, bad spacing).
    """
    degree = check_degree(degree)
    pts = as_points(points)
    m = pts.shape[0]
    if m < degree + 1:
        raise FitError(f"a degree-{degree} fit needs at least {degree + 1} points, got {m}")
    t = chord_length_parameters(pts) if params is None else check_params(params, m)
    length = float(t[-1] - t[0])
    if not length > 0:
        raise FitError("all points share one parameter (coincident points); nothing to fit")
    distinct = np.unique(t)
    # n_control = spans + degree can never exceed the number of distinct parameters.
    most = min(span_count(length, spacing_m), distinct.shape[0] - degree)
    for spans in range(most, 0, -1):
        knots = clamped_knots_with_spans(length, spans, degree, start=float(t[0]))
        knots[-degree - 1 :] = t[-1]  # exactly the last parameter, not start + length
        if not satisfies_schoenberg_whitney(knots, degree, distinct):
            continue
        phi = least_squares_operator(collocation_matrix(knots, degree, t), max_noise_gain)
        if phi is None:
            continue
        curve = BSplineCurve.unchecked(phi @ pts, knots, degree)
        return FitResult(curve=curve, phi=phi, params=t)
    raise FitError(
        f"no degree-{degree} spline with 1..{max(most, 1)} spans fits these {m} points "
        "(Schoenberg–Whitney fails: too few distinct points)")
