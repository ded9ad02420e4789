"""Knot refinement for splines that enter the map: halve the knot spacing where a finer
fit shows the coarser one biased (a wall bending faster than the spacing allows).

A fit's global residual RMS hides a bias of a few millimetres over a few points, yet a map
spline's covariance is far below that there, and a wall seen again and again through the
same biased stretch pulls the pose the same way in every run. Numpy only.
"""

from __future__ import annotations

import numpy as np

from bsslam.errors import FitError
from bsslam.spline import FitResult, collocation_matrix, fit_curve


def fit_bias_scores(coarse: FitResult, fine: FitResult, points: np.ndarray, sigma_range: float) -> np.ndarray:
    """(m,) normalised difference, along the curve normal, between two fits of the same
    sensor-frame points (m, 2) on the same parameters.

    If the coarse fit is unbiased, ``δ = (H_f − H_c) d`` (H = B Φ, the hat matrices) is
    range noise only: along the normal n_j its variance is σ² Σ_k D_jk² (u_k·n_j)², u_k the
    beam direction of point k. A score far above 1 means the coarse spline cannot follow
    the wall there (e.g. where a straight wall meets an arc: its curvature jumps).
    """
    t = coarse.params
    deg = coarse.curve.degree
    D = (collocation_matrix(fine.curve.knots, deg, t) @ fine.phi
         - collocation_matrix(coarse.curve.knots, deg, t) @ coarse.phi)
    delta = D @ points
    tangent = fine.curve.evaluate(t, der=1)
    tangent /= np.maximum(np.hypot(tangent[:, 0], tangent[:, 1]), 1e-12)[:, None]
    n = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    u = points / np.maximum(np.hypot(points[:, 0], points[:, 1]), 1e-12)[:, None]
    D2 = D * D
    var = (D2 @ (u[:, 0] ** 2) * n[:, 0] ** 2 + 2.0 * (D2 @ (u[:, 0] * u[:, 1])) * n[:, 0] * n[:, 1]
           + D2 @ (u[:, 1] ** 2) * n[:, 1] ** 2) * sigma_range ** 2
    return np.abs(np.einsum("ij,ij->i", delta, n)) / np.sqrt(np.maximum(var, 1e-30))


def refine_for_map(fit: FitResult, points: np.ndarray, sigma_range: float, min_spacing_m: float,
                   max_score: float, *, max_noise_gain: float | None = None) -> FitResult:
    """Halve the knot spacing of a fit that is to enter the map while the finer fit shows
    the coarser one biased somewhere (:func:`fit_bias_scores` above ``max_score``).

    A fit's global residual RMS hides a bias of a few millimetres over a few points, but the
    map spline's covariance (built from many beams) is far below that there, and a wall
    seen again and again through the same biased stretch pulls the pose the same way in
    every run. The finer spacings are only used where the data demand them.
    """
    deg = fit.curve.degree
    length = float(fit.params[-1] - fit.params[0])
    while True:
        spans = fit.curve.n_control - deg
        spacing = length / (2 * spans)
        if spacing < min_spacing_m:
            return fit
        try:
            fine = fit_curve(points, deg, spacing * (1.0 + 1e-9), params=fit.params,
                             max_noise_gain=max_noise_gain)
        except FitError:
            return fit
        if fine.curve.n_control <= fit.curve.n_control:
            return fit
        if np.max(fit_bias_scores(fit, fine, points, sigma_range)) <= max_score:
            return fit
        fit = fine
