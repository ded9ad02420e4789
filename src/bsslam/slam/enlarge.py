"""Map enlargement: new splines (spec §8.1) and extension of known ones (spec §8.2).

Both are linear maps of data points ``d_j = p_l + z_j (cos μ_j, sin μ_j)`` (and, for an
extension, of the old control points), so their covariance follows exactly from the
Jacobians w.r.t. the robot pose, the old control points and the ranges. These functions
return the linear pieces; :class:`bsslam.slam.filter.SplineSLAM` applies them to the state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.slam import enlarge_kernels
from bsslam.slam.measurement import laser_pose


@dataclass(frozen=True)
class BeamPoints:
    """World points of k beams and their derivatives.

    Attributes:
        points: (k, 2) world points (m).
        d_dpose: (2, k, 3) ∂(x, y) of each point w.r.t. the robot pose.
        d_drange: (2, k) ∂(x, y) of each point w.r.t. its own range (cos μ, sin μ).
    """

    points: np.ndarray
    d_dpose: np.ndarray
    d_drange: np.ndarray

    def subset(self, keep: np.ndarray) -> BeamPoints:
        """The beams in ``keep`` ((k,) bool)."""
        return BeamPoints(self.points[keep], self.d_dpose[:, keep], self.d_drange[:, keep])


def beam_points(robot_pose: np.ndarray, laser_offset: np.ndarray, bearings: np.ndarray,
                ranges: np.ndarray) -> BeamPoints:
    """World points of beams (bearing rad, range m) with their Jacobians."""
    lp = laser_pose(robot_pose, laser_offset)
    mu = lp[2] + bearings
    cm, sm = np.cos(mu), np.sin(mu)
    c, s = np.cos(robot_pose[2]), np.sin(robot_pose[2])
    ox, oy = laser_offset[0], laser_offset[1]
    return BeamPoints(*enlarge_kernels.beam_arrays(lp[0], lp[1], cm, sm, np.asarray(ranges, dtype=float),
                                                   -s * ox - c * oy, c * ox - s * oy))


@dataclass(frozen=True)
class LinearBlock:
    """New state entries ``v = J · x[cols] + (terms in the ranges)``, linearised.

    Attributes:
        mean: (q,) the new entries' values.
        cols: (c,) state indices they depend on.
        J: (q, c) Jacobian w.r.t. ``x[cols]``.
        G_z: (q, k) Jacobian w.r.t. the k ranges.
    """

    mean: np.ndarray
    cols: np.ndarray
    J: np.ndarray
    G_z: np.ndarray

    def noise(self, range_variance: float, shared_variance: float = 0.0) -> np.ndarray:
        """(q, q) the ranges' share of the new entries' covariance (m²): independent ranges
        of variance R and one error of variance s shared by all k of them (they are one
        scan's beams on one surface), R G_z G_zᵀ + s (G_z 1)(G_z 1)ᵀ; the rest,
        J P[cols, cols] Jᵀ and the cross terms J P[cols, :], are the state's
        (:meth:`JointState.append_dependent`)."""
        noise = range_variance * (self.G_z @ self.G_z.T)
        if shared_variance:
            g = self.G_z.sum(axis=1)
            noise += shared_variance * np.outer(g, g)
        return noise


def stacked_map(A: np.ndarray, bp: BeamPoints) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Apply one (q, k) map to the x and y of k beam points.

    Returns ([A·D_x; A·D_y] (2q,), Jacobian w.r.t. the pose (2q, 3), w.r.t. ranges (2q, k)).
    """
    return enlarge_kernels.stacked_arrays(A @ bp.points[:, 0], A @ bp.points[:, 1], A @ bp.d_dpose[0],
                                          A @ bp.d_dpose[1], A, bp.d_drange)


def new_feature_block(phi: np.ndarray, bp: BeamPoints) -> LinearBlock:
    """Control points [X; Y] = [Φ D_x; Φ D_y] of a new spline (paper (40)–(46))."""
    mean, J_pose, G_z = stacked_map(phi, bp)
    return LinearBlock(mean, np.arange(3), J_pose, G_z)


def extension_block(psi_new: np.ndarray, n_old: int, idx_x: np.ndarray, idx_y: np.ndarray,
                    old_control_points: np.ndarray, bp: BeamPoints) -> LinearBlock:
    """The appended control points of an extension (paper (53)–(55)).

    Args:
        psi_new: (m, n_old + k) rows of Ψ that give the m new control points from
            [old control points; new data points].
        idx_x, idx_y: (n_old,) state indices of the old control points.
        old_control_points: (n_old, 2) their current values.
    """
    psi_o, psi_d = psi_new[:, :n_old], psi_new[:, n_old:]
    data_mean, J_pose, G_z = stacked_map(psi_d, bp)
    mean, J, cols = enlarge_kernels.extension_arrays(data_mean, J_pose, psi_o @ old_control_points[:, 0],
                                                     psi_o @ old_control_points[:, 1], psi_o, idx_x, idx_y)
    return LinearBlock(mean, cols, J, G_z)
