"""The EKF update for all accepted beams of a scan (spec §7, paper §III-E.2).

``H`` is non-zero only in the pose columns and the columns of the observed control points,
so everything is built from those columns (``cols``): ``P Hᵀ = P[:, cols] H_cᵀ``. The
covariance correction ``P ← P − P Hᵀ S⁻¹ H P`` is applied as a symmetric low-rank update
``P ← P − Z Zᵀ`` with rank min(beams, touched columns): that product is the only O(n²)
work of a scan. The Joseph form would cost O(n³) on the full state; instead the result is
symmetrised and its pose block checked, which keeps P symmetric and positive definite in
practice (every test run checks it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, qr, solve_triangular
from scipy.stats import chi2

from bsslam.errors import FilterError
from bsslam.slam.state import JointState


@dataclass(frozen=True)
class UpdateResult:
    """What one stacked update did.

    Attributes:
        innovation: (m,) ν = z − ẑ of the beams used (m).
        innovation_variance: (m,) diagonal of S (m²).
        nis: ν S⁻¹ ν of the stacked update (dimensionless), χ² with ``len(innovation)`` dof.
        accepted: (m_in,) bool mask of the beams passed to the update that survived the gate.
    """

    innovation: np.ndarray
    innovation_variance: np.ndarray
    nis: float
    accepted: np.ndarray


def gate_threshold(probability: float) -> float:
    """χ² (1 dof) bound of the per-beam innovation gate."""
    return float(chi2.ppf(probability, 1))


def stacked_update(state: JointState, cols: np.ndarray, H_c: np.ndarray, innovation: np.ndarray,
                   range_variance: float, gate: float | None = None) -> UpdateResult:
    """Update ``state`` in place with m beams.

    Args:
        cols: (c,) state indices that ``H`` touches (pose and control points).
        H_c: (m, c) the Jacobian restricted to ``cols``.
        innovation: (m,) z − ẑ (m).
        range_variance: R of one beam (m²).
        gate: χ² bound on ν_i²/S_ii per beam; None disables gating.
    """
    m = innovation.shape[0]
    P = state.P
    P_c = P[:, cols]                      # (n, c): the only columns of P we read
    HP_cc = H_c @ P_c[cols]               # (m, c)
    s_diag = np.einsum("ij,ij->i", HP_cc, H_c) + range_variance
    accepted = np.ones(m, dtype=bool)
    if gate is not None:
        accepted = innovation * innovation <= gate * s_diag
    if not accepted.any():
        return UpdateResult(np.empty(0), np.empty(0), 0.0, accepted)
    H_a, nu = H_c[accepted], innovation[accepted]
    S = HP_cc[accepted] @ H_a.T
    S[np.diag_indices_from(S)] += range_variance
    try:
        L, _ = cho_factor(S, lower=True, check_finite=False)
    except np.linalg.LinAlgError as exc:  # pragma: no cover - S ≥ R > 0 in exact arithmetic
        raise FilterError(f"innovation covariance not positive definite: {exc}") from None
    L = np.tril(L)
    Y = solve_triangular(L, H_a, lower=True, check_finite=False)    # (m, c): Hᵀ S⁻¹ H = Yᵀ Y
    w = solve_triangular(L, nu, lower=True, check_finite=False)     # (m,):  ν S⁻¹ ν = w·w
    state.x[:] += P_c @ (Y.T @ w)
    # Factor Hᵀ S⁻¹ H with the smaller rank: YᵀY = R_yᵀ R_y when there are more beams than columns.
    if Y.shape[0] > Y.shape[1]:
        Y = qr(Y, mode="r", check_finite=False)[0]
    Z = P_c @ Y.T
    P -= Z @ Z.T
    state.symmetrize()
    if np.any(np.diag(P)[:3] <= 0):
        raise FilterError("pose covariance lost positive definiteness in the update")
    return UpdateResult(nu, np.diag(S).copy(), float(w @ w), accepted)
