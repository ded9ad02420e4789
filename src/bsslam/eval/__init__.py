"""Trajectory metrics: ATE and RPE against a reference, the relations metric of Kümmerle
et al. 2009, NEES with its χ² band (over Monte Carlo runs, or per pose against an
approximate reference), and :func:`evaluate_files` combining them for files."""

from bsslam.eval.alignment import align_rigid_2d
from bsslam.eval.association import associate
from bsslam.eval.consistency import RunErrors, chi2_band, nees, pose_errors
from bsslam.eval.evaluate_files import evaluate_files
from bsslam.eval.pose_nees import NeesReport, pose_nees
from bsslam.eval.relations import RelationsError, relations_error
from bsslam.eval.trajectory_error import RelativePoseError, ate, rpe

__all__ = ["align_rigid_2d", "associate", "ate", "chi2_band", "evaluate_files", "nees", "NeesReport", "pose_errors",
           "pose_nees", "RunErrors", "RelationsError", "relations_error", "RelativePoseError", "rpe"]
