"""Map features: B-spline curves whose control points live in the joint state.

In full SLAM a feature owns two index arrays into the state (its x and y control-point
coordinates, in curve order). In localisation mode (spec §9) the state holds the pose only
and a feature keeps fixed control points with zero uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.spline import BSplineCurve


@dataclass
class SplineFeature:
    """One map spline.

    Attributes:
        id: stable identifier.
        degree: polynomial degree (order − 1).
        knots: (n + degree + 1,) knot vector.
        idx_x, idx_y: (n,) state indices of the control points' x / y (full SLAM), or None.
        fixed_control_points: (n, 2) control points (localisation mode), or None.
        observations: scans in which the feature was used in an update.
        created: index of the step that created it.
    """

    id: int
    degree: int
    knots: np.ndarray
    idx_x: np.ndarray | None = None
    idx_y: np.ndarray | None = None
    fixed_control_points: np.ndarray | None = None
    observations: int = 0
    created: int = 0

    @property
    def in_state(self) -> bool:
        return self.idx_x is not None

    @property
    def state_indices(self) -> np.ndarray:
        """(2n,) [x_0 … x_n, y_0 … y_n] indices (paper (17) ordering)."""
        return np.concatenate([self.idx_x, self.idx_y])

    def control_points(self, x: np.ndarray) -> np.ndarray:
        """(n, 2) current control points, read from the state mean ``x`` when in the state."""
        if self.in_state:
            return np.column_stack([x[self.idx_x], x[self.idx_y]])
        return self.fixed_control_points

    def curve(self, x: np.ndarray) -> BSplineCurve:
        return BSplineCurve.unchecked(self.control_points(x), self.knots, self.degree)


@dataclass(frozen=True)
class MapSpline:
    """Public, immutable view of one map spline.

    Attributes:
        id: stable identifier.
        curve: the spline (world frame, m).
        covariance: (2n, 2n) covariance of [x_0 … x_{n−1}, y_0 … y_{n−1}] (m²); zeros in
            localisation mode.
        submap: the submap it was mapped in (``backend: submaps``; 0 otherwise); its
            covariance is relative to that submap's base pose.
        surface: splines of different submaps lying on one another share this id (the
            same wall mapped twice); None when not computed.
    """

    id: int
    curve: BSplineCurve
    covariance: np.ndarray
    submap: int = 0
    surface: int | None = None

    @property
    def order(self) -> int:
        return self.curve.degree + 1

    @property
    def position_sigma(self) -> float:
        """How well the spline's place is known (m): the median over its control points
        of √ the largest eigenvalue of each one's 2 × 2 covariance block (the median, not
        the largest: an end control point can be loose while the curve is fixed)."""
        n = self.curve.control_points.shape[0]
        c = self.covariance
        if n == 0 or c.size == 0:
            return 0.0
        i = np.arange(n)
        a, d, b = c[i, i], c[n + i, n + i], c[i, n + i]
        largest = 0.5 * (a + d) + np.sqrt(0.25 * (a - d) ** 2 + b * b)
        return float(np.sqrt(max(float(np.median(largest)), 0.0)))
