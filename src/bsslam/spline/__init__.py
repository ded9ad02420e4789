"""B-spline maths for BS-SLAM: knots, basis, curves, fitting, closest points, ray
intersection and extension. Imports numpy and scipy only.

Everything speaks in *degree* p (order κ = p + 1); points are (m, 2) arrays in metres.
"""

from bsslam.spline.basis import basis_functions, collocation_matrix, find_span
from bsslam.spline.closest import closest_point
from bsslam.spline.curve import BSplineCurve
from bsslam.spline.extend import Extension, continuation_parameters, extend_curve, runs_outward, unclamp
from bsslam.spline.fit import FitResult, chord_length_parameters, fit_curve
from bsslam.spline.intersect import RayHits, intersect_rays
from bsslam.spline.knots import clamped_knots, knot_domain, n_control_points, uniform_knots
from bsslam.spline.pieces import PolynomialPieces

__all__ = [
    "BSplineCurve",
    "Extension",
    "FitResult",
    "PolynomialPieces",
    "RayHits",
    "basis_functions",
    "chord_length_parameters",
    "clamped_knots",
    "closest_point",
    "collocation_matrix",
    "continuation_parameters",
    "extend_curve",
    "find_span",
    "fit_curve",
    "intersect_rays",
    "knot_domain",
    "n_control_points",
    "runs_outward",
    "unclamp",
    "uniform_knots",
]
