"""The numpy form of the filter's range model (formerly ``bsslam.slam.observation``): one
curve's beam prediction (:func:`predict_beams`, checked against finite differences) and
the prediction over a batch of curves as it was before the linearisation was compiled
(:func:`bsslam.slam.range_kernels.linearize_beams`): the oracle the compiled form must
match bit for bit."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ray_oracle import basis_at, intersect_rays_batch
from bsslam.slam.measurement import laser_pose
from bsslam.spline import BSplineCurve, basis_functions, intersect_rays
from bsslam.spline.batch import CurveBatch


@dataclass(frozen=True)
class BeamPrediction:
    """Predicted ranges and Jacobians of m beams against one spline.

    Attributes:
        z: (m,) predicted range (m); NaN where the beam misses the curve.
        t: (m,) curve parameter of the hit.
        r: (m,) tangent ratio x̃'/ỹ' at the hit.
        hit: (m,) bool, the beam meets the curve within its domain.
        H_pose: (m, 3) ∂z/∂(x, y, φ) of the robot pose.
        first_cp: (m,) index of the first of the degree+1 control points with non-zero weight.
        H_cp_x: (m, degree+1) ∂z/∂x_i for those control points.
        H_cp_y: (m, degree+1) ∂z/∂y_i.
    """

    z: np.ndarray
    t: np.ndarray
    r: np.ndarray
    hit: np.ndarray
    H_pose: np.ndarray
    first_cp: np.ndarray
    H_cp_x: np.ndarray
    H_cp_y: np.ndarray


def _range_jacobians(z, r, mu, robot_pose, laser_offset):
    """(gx, gy) = ∂z/∂p_l (m,) each, and H_pose (m, 3), from ranges z, tangent ratios r and
    world beam angles μ (m,)."""
    cm, sm = np.cos(mu), np.sin(mu)
    gx = -cm - r * sm
    gy = -sm + r * cm
    c, s = np.cos(robot_pose[2]), np.sin(robot_pose[2])
    ox, oy = laser_offset[0], laser_offset[1]
    lever_x = -s * ox - c * oy  # ∂p_l/∂φ
    lever_y = c * ox - s * oy
    return gx, gy, np.column_stack([gx, gy, z * r + gx * lever_x + gy * lever_y])


def predict_beams(curve: BSplineCurve, robot_pose: np.ndarray, laser_offset: np.ndarray,
                  bearings: np.ndarray, t0: np.ndarray | None = None,
                  max_range: float = np.inf) -> BeamPrediction:
    """Predict the ranges of beams with robot-frame bearings (m,) (rad) against ``curve``
    (world frame), starting Newton from ``t0`` (m,) where data association gives it."""
    lp = laser_pose(robot_pose, laser_offset)
    mu = lp[2] + np.asarray(bearings, dtype=float)
    hits = intersect_rays(curve, lp[:2], mu, t0=t0, max_range=max_range)
    z, r, t = hits.range, hits.r, hits.t
    gx, gy, H_pose = _range_jacobians(z, r, mu, robot_pose, laser_offset)
    t_safe = np.where(hits.hit, t, curve.domain[0])
    span, values = basis_functions(curve.knots, curve.degree, t_safe)
    beta = values[0]
    return BeamPrediction(
        z=z, t=t, r=r, hit=hits.hit, H_pose=H_pose,
        first_cp=span - curve.degree,
        H_cp_x=-beta * gx[:, None], H_cp_y=-beta * gy[:, None],
    )


@dataclass(frozen=True)
class BatchBeamPrediction:
    """Predicted ranges and Jacobians of m beams, each against its own curve of a batch.

    Attributes:
        z, t, r, hit, H_pose: as in :class:`BeamPrediction`, (m,) and (m, 3).
        window: (m, p+1) rows, in the batch's stacked control points, of the control points
            with non-zero weight at each hit (p: the batch's padded degree).
        real: (m, p+1) bool, False on padding entries (curves of lower degree; zero weight).
        H_cp_x, H_cp_y: (m, p+1) ∂z/∂x_i and ∂z/∂y_i for the control points of ``window``.
    """

    z: np.ndarray
    t: np.ndarray
    r: np.ndarray
    hit: np.ndarray
    H_pose: np.ndarray
    window: np.ndarray
    real: np.ndarray
    H_cp_x: np.ndarray
    H_cp_y: np.ndarray


def predict_beams_batch(batch: CurveBatch, curve: np.ndarray, robot_pose: np.ndarray,
                        laser_offset: np.ndarray, bearings: np.ndarray, t0: np.ndarray | None = None,
                        max_range: float = np.inf) -> BatchBeamPrediction:
    """:func:`predict_beams` for beams that each name their curve: beam j with bearing
    ``bearings[j]`` (rad) against curve ``curve[j]`` of ``batch`` (world frame), Newton from
    ``t0[j]`` (m) — one vectorised computation for all the beams of a scan."""
    lp = laser_pose(robot_pose, laser_offset)
    mu = lp[2] + np.asarray(bearings, dtype=float)
    hits = intersect_rays_batch(batch, curve, lp[:2], mu, t0=t0, max_range=max_range)
    z, r, t = hits.range, hits.r, hits.t
    gx, gy, H_pose = _range_jacobians(z, r, mu, robot_pose, laser_offset)
    table = batch.table
    piece, beta = basis_at(table, curve, np.where(hits.hit, t, table.lo[curve]))
    return BatchBeamPrediction(
        z=z, t=t, r=r, hit=hits.hit, H_pose=H_pose, window=table.window[piece], real=table.real[piece],
        H_cp_x=-beta * gx[:, None], H_cp_y=-beta * gy[:, None],
    )
