"""The numpy form of the map-enlargement blocks (``bsslam.slam.enlarge``) as it was before
their assembly was compiled (bsslam.slam.enlarge_kernels): the oracle the compiled form
must match bit for bit."""

from __future__ import annotations

import numpy as np

from bsslam.slam.enlarge import BeamPoints, LinearBlock
from bsslam.slam.measurement import laser_pose


def beam_points(robot_pose: np.ndarray, laser_offset: np.ndarray, bearings: np.ndarray,
                ranges: np.ndarray) -> BeamPoints:
    """World points of beams (bearing rad, range m) with their Jacobians."""
    lp = laser_pose(robot_pose, laser_offset)
    mu = lp[2] + bearings
    cm, sm = np.cos(mu), np.sin(mu)
    points = np.column_stack([lp[0] + ranges * cm, lp[1] + ranges * sm])
    c, s = np.cos(robot_pose[2]), np.sin(robot_pose[2])
    ox, oy = laser_offset[0], laser_offset[1]
    k = bearings.shape[0]
    d_dpose = np.zeros((2, k, 3))
    d_dpose[0, :, 0] = 1.0
    d_dpose[1, :, 1] = 1.0
    d_dpose[0, :, 2] = -s * ox - c * oy - ranges * sm
    d_dpose[1, :, 2] = c * ox - s * oy + ranges * cm
    return BeamPoints(points, d_dpose, np.vstack([cm, sm]))


def stacked_map(A: np.ndarray, bp: BeamPoints) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Apply one (q, k) map to the x and y of k beam points.

    Returns ([A·D_x; A·D_y] (2q,), Jacobian w.r.t. the pose (2q, 3), w.r.t. ranges (2q, k)).
    """
    mean = np.concatenate([A @ bp.points[:, 0], A @ bp.points[:, 1]])
    J_pose = np.vstack([A @ bp.d_dpose[0], A @ bp.d_dpose[1]])
    G_z = np.vstack([A * bp.d_drange[0][None, :], A * bp.d_drange[1][None, :]])
    return mean, J_pose, G_z


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
    m = psi_new.shape[0]
    mean = data_mean + np.concatenate([psi_o @ old_control_points[:, 0], psi_o @ old_control_points[:, 1]])
    J = np.zeros((2 * m, 3 + 2 * n_old))
    J[:, :3] = J_pose
    J[:m, 3:3 + n_old] = psi_o
    J[m:, 3 + n_old:] = psi_o
    cols = np.concatenate([np.arange(3), idx_x, idx_y])
    return LinearBlock(mean, cols, J, G_z)
