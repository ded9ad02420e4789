"""NEES of an estimated trajectory with its covariances against an approximate reference,
with the reference's own uncertainty added, in the frame the covariances refer to.

A SLAM estimate's covariances are relative to its first pose, which fixes the map frame
and has none: the pose k steps on is uncertain by the drift since. Its error must be taken
in that frame — the reference moved so that its first pose lies on the estimate's
(``frame="first-pose"``, the default). The best rigid fit of the whole trajectory (the
ATE's alignment, ``frame="aligned"``) spreads the drift over every pose instead: the first
poses then carry an error of the order of the drift that their near-zero covariance cannot
explain (on ACES, 37 % of the online poses outside the 95 % region aligned, 11 % in the
first pose's frame, the same default run)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.errors import InputError
from bsslam.eval.alignment import align_rigid_2d
from bsslam.eval.association import associate
from bsslam.eval.consistency import chi2_band, nees
from bsslam.se2 import compose, inverse
from bsslam.trajectory import Trajectory, wrap_angle

# Relative to a matrix's largest |eigenvalue|: eigenvalues this small are rounding, so a
# matrix whose smallest one is within it is singular (skipped) rather than indefinite.
_EIGEN_RTOL = 1e-9
_POSE_DOF = 3

#: The frames the error can be taken in (:func:`pose_nees`).
NEES_FRAMES = ("first-pose", "aligned", "same")


@dataclass(frozen=True)
class NeesReport:
    """Per-pose NEES of a trajectory and its summary.

    Attributes:
        stamps: (M,) estimate times (s) of the poses scored.
        nees: (M,) NEES of each scored pose (dimensionless; χ²(3) if consistent).
        errors: (M, 3) estimate − reference (x m, y m, φ rad wrapped) in the estimate's
            map frame, the frame of its covariances.
        mean, median: of ``nees`` (NaN when no pose was scored).
        fraction_outside_95: share of ``nees`` above ``upper_95`` (0.05 if consistent).
        upper_95: χ²(3) 95 % quantile, 7.81: a single consistent pose lies above it 5 % of the time.
        band_95: (2.5 %, 97.5 %) quantiles of χ²(3), (0.216, 9.35): the two-sided 95 % band.
        matched: estimate poses paired with a reference pose by time.
        skipped_singular: matched poses left out because their own covariance is singular
            (the first pose of a run defines the map frame and has zero covariance), or
            because they anchor the frame (``frame="first-pose"``).
    """

    stamps: np.ndarray
    nees: np.ndarray
    errors: np.ndarray
    mean: float
    median: float
    fraction_outside_95: float
    upper_95: float
    band_95: tuple[float, float]
    matched: int
    skipped_singular: int


def singular_covariances(covariances: np.ndarray, source: str | None = None) -> np.ndarray:
    """Which of the (N, 3, 3) pose covariances are singular; every one must be finite,
    symmetric and positive semidefinite.

    Returns:
        (N,) bool, True where the matrix is singular (smallest eigenvalue ≤ 1e-9 of the
        largest |eigenvalue|, or all zero).

    Raises:
        InputError: a non-finite, asymmetric or indefinite matrix, naming ``source`` (a
            file) and the row (0-based, in file order).
    """
    cov = np.asarray(covariances, dtype=float)
    if cov.ndim != 3 or cov.shape[1:] != (3, 3):
        raise InputError(f"need (N, 3, 3) covariances, got {cov.shape}", source)
    bad = np.nonzero(~np.all(np.isfinite(cov), axis=(1, 2)))[0]
    if len(bad):
        raise InputError(f"non-finite covariance in row {bad[0]} ({len(bad)} row(s) in all)", source)
    scale = np.max(np.abs(cov), axis=(1, 2))
    asym = np.nonzero(np.max(np.abs(cov - cov.transpose(0, 2, 1)), axis=(1, 2)) > _EIGEN_RTOL * scale)[0]
    if len(asym):
        raise InputError(f"covariance in row {asym[0]} is not symmetric ({len(asym)} row(s) in all)", source)
    eig = np.linalg.eigvalsh(cov) if len(cov) else np.zeros((0, 3))
    tol = _EIGEN_RTOL * np.max(np.abs(eig), axis=1, initial=0.0)
    indefinite = np.nonzero(eig[:, 0] < -tol)[0]
    if len(indefinite):
        k = indefinite[0]
        raise InputError(f"covariance in row {k} is not positive semidefinite (eigenvalue {eig[k, 0]:.3g}; "
                         f"{len(indefinite)} row(s) in all)", source)
    return eig[:, 0] <= tol


def pose_nees(estimate: Trajectory, reference: Trajectory, covariances: np.ndarray, *,
              reference_sigma_xy_m: float = 0.0, reference_sigma_phi_rad: float = 0.0,
              max_dt: float = 0.05, offset: float = 0.0, frame: str = "first-pose") -> NeesReport:
    """NEES_k = e_kᵀ (P_k + P_ref,k)⁻¹ e_k of each estimate pose matched to a reference pose.

    The poses are paired by time as the ATE pairs them (:func:`associate`), and the
    reference is moved into the estimate's frame, the frame of P_k (moving the estimate
    instead would turn the error but not P_k):

    * ``"first-pose"``: rigidly, so that the first matched reference pose lies on its
      estimate pose — the frame of a SLAM estimate whose first pose has no uncertainty
      (bsslam's). That pose's error is then zero by construction and is not scored; the
      reference's own error there moves every other reference pose with it (rigidly
      about it), so P_ref,k = P_ref + G_k P_ref G_kᵀ, G_k the lever arm from that pose;
    * ``"aligned"``: by the inverse of the ATE's best rigid fit (:func:`align_rigid_2d` of
      the matched positions), P_ref,k = P_ref: for estimates whose covariances are not
      relative to their first pose;
    * ``"same"``: not at all (exact ground truth in the estimate's frame, a simulation).

    P_ref = diag(σ_xy², σ_xy², σ_φ²) is the reference's own uncertainty, independent from
    pose to pose; being isotropic in x and y it is the same in either frame. Poses whose
    own P_k is singular are skipped and counted: their error is not one the filter claims
    to know.

    Args:
        estimate: the estimated trajectory (N poses).
        reference: the reference trajectory.
        covariances: (N, 3, 3) the estimate's pose covariances over (x m, y m, φ rad), in
            the order of ``estimate``'s poses.
        reference_sigma_xy_m: σ of the reference's x and y (m), ≥ 0.
        reference_sigma_phi_rad: σ of the reference's heading (rad), ≥ 0.
        max_dt: largest time difference of a matched pair (s).
        offset: added to the estimate's stamps when matching (s).
        frame: one of :data:`NEES_FRAMES` (above).

    Raises:
        InputError: a covariance count different from the pose count, non-finite,
            asymmetric or indefinite covariances, a negative σ, an unknown frame, or fewer
            than two matched poses when moving the reference.
    """
    cov = np.asarray(covariances, dtype=float)
    if cov.shape != (len(estimate), 3, 3):
        raise InputError(f"need ({len(estimate)}, 3, 3) covariances for the estimate's poses, got {cov.shape}")
    if not (reference_sigma_xy_m >= 0 and reference_sigma_phi_rad >= 0):  # also rejects NaN
        raise InputError(f"reference σ must be ≥ 0, got {reference_sigma_xy_m} m, {reference_sigma_phi_rad} rad")
    if frame not in NEES_FRAMES:
        raise InputError(f"unknown NEES frame {frame!r}; choose one of {', '.join(NEES_FRAMES)}")
    singular = singular_covariances(cov)
    est_idx, ref_idx = associate(estimate, reference, max_dt, offset)
    ref_poses = reference.poses[ref_idx]
    if frame != "same" and len(est_idx) < 2:
        raise InputError(f"only {len(est_idx)} poses matched in time (max_dt = {max_dt} s, offset = {offset} s)")
    if frame == "aligned":
        rotation, translation = align_rigid_2d(estimate.poses[est_idx, :2], reference.poses[ref_idx, :2])
        # est ↦ T ⊕ est maps the estimate onto the reference, so T⁻¹ ⊕ ref is the reference
        # in the estimate's frame
        transform = np.array([*translation, np.arctan2(rotation[1, 0], rotation[0, 0])])
        ref_poses = compose(inverse(transform), ref_poses)
    elif frame == "first-pose":
        ref_poses = compose(compose(estimate.poses[est_idx[0]], inverse(ref_poses[0])), ref_poses)
    p_ref = np.diag([reference_sigma_xy_m ** 2, reference_sigma_xy_m ** 2, reference_sigma_phi_rad ** 2])
    p_ref = np.broadcast_to(p_ref, (len(est_idx), 3, 3)).copy()
    keep = ~singular[est_idx]
    if frame == "first-pose":
        keep[0] = False     # its error is zero by construction
        lever = np.broadcast_to(np.eye(3), (len(est_idx), 3, 3)).copy()
        lever[:, 0, 2] = -(ref_poses[:, 1] - ref_poses[0, 1])
        lever[:, 1, 2] = ref_poses[:, 0] - ref_poses[0, 0]
        p_ref += lever @ p_ref[0] @ lever.transpose(0, 2, 1)
    errors = estimate.poses[est_idx[keep]] - ref_poses[keep]
    errors[:, 2] = wrap_angle(errors[:, 2])
    values = nees(errors, cov[est_idx[keep]] + p_ref[keep])

    from scipy import stats  # here: scipy.stats takes most of a second to import

    upper = float(stats.chi2.ppf(0.95, _POSE_DOF))
    scored = len(values) > 0
    return NeesReport(
        stamps=estimate.stamps[est_idx[keep]], nees=values, errors=errors,
        mean=float(np.mean(values)) if scored else float("nan"),
        median=float(np.median(values)) if scored else float("nan"),
        fraction_outside_95=float(np.mean(values > upper)) if scored else float("nan"),
        upper_95=upper, band_95=chi2_band(_POSE_DOF, 1, 0.95),
        matched=len(est_idx), skipped_singular=int(np.count_nonzero(~keep)))
