"""The EKF update for all accepted beams of a scan (spec §7, paper §III-E.2).

``H`` is non-zero only in the pose columns and the columns of the observed control points,
so everything is built from those columns (``cols``): ``P Hᵀ = P[:, cols] H_cᵀ``. The
covariance correction ``P ← P − P Hᵀ S⁻¹ H P`` is applied as a symmetric low-rank update
``P ← P − Z Zᵀ`` with rank min(beams, touched columns), which :class:`JointState` defers
and folds in once many scans have gathered: that is the only O(n²) work. The Joseph form
would cost O(n³) on the full state; instead the result is exactly symmetric (the fold
writes both triangles from the same products) and its pose block is checked; the tests
check symmetry and positive definiteness on every simulated run.
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


def innovation_variances(P: np.ndarray | PriorCovariance, cols: np.ndarray, H_c: np.ndarray,
                         range_variance: float) -> np.ndarray:
    """(m,) diagonal of S = H P Hᵀ + R, for per-beam gating (m²); ``P`` is the (n, n)
    covariance or its :class:`PriorCovariance`."""
    HP = H_c @ _prior_of(P).block(cols, cols)
    return np.einsum("ij,ij->i", HP, H_c) + range_variance


class PriorCovariance:
    """The prior covariance of one (iterated) update, as the gain reads it: small blocks
    ``P[rows][:, cols]`` and products ``P[:, cols] v``, never all of P nor n × c columns of it.

    The filter's :class:`JointState` keeps P = base − B G Bᵀ with a pending term; a block
    costs rows·cols·a and a product n·(c + a) there, where gathering the columns P[:, cols]
    would cost n·c·a (the pending term's product with each column): at n = 1000 and a = 256
    that gather was most of the gain's time.

    Args:
        source: the (n, n) symmetric covariance, or a :class:`JointState` (read without
            folding its pending update); must not change while this object is used.
    """

    def __init__(self, source: np.ndarray | JointState):
        self._source = source

    def block(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(r, c) ``P[rows][:, cols]`` (a new array)."""
        if isinstance(self._source, JointState):
            return self._source.block(rows, cols)
        return self._source[np.ix_(rows, cols)]

    def times(self, cols: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(n,) ``P[:, cols] @ v`` for (c,) ``v``."""
        if isinstance(self._source, JointState):
            return self._source.columns_times(cols, v)
        return self._source[:, cols] @ v


class StackedGain:
    """``S = H P Hᵀ + R`` factorised once for a stacked linearisation, giving the mean
    correction ``P Hᵀ S⁻¹ ν`` for any ν (the iterated EKF reuses it) and the covariance update.

    Args:
        P: (n, n) prior covariance, or its :class:`PriorCovariance`.
        cols: (c,) state indices that ``H`` touches.
        H_c: (m, c) the Jacobian restricted to ``cols``.
        range_variance: R of one beam (m²).
    """

    def __init__(self, P: np.ndarray | PriorCovariance, cols: np.ndarray, H_c: np.ndarray,
                 range_variance: float):
        self.cols = cols
        self._prior = _prior_of(P)
        S = (H_c @ self._prior.block(cols, cols)) @ H_c.T
        S.flat[:: S.shape[0] + 1] += range_variance     # the diagonal, without index arrays
        self.S_diag = S.diagonal().copy()
        # LAPACK directly: the scipy.linalg front ends cost more than these small solves
        L, info = dpotrf(S, lower=1, clean=1)
        if info != 0:  # pragma: no cover - S ≥ R > 0 in exact arithmetic
            raise FilterError(f"innovation covariance not positive definite (potrf info {info})")
        self.L = L
        self.Y = _lower_solve(L, H_c)   # Hᵀ S⁻¹ H = Yᵀ Y

    def correction(self, innovation: np.ndarray) -> tuple[np.ndarray, float]:
        """(dx (n,), NIS): the mean correction P Hᵀ S⁻¹ ν and ν S⁻¹ ν."""
        w = _lower_solve(self.L, innovation)
        return self._prior.times(self.cols, self.Y.T @ w), float(w @ w)

    def posterior_variances(self, P: np.ndarray | PriorCovariance, cols: np.ndarray, H_c: np.ndarray,
                            range_variance: float) -> np.ndarray:
        """(m,) variances H P⁺ Hᵀ + R of beams linearised on ``cols`` under the posterior
        P⁺ = P − P Hᵀ S⁻¹ H P of this gain, without forming P⁺ beyond those columns.
        ``P`` is the prior (n, n) or its :class:`PriorCovariance`."""
        P = _prior_of(P)
        Z = P.block(cols, self.cols) @ self.Y.T
        P_post = P.block(cols, cols) - Z @ Z.T
        return np.einsum("ij,ij->i", H_c @ P_post, H_c) + range_variance

    def update_covariance(self, state: JointState) -> None:
        """P ← P − P Hᵀ S⁻¹ H P, as P − Z Zᵀ with the smaller of the two possible ranks,
        handed to ``state`` (which defers it, see :class:`JointState`)."""
        Y = self.Y
        if Y.shape[0] > Y.shape[1]:
            qr_, _, _, _ = dgeqrf(Y)                   # YᵀY = R_yᵀ R_y
            Y = np.triu(qr_[: Y.shape[1]])
        state.subtract_column_update(self.cols, Y.T)   # Z = P[:, cols] Yᵀ
        # exactly known components (zero variance, e.g. a fixed start) stay 0; negative is broken
        if np.any(np.diag(state.pose_covariance) < -1e-12):
            raise FilterError("pose covariance lost positive definiteness in the update")


def _prior_of(P: np.ndarray | PriorCovariance) -> PriorCovariance:
    """``P`` itself when it is a :class:`PriorCovariance` already, else a view of it."""
    return P if isinstance(P, PriorCovariance) else PriorCovariance(P)


def _lower_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """L⁻¹ b for a lower-triangular (m, m) L and (m,) or (m, k) b."""
    x, info = dtrtrs(L, b, lower=1)
    if info != 0:  # pragma: no cover - L has a positive diagonal
        raise FilterError(f"triangular solve failed (trtrs info {info})")
    return x
