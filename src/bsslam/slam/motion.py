"""Odometry motion model and prediction (spec §5, paper §III-E.1).

The increment ``u = (Δx, Δy, Δφ)`` is expressed in the robot frame at the previous pose.
"""

from __future__ import annotations

import numpy as np

from bsslam.config import MotionNoiseConfig
from bsslam.se2 import compose, compose_jacobians


def motion_noise(delta: np.ndarray, cfg: MotionNoiseConfig) -> np.ndarray:
    """Q (3×3): σ = a + b·|Δ| per component (paper §IV), plus an optional heading term
    proportional to the distance travelled."""
    dist = float(np.hypot(delta[0], delta[1]))
    sx = cfg.a_xy_m + cfg.b_xy * abs(delta[0])
    sy = cfg.a_xy_m + cfg.b_xy * abs(delta[1])
    sphi = cfg.a_phi_rad + cfg.b_phi * abs(delta[2]) + cfg.b_phi_per_m_rad * dist
    return np.diag([sx * sx, sy * sy, sphi * sphi])


def predict(x: np.ndarray, P: np.ndarray, delta: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """EKF prediction in place on the live state views; returns F_x (3, 3).

    Only the pose block and the pose rows/columns change:
    ``P_rr ← F_x P_rr F_xᵀ + F_u Q F_uᵀ``, ``P_rm ← F_x P_rm`` — never the full F of (32).
    A caller that keeps part of P elsewhere (a pending low-rank term) applies F_x to it.
    """
    F_x, F_u = compose_jacobians(x[:3], delta)
    x[:3] = compose(x[:3], delta)
    P_rm = F_x @ P[:3, 3:]
    P_rr = F_x @ P[:3, :3] @ F_x.T + F_u @ Q @ F_u.T
    P[:3, 3:] = P_rm
    P[3:, :3] = P_rm.T
    P[:3, :3] = 0.5 * (P_rr + P_rr.T)
    return F_x
