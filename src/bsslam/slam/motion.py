"""Odometry motion model and prediction (spec §5, paper §III-E.1).

The increment ``u = (Δx, Δy, Δφ)`` is expressed in the robot frame at the previous pose.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from bsslam.config import MotionNoiseConfig
from bsslam.se2 import compose, compose_jacobians

if TYPE_CHECKING:
    from bsslam.slam.state import JointState


def motion_sigmas(increments: np.ndarray, cfg: MotionNoiseConfig) -> np.ndarray:
    """(..., 3) odometry noise σ of robot-frame increments (..., 3) (Δx m, Δy m, Δφ rad):
    σ = a + b·|Δ| per component (paper §IV), plus an optional heading term proportional to
    the distance travelled: ``σ_x = a_xy + b_xy|Δx|``, ``σ_y = a_xy + b_xy|Δy|``,
    ``σ_φ = a_φ + b_φ|Δφ| + b_φ/m·|(Δx, Δy)|`` (m, m, rad)."""
    inc = np.asarray(increments, dtype=float)
    sigma = np.empty_like(inc)
    sigma[..., :2] = cfg.a_xy_m + cfg.b_xy * np.abs(inc[..., :2])
    sigma[..., 2] = (cfg.a_phi_rad + cfg.b_phi * np.abs(inc[..., 2])
                     + cfg.b_phi_per_m_rad * np.hypot(inc[..., 0], inc[..., 1]))
    return sigma


def motion_noise(delta: np.ndarray, cfg: MotionNoiseConfig) -> np.ndarray:
    """Q (3×3) of one increment (3,): diag(σ²) of :func:`motion_sigmas`."""
    sigma = motion_sigmas(delta, cfg)
    return np.diag(sigma * sigma)


def predict_state(state: JointState, delta: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """EKF prediction of the filter's state, in place; returns F_x (3, 3).

    The pose moves by ``delta``, and only the pose block and the pose rows/columns of P
    change: ``P_rr ← F_x P_rr F_xᵀ + F_u Q F_uᵀ``, ``P_rm ← F_x P_rm`` — never the full F of
    (32). The state keeps the pose's rows apart from its deferred update
    (:meth:`JointState.transform_pose`), so this is O(n) at most."""
    x = state.x
    F_x, F_u = compose_jacobians(x[:3], delta)
    x[:3] = compose(x[:3], delta)
    state.transform_pose(F_x, F_u @ Q @ F_u.T)
    return F_x
