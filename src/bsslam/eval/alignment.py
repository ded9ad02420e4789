"""The rigid 2-D alignment (rotation and translation, no scale) of one point set to another."""

from __future__ import annotations

import numpy as np

from bsslam.errors import InputError


def align_rigid_2d(est_xy: np.ndarray, ref_xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation R (2, 2) and translation t (2,) minimising Σ |R·est_i + t − ref_i|².

    This is Kabsch/Umeyama without scale. In 2-D the optimal angle has the closed form
    θ = atan2(Σ eᵢ × rᵢ, Σ eᵢ · rᵢ) over the centred points, which is the SVD solution
    without its reflection case.

    Args:
        est_xy, ref_xy: (N, 2) corresponding points (m), N ≥ 2.

    Raises:
        InputError: different shapes or fewer than two points.
    """
    est_xy = np.asarray(est_xy, dtype=float)
    ref_xy = np.asarray(ref_xy, dtype=float)
    if est_xy.shape != ref_xy.shape or est_xy.ndim != 2 or est_xy.shape[1] != 2:
        raise InputError(f"need two (N, 2) point sets of equal shape, got {est_xy.shape} and {ref_xy.shape}")
    if len(est_xy) < 2:
        raise InputError(f"need at least 2 corresponding points to align, got {len(est_xy)}")
    est_mean, ref_mean = est_xy.mean(axis=0), ref_xy.mean(axis=0)
    e, r = est_xy - est_mean, ref_xy - ref_mean
    cross = np.sum(e[:, 0] * r[:, 1] - e[:, 1] * r[:, 0])
    dot = np.sum(e * r)
    theta = np.arctan2(cross, dot)
    c, s = np.cos(theta), np.sin(theta)
    rotation = np.array([[c, -s], [s, c]])
    return rotation, ref_mean - rotation @ est_mean
