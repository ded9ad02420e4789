"""Observation model: the range of each beam against one map spline (spec §6, paper §III-D).

The laser sits at ``laser_offset`` (x m, y m, φ rad) in the robot frame. For a beam with
bearing τ the world beam angle is μ = φ + φ_o + τ and the beam starts at
``p_l = t_r + R(φ) o``. The predicted range z is where the spline, moved into the beam
frame, crosses the beam's x-axis. With the tangent ratio ``r = x̃'(t*)/ỹ'(t*)``:

* ∂z/∂p_l = g = (−cos μ − r sin μ, −sin μ + r cos μ);
* ∂z/∂μ = z·r, so ∂z/∂φ = z·r + g·R'(φ)·o (the lever arm of an offset laser);
* ∂z/∂(x_i, y_i) = −β_i(t*)·g — moving the curve by δ is moving the sensor by −δ.

These are (22)–(27) of the paper; tests check them against finite differences.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.spline import BSplineCurve, basis_functions, intersect_rays


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


def laser_pose(robot_pose: np.ndarray, laser_offset: np.ndarray) -> np.ndarray:
    """World pose (3,) of the laser mounted at ``laser_offset`` on a robot at ``robot_pose``."""
    c, s = np.cos(robot_pose[2]), np.sin(robot_pose[2])
    return np.array([robot_pose[0] + c * laser_offset[0] - s * laser_offset[1],
                     robot_pose[1] + s * laser_offset[0] + c * laser_offset[1],
                     robot_pose[2] + laser_offset[2]])


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
