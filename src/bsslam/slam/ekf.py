"""The EKF update for all accepted beams of a scan (spec §7, paper §III-E.2).

``H`` is non-zero only in the pose columns and the columns of the observed control points,
so everything is built from those columns (``cols``): ``P Hᵀ = P[:, cols] H_cᵀ``. The
covariance correction ``P ← P − P Hᵀ S⁻¹ H P`` is applied as a symmetric low-rank update
``P ← P − Z Zᵀ`` with rank min(beams, touched columns): that product is the only O(n²)
work of a scan. The Joseph form would cost O(n³) on the full state; instead the result is
exactly symmetric (``Z @ Z.T`` is a symmetric rank-k product) and its pose block is
checked; the tests check symmetry and positive definiteness on every simulated run.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg.lapack import dgeqrf, dpotrf, dtrtrs
from scipy.stats import chi2

from bsslam.errors import FilterError
from bsslam.slam.state import JointState


def gate_threshold(probability: float) -> float:
    """χ² (1 dof) bound of the per-beam innovation gate."""
    return float(chi2.ppf(probability, 1))


def innovation_variances(P: np.ndarray, cols: np.ndarray, H_c: np.ndarray, range_variance: float,
                         P_cc: np.ndarray | None = None) -> np.ndarray:
    """(m,) diagonal of S = H P Hᵀ + R, for per-beam gating (m²); ``P_cc`` is
    ``P[cols][:, cols]`` when the caller has it already."""
    HP = H_c @ (P[np.ix_(cols, cols)] if P_cc is None else P_cc)
    return np.einsum("ij,ij->i", HP, H_c) + range_variance


class CovarianceColumns:
    """``P[:, cols]`` of a covariance that does not change, for the repeated requests of one
    iterated update: gathering n × c scattered entries is the largest cost of a gain after
    the covariance update itself. The columns gathered are kept; a request for a subset of
    them is served from that (n, C) block, which is far faster to index than P.

    Args:
        P: (n, n) covariance; must not change while this object is used.
    """

    def __init__(self, P: np.ndarray):
        self.P = P
        self._cols = np.empty(0, dtype=np.intp)     # sorted
        self._P_c = np.empty((P.shape[0], 0))
        self._last: tuple[np.ndarray, np.ndarray] | None = None

    def get(self, cols: np.ndarray) -> np.ndarray:
        """(n, c) ``P[:, cols]`` (do not modify it)."""
        if self._last is not None and np.array_equal(self._last[0], cols):
            return self._last[1]
        pos = np.searchsorted(self._cols, cols)
        pos_ok = np.minimum(pos, max(self._cols.shape[0] - 1, 0))
        if self._cols.shape[0] and np.array_equal(self._cols[pos_ok], cols):
            out = self._P_c[:, pos]
        else:
            out = self.P[:, cols]
            self._cols, first = np.unique(np.concatenate([self._cols, cols]), return_index=True)
            # the union, taken from what is gathered already where possible
            both = np.concatenate([self._P_c, out], axis=1)
            self._P_c = np.ascontiguousarray(both[:, first])
        self._last = (cols.copy(), out)
        return out

    def block(self, cols: np.ndarray) -> np.ndarray:
        """(c, c) ``P[cols][:, cols]``."""
        return self.get(cols)[cols]


class StackedGain:
    """``S = H P Hᵀ + R`` factorised once for a stacked linearisation, giving the mean
    correction ``P Hᵀ S⁻¹ ν`` for any ν (the iterated EKF reuses it) and the covariance update.

    Args:
        P: (n, n) prior covariance.
        cols: (c,) state indices that ``H`` touches.
        H_c: (m, c) the Jacobian restricted to ``cols``.
        range_variance: R of one beam (m²).
        P_c: optional (n, c) ``P[:, cols]`` when the caller has it already (read only).
    """

    def __init__(self, P: np.ndarray, cols: np.ndarray, H_c: np.ndarray, range_variance: float,
                 P_c: np.ndarray | None = None):
        self.cols = cols
        self.P_c = P[:, cols] if P_c is None else P_c   # (n, c): the only columns of P read
        S = (H_c @ self.P_c[cols]) @ H_c.T
        S[np.diag_indices_from(S)] += range_variance
        self.S_diag = np.diag(S).copy()
        # LAPACK directly: the scipy.linalg front ends cost more than these small solves
        L, info = dpotrf(S, lower=1, clean=1)
        if info != 0:  # pragma: no cover - S ≥ R > 0 in exact arithmetic
            raise FilterError(f"innovation covariance not positive definite (potrf info {info})")
        self.L = L
        self.Y = _lower_solve(L, H_c)   # Hᵀ S⁻¹ H = Yᵀ Y

    def correction(self, innovation: np.ndarray) -> tuple[np.ndarray, float]:
        """(dx (n,), NIS): the mean correction P Hᵀ S⁻¹ ν and ν S⁻¹ ν."""
        w = _lower_solve(self.L, innovation)
        return self.P_c @ (self.Y.T @ w), float(w @ w)

    def posterior_variances(self, P: np.ndarray, cols: np.ndarray, H_c: np.ndarray,
                            range_variance: float) -> np.ndarray:
        """(m,) variances H P⁺ Hᵀ + R of beams linearised on ``cols`` under the posterior
        P⁺ = P − P Hᵀ S⁻¹ H P of this gain, without forming P⁺ beyond those columns."""
        Z = P[np.ix_(cols, self.cols)] @ self.Y.T
        P_post = P[np.ix_(cols, cols)] - Z @ Z.T
        return np.einsum("ij,ij->i", H_c @ P_post, H_c) + range_variance

    def update_covariance(self, state: JointState, workspace: Workspace | None = None) -> None:
        """P ← P − P Hᵀ S⁻¹ H P, as P − Z Zᵀ with the smaller of the two possible ranks.

        ``workspace`` holds the n × n product between calls: a fresh 8 MB temporary at
        n = 1000 costs as much in page faults as the subtraction itself.
        """
        Y = self.Y
        if Y.shape[0] > Y.shape[1]:
            qr_, _, _, _ = dgeqrf(Y)                   # YᵀY = R_yᵀ R_y
            Y = np.triu(qr_[: Y.shape[1]])
        Z = self.P_c @ Y.T
        P = state.P
        n = P.shape[0]
        W = np.empty((n, n)) if workspace is None else workspace.matrix(n)
        # numpy computes Z @ Z.T with syrk: exactly symmetric, so P stays symmetric
        np.matmul(Z, Z.T, out=W)
        np.subtract(P, W, out=P)
        # exactly known components (zero variance, e.g. a fixed start) stay 0; negative is broken
        if np.any(np.diag(P)[:3] < -1e-12):
            raise FilterError("pose covariance lost positive definiteness in the update")


def _lower_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """L⁻¹ b for a lower-triangular (m, m) L and (m,) or (m, k) b."""
    x, info = dtrtrs(L, b, lower=1)
    if info != 0:  # pragma: no cover - L has a positive diagonal
        raise FilterError(f"triangular solve failed (trtrs info {info})")
    return x


class Workspace:
    """Scratch memory reused across updates (one per filter: not shared between threads)."""

    def __init__(self):
        self._buffer = np.empty(0)

    def matrix(self, n: int) -> np.ndarray:
        """A contiguous (n, n) scratch array (contents undefined)."""
        if self._buffer.shape[0] < n * n:
            self._buffer = np.empty(max(n * n, 2 * self._buffer.shape[0]))
        return self._buffer[: n * n].reshape(n, n)
