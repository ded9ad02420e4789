"""Absolute and relative trajectory errors (ATE, RPE) of an estimate against a reference."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.errors import InputError
from bsslam.eval.alignment import align_rigid_2d
from bsslam.eval.association import associate
from bsslam.se2 import between
from bsslam.trajectory import Trajectory, wrap_angle


def ate(est: Trajectory, ref: Trajectory, max_dt: float = 0.01,
        offset: float = 0.0) -> tuple[float, int, Trajectory]:
    """Absolute trajectory error: the RMSE of the positions after the best rigid 2-D
    alignment of the matched estimate poses onto the reference ones.

    Args:
        est, ref: the trajectories; poses paired by :func:`associate`.
        max_dt: largest accepted time difference of a pair (s).
        offset: added to the estimate's stamps (s).

    Returns:
        (rmse_m, matched pair count, the whole estimate moved by the alignment — positions
        rotated and shifted, headings turned, covariances rotated).

    Raises:
        InputError: fewer than two matched poses.
    """
    est_idx, ref_idx = associate(est, ref, max_dt, offset)
    if len(est_idx) < 2:
        raise InputError(f"only {len(est_idx)} poses matched in time (max_dt = {max_dt} s, offset = {offset} s)")
    rotation, translation = align_rigid_2d(est.poses[est_idx, :2], ref.poses[ref_idx, :2])
    aligned = _transform(est, rotation, translation)
    residual = aligned.poses[est_idx, :2] - ref.poses[ref_idx, :2]
    rmse = float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))
    return rmse, len(est_idx), aligned


def _transform(traj: Trajectory, rotation: np.ndarray, translation: np.ndarray) -> Trajectory:
    """``traj`` moved rigidly: p ↦ R p + t, φ ↦ φ + angle(R), Σ ↦ J Σ Jᵀ, J = diag(R, 1)."""
    angle = np.arctan2(rotation[1, 0], rotation[0, 0])
    poses = np.column_stack([traj.poses[:, :2] @ rotation.T + translation, wrap_angle(traj.poses[:, 2] + angle)])
    cov = None
    if traj.covariances is not None:
        jac = np.eye(3)
        jac[:2, :2] = rotation
        cov = jac @ traj.covariances @ jac.T
    return Trajectory(traj.stamps.copy(), poses, cov)


@dataclass(frozen=True)
class RelativePoseError:
    """RPE over pairs of matched poses ``delta`` matches apart.

    Attributes:
        trans_rmse_m, trans_mean_m: RMSE and mean of the translation error (m).
        rot_rmse_deg, rot_mean_deg: RMSE and mean of |rotation error| (deg).
        pairs: how many pose pairs were compared.
    """

    trans_rmse_m: float
    trans_mean_m: float
    rot_rmse_deg: float
    rot_mean_deg: float
    pairs: int


def rpe(est: Trajectory, ref: Trajectory, delta: int = 1, max_dt: float = 0.01,
        offset: float = 0.0) -> RelativePoseError:
    """Relative pose error: for matched poses k and k + ``delta`` (in matched order), the
    error of the estimated motion against the reference motion,
    E = (ref_k⁻¹ ref_{k+δ})⁻¹ (est_k⁻¹ est_{k+δ}); no alignment is needed.

    Raises:
        InputError: ``delta`` < 1 or not more than ``delta`` matched poses.
    """
    if delta < 1:
        raise InputError(f"delta must be ≥ 1, got {delta}")
    est_idx, ref_idx = associate(est, ref, max_dt, offset)
    if len(est_idx) <= delta:
        raise InputError(f"{len(est_idx)} matched poses are too few for delta = {delta}")
    est_p, ref_p = est.poses[est_idx], ref.poses[ref_idx]
    error = between(between(ref_p[:-delta], ref_p[delta:]), between(est_p[:-delta], est_p[delta:]))
    trans = np.hypot(error[:, 0], error[:, 1])
    rot = np.degrees(np.abs(error[:, 2]))
    return RelativePoseError(float(np.sqrt(np.mean(trans ** 2))), float(np.mean(trans)),
                             float(np.sqrt(np.mean(rot ** 2))), float(np.mean(rot)), len(trans))
