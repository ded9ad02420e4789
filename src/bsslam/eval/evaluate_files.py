"""All metrics of one estimated trajectory file against its references, as one flat dict
(what ``bsslam evaluate`` prints), saved as JSON; and its picture against the reference."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import numpy as np

from bsslam.errors import InputError
from bsslam.eval.association import associate, nearest_stamps
from bsslam.eval.consistency import nees
from bsslam.eval.pose_nees import NeesReport, pose_nees, singular_covariances
from bsslam.eval.relations import relations_error
from bsslam.eval.trajectory_error import ate, rpe
from bsslam.io.path_or_file import PathOrFile, open_path_or_file
from bsslam.io.pose_covariance_file import read_pose_covariance_csv
from bsslam.io.trajectory_file import read_trajectory
from bsslam.trajectory import Trajectory

logger = logging.getLogger(__name__)

POSE_COVARIANCE_FILE = "pose_covariance.csv"
# Covariance rows are written with the same stamps as the trajectory; allow only rounding.
_COVARIANCE_STAMP_TOLERANCE_S = 1e-6


def _nees_mean(est: Trajectory, ref: Trajectory, covariance_path: Path, max_dt: float,
               offset: float) -> tuple[float, int]:
    """Mean NEES of the estimate against an exact reference, with no alignment (the
    reference shares the estimate's frame, as a simulation's ground truth does). Poses
    whose covariance is not positive definite are left out: the first pose of a run
    defines the map frame and has zero covariance."""
    cov_stamps, covariances = read_pose_covariance_csv(covariance_path)
    positive = np.all(np.linalg.eigvalsh(covariances) > 0, axis=1) if len(covariances) else np.zeros(0, bool)
    cov_idx = nearest_stamps(cov_stamps, est.stamps, _COVARIANCE_STAMP_TOLERANCE_S)
    est_idx, ref_idx = associate(est, ref, max_dt, offset)
    usable = cov_idx[est_idx] >= 0
    usable[usable] = positive[cov_idx[est_idx[usable]]]
    est_idx, ref_idx = est_idx[usable], ref_idx[usable]
    if len(est_idx) == 0:
        return float("nan"), 0
    errors = est.poses[est_idx] - ref.poses[ref_idx]
    values = nees(errors, covariances[cov_idx[est_idx]])
    return float(np.mean(values)), len(values)


def read_matching_covariances(covariance_path: str | os.PathLike, est: Trajectory) -> np.ndarray:
    """The (N, 3, 3) covariances of a pose covariance CSV written for the trajectory ``est``
    (one row per pose, the same stamps), checked finite and positive semidefinite.

    Raises:
        InputError: naming ``covariance_path``: unreadable, a row count or a stamp that
            differs from the estimate's, or a bad matrix.
    """
    name = str(covariance_path)
    stamps, covariances = read_pose_covariance_csv(covariance_path)
    if len(stamps) != len(est):
        raise InputError(f"{len(stamps)} covariance rows for an estimate of {len(est)} poses: "
                         "not the covariances of this trajectory", name)
    off = np.nonzero(~(np.abs(stamps - est.stamps) <= _COVARIANCE_STAMP_TOLERANCE_S))[0]
    if len(off):
        k = off[0]
        raise InputError(f"row {k} has stamp {stamps[k]!r} but the estimate's pose {k} has {est.stamps[k]!r}: "
                         "not the covariances of this trajectory", name)
    singular_covariances(covariances, name)
    return covariances


def nees_files(est_path: str | os.PathLike, ref_path: str | os.PathLike, covariance_path: str | os.PathLike, *,
               reference_sigma_xy_m: float = 0.0, reference_sigma_phi_rad: float = 0.0, max_dt: float = 0.05,
               ref_offset: float = 0.0, exact_reference: bool = False, nees_frame: str = "first-pose") -> NeesReport:
    """:func:`~bsslam.eval.pose_nees.pose_nees` of trajectory files and the estimate's
    covariance CSV (e.g. ``trajectory_online.tum`` with ``pose_covariance_online.csv``),
    the error taken in ``nees_frame`` (:data:`~bsslam.eval.pose_nees.NEES_FRAMES`), or as
    it is when ``exact_reference``.

    Raises:
        InputError: unreadable files, covariances not matching the estimate, or too few
            matched poses.
    """
    est = read_trajectory(est_path)
    covariances = read_matching_covariances(covariance_path, est)
    return pose_nees(est, read_trajectory(ref_path), covariances, reference_sigma_xy_m=reference_sigma_xy_m,
                     reference_sigma_phi_rad=reference_sigma_phi_rad, max_dt=max_dt, offset=ref_offset,
                     frame="same" if exact_reference else nees_frame)


def evaluate_files(est_path: str | os.PathLike, ref_path: str | os.PathLike | None,
                   relations_path: str | os.PathLike | None = None, offset: float = 0.0,
                   max_dt: float = 0.05, *, relations_max_dt: float = 0.001, ref_offset: float = 0.0,
                   exact_reference: bool = False, rpe_delta: int = 1,
                   covariance_path: str | os.PathLike | None = None, reference_sigma_xy_m: float = 0.0,
                   reference_sigma_phi_rad: float = 0.0, nees_frame: str = "first-pose") -> dict[str, Any]:
    """Evaluate a trajectory file (TUM or ``t x y θ``).

    Args:
        est_path: the estimate.
        ref_path: a reference trajectory file, or None to score relations only.
        relations_path: an optional Kümmerle relations file.
        offset: the relations' clock minus the estimate's (s): subtracted from the relation
            stamps, i.e. added to the estimate's stamps when matching relations;
            976052857.337 for the Intel logs shipped with the project.
        max_dt: largest time difference of a matched estimate/reference pair (s).
        relations_max_dt: largest time difference when matching a relation stamp (s).
        ref_offset: added to the estimate's stamps when matching the reference (s); the
            shipped ``*.gt.txt`` files share the logs' clock, so 0.
        exact_reference: the reference is exact ground truth in the estimate's frame (a
            simulation). Then, if ``pose_covariance.csv`` sits next to the estimate, the
            mean NEES of the matched poses is reported; never for approximate references
            such as the GMapping poses, whose own error would count as filter error.
        rpe_delta: RPE compares poses this many matches apart.
        covariance_path: the estimate's pose covariance CSV: report NEES against the
            reference (see :func:`nees_files`), whether or not it is exact; it replaces the
            ``exact_reference`` NEES.
        reference_sigma_xy_m, reference_sigma_phi_rad: the reference's own σ (m, rad),
            added to the estimate's covariance for that NEES.
        nees_frame: the frame that NEES takes the error in (:func:`pose_nees`):
            ``first-pose`` (the frame of a SLAM estimate's covariances) or ``aligned``.

    Returns:
        dict with, when a reference is given: ``matched``, ``ate_m``, ``rpe_trans_m`` and
        ``rpe_rot_deg`` (RMSE), ``rpe_trans_mean_m``, ``rpe_rot_mean_deg``; with relations:
        ``relations_trans_mean_m``, ``relations_trans_std_m``, ``relations_rot_mean_deg``,
        ``relations_rot_std_deg``, ``relations_used``, ``relations_total``; with NEES:
        ``nees_mean`` and ``nees_count``; with ``covariance_path`` also ``nees_median``,
        ``nees_fraction_outside_95`` (share above the χ²(3) 95 % quantile, 7.81) and
        ``nees_skipped_singular``.

    Raises:
        InputError: unreadable files or too few matched poses.
    """
    est = read_trajectory(est_path)
    result: dict[str, Any] = {}
    if ref_path is not None:
        ref = read_trajectory(ref_path)
        ate_m, matched, _ = ate(est, ref, max_dt, ref_offset)
        errors = rpe(est, ref, rpe_delta, max_dt, ref_offset)
        result.update(matched=matched, ate_m=ate_m, rpe_trans_m=errors.trans_rmse_m,
                      rpe_rot_deg=errors.rot_rmse_deg, rpe_trans_mean_m=errors.trans_mean_m,
                      rpe_rot_mean_deg=errors.rot_mean_deg)
        beside = Path(est_path).with_name(POSE_COVARIANCE_FILE)
        if covariance_path is not None:
            report = pose_nees(est, ref, read_matching_covariances(covariance_path, est),
                               reference_sigma_xy_m=reference_sigma_xy_m,
                               reference_sigma_phi_rad=reference_sigma_phi_rad, max_dt=max_dt, offset=ref_offset,
                               frame="same" if exact_reference else nees_frame)
            result.update(nees_mean=report.mean, nees_median=report.median,
                          nees_fraction_outside_95=report.fraction_outside_95, nees_count=len(report.nees),
                          nees_skipped_singular=report.skipped_singular)
        elif exact_reference and beside.exists():
            result["nees_mean"], result["nees_count"] = _nees_mean(est, ref, beside, max_dt, ref_offset)
        elif exact_reference:
            logger.info("no %s next to %s: NEES not computed", POSE_COVARIANCE_FILE, est_path)
    if relations_path is not None:
        rel = relations_error(est, relations_path, offset, relations_max_dt)
        result.update(relations_trans_mean_m=rel.trans_mean_m, relations_trans_std_m=rel.trans_std_m,
                      relations_rot_mean_deg=rel.rot_mean_deg, relations_rot_std_deg=rel.rot_std_deg,
                      relations_used=rel.used, relations_total=rel.total)
    return result


def write_metrics_json(target: PathOrFile, metrics: dict[str, Any]) -> None:
    """Write the metrics of :func:`evaluate_files` as a JSON object (NaN where undefined)."""
    with open_path_or_file(target, "w") as f:
        f.write(json.dumps(metrics, indent=2) + "\n")


def write_evaluation_plot(est_path: str | os.PathLike, ref_path: str | os.PathLike,
                          target: str | os.PathLike, max_dt: float = 0.05, ref_offset: float = 0.0, *,
                          covariance_path: str | os.PathLike | None = None, reference_sigma_xy_m: float = 0.0,
                          reference_sigma_phi_rad: float = 0.0, exact_reference: bool = False,
                          nees_frame: str = "first-pose") -> Path:
    """Draw the estimate aligned onto the reference as the ATE aligns it, and the position
    error of the matched poses over time, to ``target`` (PNG, SVG or PDF by its suffix);
    with ``covariance_path`` also the NEES of :func:`nees_files` over time.

    Raises:
        InputError: unreadable files, too few matched poses, or bad covariances.
    """
    from bsslam.viz.evaluation_plots import save_evaluation_figure

    est, ref = read_trajectory(est_path), read_trajectory(ref_path)
    rmse, _, aligned = ate(est, ref, max_dt, ref_offset)
    est_idx, ref_idx = associate(aligned, ref, max_dt, ref_offset)
    error = np.linalg.norm(aligned.poses[est_idx, :2] - ref.poses[ref_idx, :2], axis=1)
    report = None
    if covariance_path is not None:
        report = pose_nees(est, ref, read_matching_covariances(covariance_path, est),
                           reference_sigma_xy_m=reference_sigma_xy_m, reference_sigma_phi_rad=reference_sigma_phi_rad,
                           max_dt=max_dt, offset=ref_offset, frame="same" if exact_reference else nees_frame)
    return save_evaluation_figure(target, aligned.poses, ref.poses, aligned.stamps[est_idx], error,
                                  title=f"{Path(est_path).name} against {Path(ref_path).name}: ATE {rmse:.3f} m",
                                  nees=report)
