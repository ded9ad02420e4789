"""The planar B-spline curve: control points, knots and degree, and what it can compute."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from bsslam.errors import SplineError
from bsslam.spline import kernels
from bsslam.spline.basis import as_parameters, basis_functions
from bsslam.spline.knots import check_degree, check_knots, knot_domain
from bsslam.spline.pieces import PolynomialPieces, polynomial_pieces


def as_points(points: object, name: str = "points") -> np.ndarray:
    """Points as a finite float64 (m, 2) array, or SplineError."""
    arr = np.asarray(points, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise SplineError(f"{name} must have shape (m, 2), got {arr.shape}")
    # np.all's reduction without its five wrapper calls (fits check every scan's points)
    if not np.logical_and.reduce(np.isfinite(arr), axis=None):
        raise SplineError(f"{name} must be finite")
    return arr


def rotation_matrix(angle_rad: float) -> np.ndarray:
    """(2, 2) matrix of the counter-clockwise rotation by ``angle_rad``."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s], [s, c]])


@dataclass(frozen=True, eq=False)
class BSplineCurve:
    """A planar B-spline curve ``s(t) = Σ_i β_{i,p}(t) x_i`` (spec §1).

    Attributes:
        control_points: (n_control, 2) control points x_i, columns x, y (m).
        knots: (n_control + degree + 1,) non-decreasing knot vector (m of arc length).
        degree: polynomial degree p (the order is κ = p + 1).

    The constructor validates and copies its inputs (read-only arrays) and raises
    SplineError naming the problem; :meth:`unchecked` skips both for the filter's hot loop.
    Parameters outside the domain are clamped into it (no extrapolation).
    """

    control_points: np.ndarray
    knots: np.ndarray
    degree: int

    def __post_init__(self) -> None:
        degree = check_degree(self.degree)
        knots = np.array(check_knots(self.knots, degree), dtype=float)
        control_points = np.array(as_points(self.control_points, "control_points"), dtype=float)
        expected = knots.shape[0] - degree - 1
        if control_points.shape[0] != expected:
            raise SplineError(
                f"{knots.shape[0]} knots of a degree-{degree} spline need {expected} control points, "
                f"got {control_points.shape[0]}")
        knots.flags.writeable = False
        control_points.flags.writeable = False
        object.__setattr__(self, "degree", degree)
        object.__setattr__(self, "knots", knots)
        object.__setattr__(self, "control_points", control_points)

    @classmethod
    def unchecked(cls, control_points: np.ndarray, knots: np.ndarray, degree: int) -> BSplineCurve:
        """Build without validation or copies: float64 arrays of matching sizes are the
        caller's promise, and they must not be modified afterwards (results are cached)."""
        curve = object.__new__(cls)
        object.__setattr__(curve, "control_points", control_points)
        object.__setattr__(curve, "knots", knots)
        object.__setattr__(curve, "degree", degree)
        return curve

    @property
    def order(self) -> int:
        """Order κ = degree + 1."""
        return self.degree + 1

    @property
    def n_control(self) -> int:
        """Number of control points."""
        return self.control_points.shape[0]

    @property
    def domain(self) -> tuple[float, float]:
        """Valid parameter interval ``(knots[degree], knots[-degree-1])`` (m)."""
        return knot_domain(self.knots, self.degree)

    @functools.cached_property
    def pieces(self) -> PolynomialPieces:
        """The same curve as per-span polynomials (computed once, on first use)."""
        return polynomial_pieces(self.control_points, self.knots, self.degree)

    def derivatives(self, t: object, nder: int) -> np.ndarray:
        """Curve point and derivatives 0 … nder at parameters ``t`` (scalar or (m,), m).

        Returns:
            (nder+1, m, 2): entry k is ``dᵏs/dtᵏ`` (m / mᵏ).
        """
        span, values = basis_functions(self.knots, self.degree, t, nder)
        local = self.control_points[span[:, None] - self.degree + np.arange(self.degree + 1)]
        return np.einsum("kmr,mrd->kmd", values, local)

    def evaluate(self, t: object, der: int = 0) -> np.ndarray:
        """Curve point (``der`` = 0) or its ``der``-th derivative at ``t``, shape (m, 2)."""
        if der == 0:
            # compiled (kernels.curve_points): the basis and the sum below, per parameter
            # in the same order; a whole-array evaluation cost ~30 numpy calls per curve
            return kernels.curve_points(np.ascontiguousarray(self.knots, dtype=float), self.degree,
                                        np.ascontiguousarray(self.control_points, dtype=float), as_parameters(t))
        span, values = basis_functions(self.knots, self.degree, t, der)
        local = self.control_points[span[:, None] - self.degree + np.arange(self.degree + 1)]
        return np.einsum("mr,mrd->md", values[der], local)

    __call__ = evaluate

    def length(self, *, rtol: float = 1e-10) -> float:
        """Arc length over the domain (m).

        Composite 10-point Gauss–Legendre on every span, halving the sub-intervals until
        two successive estimates agree to ``rtol``: the speed |s'| is smooth on a span but
        can vary sharply where the curve turns tightly, so a fixed rule is not enough.
        """
        nodes, weights = np.polynomial.legendre.leggauss(10)
        previous = np.nan
        for level in range(12):
            edges = self.pieces.subdivide(2**level)
            half = 0.5 * np.diff(edges)
            mid = 0.5 * (edges[:-1] + edges[1:])
            t = (mid[:, None] + half[:, None] * nodes).ravel()
            speed = np.linalg.norm(self.pieces.evaluate(t, 1)[1], axis=1).reshape(half.shape[0], -1)
            estimate = float(np.sum(half * (speed @ weights)))
            if abs(estimate - previous) <= rtol * estimate:
                break
            previous = estimate
        return estimate

    def bbox(self) -> np.ndarray:
        """(4,) ``xmin, ymin, xmax, ymax`` of the control polygon (m); contains the curve."""
        return np.concatenate([self.control_points.min(axis=0), self.control_points.max(axis=0)])

    def transformed(self, rotation_rad: float, translation: object) -> BSplineCurve:
        """The curve moved rigidly, ``p → R(rotation_rad) p + translation`` (affine invariance)."""
        shift = np.asarray(translation, dtype=float).reshape(2)
        moved = self.control_points @ rotation_matrix(rotation_rad).T + shift
        return BSplineCurve.unchecked(moved, self.knots, self.degree)

    def with_control_points(self, control_points: object) -> BSplineCurve:
        """Same knots and degree, new (n_control, 2) control points; not validated."""
        return BSplineCurve.unchecked(np.asarray(control_points, dtype=float), self.knots, self.degree)
