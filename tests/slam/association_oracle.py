"""The numpy forms of the filter's inputs to association as they were before they were
compiled into :func:`bsslam.slam.kernels.association_frame` and
:func:`bsslam.slam.kernels.association_thresholds`: the oracles the kernels must match bit
for bit."""

from __future__ import annotations

import numpy as np


def extreme_control_points(cp_start: np.ndarray, control_points: np.ndarray, curves: np.ndarray, point: np.ndarray,
                           farthest: bool = False) -> np.ndarray:
    """(len(curves),) row of each curve's control point nearest to (or farthest from)
    ``point`` (2,), among stacked control points (N, 2) (m) (formerly
    ``CurveTable.extreme_control_points``)."""
    curves = np.asarray(curves, dtype=np.intp)
    count = cp_start[curves + 1] - cp_start[curves]
    owner = np.repeat(np.arange(curves.shape[0]), count)
    rows = np.arange(owner.shape[0]) - np.repeat(np.cumsum(count) - count, count) + cp_start[curves][owner]
    d2 = np.sum((control_points[rows] - point) ** 2, axis=1)
    order = np.lexsort((-d2 if farthest else d2, owner))
    return rows[order[np.cumsum(count) - count]]


def candidates(boxes: np.ndarray, laser_pose: np.ndarray, radius_m: float) -> np.ndarray:
    """Map curves whose boxes (C, 4) are within ``radius_m`` of the laser (m)."""
    lp = laser_pose
    dx = np.maximum(np.maximum(boxes[:, 0] - lp[0], 0.0), lp[0] - boxes[:, 2])
    dy = np.maximum(np.maximum(boxes[:, 1] - lp[1], 0.0), lp[1] - boxes[:, 3])
    return np.flatnonzero(dx * dx + dy * dy <= radius_m ** 2)


def relative_sigma(pose: np.ndarray, pose_covariance: np.ndarray, points: np.ndarray, cross: np.ndarray,
                   map_variance: np.ndarray) -> np.ndarray:
    """(k, F) σ (m) of the offset between k points seen from the robot and F map control
    points (:func:`bsslam.slam.association.relative_sigma`)."""
    lever = points - pose[:2]
    k = points.shape[0]
    J = np.zeros((k, 2, 3))
    J[:, 0, 0] = J[:, 1, 1] = 1.0
    J[:, 0, 2], J[:, 1, 2] = -lever[:, 1], lever[:, 0]
    own = np.einsum("kab,bc,kac->k", J, pose_covariance, J)
    coupled = np.einsum("kab,bfa->kf", J, cross)                          # tr(J P_pc)
    return np.sqrt(np.maximum(own[:, None] - 2.0 * coupled + map_variance[None, :], 0.0))


def thresholds(pose, pose_covariance, far, cross, diagonal, near, sigmas, match_m, max_match_m, gate_m):
    """Gate and match distance (k, F) of each pair as the filter computed them: ``cross``
    (3, F, 2) and ``diagonal`` (2F,) read at the state rows ``near`` (F, 2), −1 fixed."""
    fixed = near[:, 0] < 0
    cross = cross.copy()
    map_var = diagonal.reshape(-1, 2).sum(axis=1)
    cross[:, fixed] = 0.0
    map_var[fixed] = 0.0
    grow = sigmas * relative_sigma(pose, pose_covariance, far, cross, map_var)
    return gate_m + grow, np.minimum(match_m + grow, max_match_m)
