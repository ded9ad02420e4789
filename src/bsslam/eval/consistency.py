"""Filter consistency: normalised estimation error squared (NEES) and its χ² band."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.errors import InputError
from bsslam.trajectory import Trajectory, wrap_angle


def nees(errors: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """NEES εᵢ = eᵢᵀ Σᵢ⁻¹ eᵢ of pose errors.

    Args:
        errors: (N, 3) estimate − truth (x m, y m, φ rad); φ is wrapped to (−π, π] here.
        covariances: (N, 3, 3) the estimate's covariances.

    Returns:
        (N,) NEES values; a consistent filter gives χ²(3)-distributed values, mean 3.

    Raises:
        InputError: mismatched shapes or a singular covariance.
    """
    e = np.array(errors, dtype=float).reshape(-1, 3)
    cov = np.asarray(covariances, dtype=float)
    if cov.shape != (len(e), 3, 3):
        raise InputError(f"need (N, 3, 3) covariances for {len(e)} errors, got {cov.shape}")
    e[:, 2] = wrap_angle(e[:, 2])
    try:
        solved = np.linalg.solve(cov, e[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        raise InputError("a pose covariance is singular; NEES is undefined") from None
    return np.einsum("ni,ni->n", e, solved)


def chi2_band(dof: int, runs: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided ``probability`` interval of the average of ``runs`` independent
    χ²(dof) values, i.e. χ²(dof·runs) quantiles divided by ``runs``.

    Example: 3 dof averaged over 50 runs → (2.36, 3.72) at 95 %.
    """
    if dof < 1 or runs < 1 or not 0 < probability < 1:
        raise InputError(f"need dof ≥ 1, runs ≥ 1 and 0 < probability < 1, got {dof}, {runs}, {probability}")
    # imported here: scipy.stats takes most of a second to load, which every CLI verb
    # importing bsslam.eval would otherwise pay
    from scipy import stats

    tail = 0.5 * (1.0 - probability)
    total = dof * runs
    return float(stats.chi2.ppf(tail, total) / runs), float(stats.chi2.ppf(1.0 - tail, total) / runs)


@dataclass(frozen=True)
class RunErrors:
    """Per-step pose errors of one run: errors (N, 3), sigmas (N, 3), nees (N,)."""

    errors: np.ndarray
    sigmas: np.ndarray
    nees: np.ndarray


def pose_errors(estimate: Trajectory, truth: Trajectory) -> RunErrors:
    """Errors true − estimated (angle wrapped), their σ and NEES for matched trajectories.

    The first pose defines the map frame and has zero covariance: its NEES is NaN.
    """
    e = truth.poses - estimate.poses
    e[:, 2] = wrap_angle(e[:, 2])
    cov = estimate.covariances
    sig = np.sqrt(np.maximum(np.einsum("nii->ni", cov), 0.0))
    value = np.full(e.shape[0], np.nan)
    defined = np.linalg.det(cov) > 0
    value[defined] = nees(e[defined], cov[defined])
    return RunErrors(e, sig, value)
