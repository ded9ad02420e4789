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

import functools

import numpy as np
from scipy.linalg.lapack import dgeqrf, dormqr, dpotrf, dtrtrs
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
    ``P[rows][:, cols]`` and products ``P[:, cols] v``, never n × c columns of P itself.

    The filter's :class:`JointState` keeps P = base − B G Bᵀ with a pending term. Gathering
    the columns P[:, cols] would cost n·c·a there (the pending term's product with each
    column; c ≈ 40, a ≤ 256): at n = 1000 that was most of the gain's time. Instead a block
    costs rows·cols·a, and a product is the base rows' (gathered once per state index for
    the whole update, like the old columns but without the pending term) plus
    B (G (B[cols]ᵀ v)) at n·a.

    Args:
        source: the (n, n) symmetric covariance, or a :class:`JointState` (read without
            folding its pending update); must not change while this object is used.
    """

    def __init__(self, source: np.ndarray | JointState):
        self._source = source
        if isinstance(source, JointState):
            self._slot = np.full(source.size, -1, dtype=np.intp)   # row of _rows holding index j
            self._rows = np.empty((64, source.size))                 # base rows gathered so far
            self._count = 0

    def block(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(r, c) ``P[rows][:, cols]`` (a new array)."""
        if isinstance(self._source, JointState):
            return self._source.block(rows, cols)
        return self._source[np.ix_(rows, cols)]

    def times(self, cols: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(n,) ``P[:, cols] @ v`` for (c,) ``v`` (``cols`` distinct)."""
        state = self._source
        if not isinstance(state, JointState):
            return state[:, cols] @ v
        slot = self._slots(cols)
        weights = np.zeros(self._count)
        weights[slot] = v
        out = weights @ self._rows[: self._count]     # Σ_j v_j base[j, :], no gather
        out -= state.pending_columns_times(cols, v)
        return out

    def _slots(self, cols: np.ndarray) -> np.ndarray:
        slot = self._slot[cols]
        missing = cols[slot < 0]
        if missing.size:
            end = self._count + missing.shape[0]
            if end > self._rows.shape[0]:
                grown = np.empty((max(2 * self._rows.shape[0], end), self._rows.shape[1]))
                grown[: self._count] = self._rows[: self._count]
                self._rows = grown
            self._rows[self._count : end] = self._source.base_rows(missing)
            self._slot[missing] = np.arange(self._count, end)
            self._count = end
            slot = self._slot[cols]
        return slot


class StackedGain:
    """The gain of a stacked linearisation ``S = H P Hᵀ + R`` (R = r I), factorised once,
    giving the mean correction ``P Hᵀ S⁻¹ ν`` for any ν (the iterated EKF reuses it) and
    the covariance update.

    With m beams on c state columns (typically m ≈ 100 beams on c ≈ 40 columns), S is
    m × m, but it is never formed: with the thin QR H = Q R_h (Q: m × k orthonormal,
    R_h: k × c, k = min(m, c)),

        S⁻¹ = (I − Q Qᵀ)/r + Q M⁻¹ Qᵀ,   M = r I_k + R_h P_cc R_hᵀ  (k × k),

    so Hᵀ S⁻¹ H = Yᵀ Y with Y = L_M⁻¹ R_h (L_M the Cholesky factor of M), the correction
    is P[:, cols] Yᵀ L_M⁻¹ Qᵀ ν, and νᵀ S⁻¹ ν = |L_M⁻¹ Qᵀ ν|² + |ν − Q Qᵀ ν|²/r. That is
    O(m c²) instead of the O(m³) Cholesky of S, and M ≥ r I is well conditioned.

    Args:
        P: (n, n) prior covariance, or its :class:`PriorCovariance`.
        cols: (c,) state indices that ``H`` touches.
        H_c: (m, c) the Jacobian restricted to ``cols``.
        range_variance: r, the variance of one beam (m²).
    """

    def __init__(self, P: np.ndarray | PriorCovariance, cols: np.ndarray, H_c: np.ndarray,
                 range_variance: float):
        self.cols = cols
        self._prior = _prior_of(P)
        self._H_c = H_c
        self._r = range_variance
        self._P_cc = self._prior.block(cols, cols)
        m, c = H_c.shape
        k = min(m, c)
        # LAPACK directly: the scipy.linalg front ends cost more than these small solves
        qr, tau, _, info = dgeqrf(H_c)
        if info != 0:  # pragma: no cover - only for invalid arguments
            raise FilterError(f"QR of the stacked Jacobian failed (geqrf info {info})")
        self._reflectors, self._tau = qr[:, :k], tau
        R_h = qr[:k] * _upper_mask(k, c)             # np.triu, without building the mask each time
        M = (R_h @ self._P_cc) @ R_h.T
        M.flat[:: k + 1] += range_variance
        L, info = dpotrf(M, lower=1, clean=1)
        if info != 0:  # pragma: no cover - M ≥ r I > 0 in exact arithmetic
            raise FilterError(f"innovation covariance not positive definite (potrf info {info})")
        self.L = L
        self.Y = _lower_solve(L, R_h)   # Hᵀ S⁻¹ H = Yᵀ Y, (k, c)

    @functools.cached_property
    def S_diag(self) -> np.ndarray:
        """(m,) diagonal of S = H P Hᵀ + R (m²)."""
        return np.einsum("ij,ij->i", self._H_c @ self._P_cc, self._H_c) + self._r

    def correction(self, innovation: np.ndarray) -> tuple[np.ndarray, float]:
        """(dx (n,), NIS): the mean correction P Hᵀ S⁻¹ ν and ν S⁻¹ ν."""
        k = self.L.shape[0]
        # Qᵀ ν with the full orthogonal Q: its first k entries are the thin Qᵀ ν, the rest
        # has the norm of ν − Q Qᵀ ν (no cancellation)
        qt, _, info = dormqr(b"L", b"T", self._reflectors, self._tau, innovation.reshape(-1, 1),
                             max(1, innovation.shape[0]))
        if info != 0:  # pragma: no cover - only for invalid arguments
            raise FilterError(f"applying Qᵀ failed (ormqr info {info})")
        qt = qt[:, 0]
        w = _lower_solve(self.L, qt[:k])
        rest = qt[k:]
        return self._prior.times(self.cols, self.Y.T @ w), float(w @ w + (rest @ rest) / self._r)

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
        """P ← P − P Hᵀ S⁻¹ H P, as P − Z Zᵀ with Z = P[:, cols] Yᵀ of rank min(m, c),
        handed to ``state`` (which defers it, see :class:`JointState`)."""
        state.subtract_column_update(self.cols, self.Y.T)
        # exactly known components (zero variance, e.g. a fixed start) stay 0; negative is broken
        if np.any(np.diag(state.pose_covariance) < -1e-12):
            raise FilterError("pose covariance lost positive definiteness in the update")


@functools.lru_cache(maxsize=64)
def _upper_mask(k: int, c: int) -> np.ndarray:
    """(k, c) 1.0 on and above the diagonal, 0.0 below (read only)."""
    mask = np.triu(np.ones((k, c)))
    mask.setflags(write=False)
    return mask


def _prior_of(P: np.ndarray | PriorCovariance) -> PriorCovariance:
    """``P`` itself when it is a :class:`PriorCovariance` already, else a view of it."""
    return P if isinstance(P, PriorCovariance) else PriorCovariance(P)


def _lower_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """L⁻¹ b for a lower-triangular (m, m) L and (m,) or (m, k) b."""
    x, info = dtrtrs(L, b, lower=1)
    if info != 0:  # pragma: no cover - L has a positive diagonal
        raise FilterError(f"triangular solve failed (trtrs info {info})")
    return x
