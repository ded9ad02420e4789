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
import functools

from scipy.linalg.lapack import dgeqrf, dormqr, dpotrf, dtrtrs

from bsslam.chi2 import chi2_quantile
from bsslam.errors import FilterError
from bsslam.slam.kernels import take_block
from bsslam.slam.state import POSE, JointState


def gate_threshold(probability: float) -> float:
    """χ² (1 dof) bound of the per-beam innovation gate."""
    return chi2_quantile(probability, 1)


def innovation_variances(P: np.ndarray | CovarianceColumns, cols: np.ndarray, H_c: np.ndarray,
                         R: float | np.ndarray) -> np.ndarray:
    """(m,) diagonal of S = H P Hᵀ + R, for per-beam gating (m²); ``P`` is the (n, n)
    covariance or its :class:`CovarianceColumns`; R as :class:`StackedGain` takes it."""
    HP = H_c @ _columns_of(P).block(cols)
    return np.einsum("ij,ij->i", HP, H_c) + _noise_diagonal(R)


def _noise_diagonal(R: float | np.ndarray) -> float | np.ndarray:
    """The measurement noise's variances: R itself when it is a scalar (R = r·I) or the
    (m,) diagonal, the diagonal of an (m, m) R."""
    return R.diagonal() if isinstance(R, np.ndarray) and R.ndim == 2 else R


class CovarianceColumns:
    """``P[:, cols]`` of a covariance that does not change, for the repeated requests of one
    iterated update, on a working set of rows.

    The iterations only need the correction on the entries they relinearise (the pose and
    the observed splines' control points: ``rows``); the whole state's correction is
    needed once, at the end (:meth:`times`). So each requested state index is gathered once,
    as the row ``P[i, rows]`` (P is symmetric), and the requests are served from those; with
    a :class:`JointState` this reads its pending update on ``rows`` only, not on all n.
    Given working rows, the first request gathers all of them: a scan's update asks for
    every one of them in the end (the median scan of the simulated corridor did), over about
    four requests, and one read of a block costs less than four of its parts.

    Args:
        source: the (n, n) symmetric covariance, or a :class:`JointState` (read without
            folding its pending update); must not change while this object is used.
        rows: (w,) sorted state indices starting with the pose (0, 1, 2), a superset of
            every ``cols`` requested; all n when None.
    """

    def __init__(self, source: np.ndarray | JointState, rows: np.ndarray | None = None):
        n = source.size if isinstance(source, JointState) else source.shape[0]
        self.rows = np.arange(n) if rows is None else np.asarray(rows, dtype=np.intp)
        if self.rows.shape[0] < 3 or np.any(self.rows[:3] != POSE):
            raise FilterError("covariance columns: the working rows must start with the pose")
        self._source = source
        self._position = np.full(n, -1, dtype=np.intp)   # place of each state index in ``rows``
        self._position[self.rows] = np.arange(self.rows.shape[0])
        self._slot = np.full(n, -1, dtype=np.intp)   # row of _rows holding each state index
        self._rows = np.empty((64, self.rows.shape[0]))   # P[i, rows] of the indices gathered so far
        self._count = 0
        self._last: tuple[np.ndarray, np.ndarray] | None = None
        self._whole_at_first = rows is not None

    def _gather(self, index: np.ndarray) -> np.ndarray:
        if isinstance(self._source, JointState):
            return self._source.block(index, self.rows)
        return take_block(self._source, index, self.rows)

    def _slots(self, cols: np.ndarray) -> np.ndarray:
        slot = self._slot[cols]
        missing = cols[slot < 0]
        if missing.size:
            if np.any(self._position[missing] < 0):
                raise FilterError("covariance columns: a requested index is outside the working rows")
            new = self.rows if self._whole_at_first and self._count == 0 else np.unique(missing)
            end = self._count + new.shape[0]
            if end > self._rows.shape[0]:
                grown = np.empty((max(2 * self._rows.shape[0], end), self._rows.shape[1]))
                grown[: self._count] = self._rows[: self._count]
                self._rows = grown
            self._rows[self._count : end] = self._gather(new)
            self._slot[new] = np.arange(self._count, end)
            self._count = end
            slot = self._slot[cols]
        return slot

    def get(self, cols: np.ndarray) -> np.ndarray:
        """(w, c) ``P[rows, cols]`` (a transposed view of gathered rows; do not modify it)."""
        if self._last is not None and np.array_equal(self._last[0], cols):
            return self._last[1]
        slot = self._slots(cols)   # may replace self._rows: index it after
        out = self._rows[slot].T
        self._last = (cols.copy(), out)
        return out

    def position(self, index: np.ndarray) -> np.ndarray:
        """(k,) the places of state indices in ``rows`` (the rows of :meth:`get`)."""
        return self._position[index]

    def block(self, cols: np.ndarray) -> np.ndarray:
        """(c, c) ``P[cols][:, cols]``."""
        slot = self._slots(cols)
        return take_block(self._rows, slot, self._position[cols])

    def times(self, cols: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(n,) ``P[:, cols] v`` on the whole state, for (c,) ``v``."""
        if isinstance(self._source, JointState):
            return self._source.columns_times(cols, v)
        return self._source[:, cols] @ v

    def innovation_variances(self, cols: np.ndarray, H_c: np.ndarray, R: float | np.ndarray) -> np.ndarray:
        """(m,) diagonal of S = H P Hᵀ + R (:func:`innovation_variances`)."""
        return innovation_variances(self, cols, H_c, R)

    def gain(self, cols: np.ndarray, H_c: np.ndarray, R: float | np.ndarray) -> StackedGain:
        """The :class:`StackedGain` of H (m, c) on ``cols`` with noise R, on these rows."""
        return StackedGain(self, cols, H_c, R)


class StackedGain:
    """``S = H P Hᵀ + R`` factorised once for a stacked linearisation, giving the mean
    correction ``P Hᵀ S⁻¹ ν`` for any ν (the iterated EKF reuses it) and the covariance update.

    With many more beams than touched columns (m ≥ 2c, the usual case: a scan's ~90 beams
    fall on ~25 state columns at the default knot spacing), the gain is computed in the
    c-dimensional range of H instead of the m-dimensional measurement space. With
    H = Q R_h (thin QR) and R = r I, ``S = Q (R_h P Rₕᵀ + r I) Qᵀ + r (I − Q Qᵀ)``, so
    ``Hᵀ S⁻¹ H = Rₕᵀ S_c⁻¹ R_h`` with the c × c ``S_c = R_h P Rₕᵀ + r I``; the part of ν
    outside the range of H only adds |ν⊥|²/r to the NIS. The QR costs 2mc² against the
    m³/3 + 2m²c of factorising S and solving with it, and the update's own QR of Y goes.

    The compressed form needs R = r I. A diagonal R ((m,) variances) or a full (block) R
    ((m, m), e.g. beams with correlated errors) takes the general path: S factorised in
    the m-dimensional measurement space.

    Args:
        P: (n, n) prior covariance, or its :class:`CovarianceColumns`.
        cols: (c,) state indices that ``H`` touches.
        H_c: (m, c) the Jacobian restricted to ``cols``.
        range_variance: R: a scalar r for R = r I (m²), the (m,) diagonal of R, or the
            (m, m) R.

    Attributes:
        L: lower Cholesky factor of S (m × m), or of S_c (c × c) when compressed.
        Y: L⁻¹ H (m × c), or L⁻¹ R_h (c × c): either way Hᵀ S⁻¹ H = Yᵀ Y.
    """

    def __init__(self, P: np.ndarray | CovarianceColumns, cols: np.ndarray, H_c: np.ndarray,
                 range_variance: float | np.ndarray):
        self.cols = cols
        self._columns = _columns_of(P)
        self._H_c = H_c
        self._range_variance = range_variance
        # (w, c): the only columns of P read, on the working rows (read only)
        self.P_c = self._columns.get(cols)
        P_cc = self.P_c[self._columns.position(cols)]
        m, c = H_c.shape
        scalar = not isinstance(range_variance, np.ndarray) or range_variance.ndim == 0
        if scalar and m >= 2 * c:
            qr_, tau, _, info = dgeqrf(H_c)
            if info != 0:  # pragma: no cover - only for an invalid argument
                raise FilterError(f"QR of the stacked Jacobian failed (geqrf info {info})")
            self._qr = (qr_, tau)
            R_h = qr_[:c] * _upper_mask(c)
            S = (R_h @ P_cc) @ R_h.T
            self._S_diag = None
        else:
            self._qr = None
            R_h = H_c
            S = (H_c @ P_cc) @ H_c.T
        if scalar or range_variance.ndim == 1:
            S.flat[:: S.shape[0] + 1] += range_variance     # the diagonal, without index arrays
        else:
            S += range_variance
        if self._qr is None:
            self._S_diag = S.diagonal().copy()
        # LAPACK directly: the scipy.linalg front ends cost more than these small solves
        L, info = dpotrf(S, lower=1, clean=1)
        if info != 0:  # pragma: no cover - S ≥ R > 0 in exact arithmetic
            raise FilterError(f"innovation covariance not positive definite (potrf info {info})")
        self.L = L
        self.Y = _lower_solve(L, R_h)   # Hᵀ S⁻¹ H = Yᵀ Y

    @property
    def S_diag(self) -> np.ndarray:
        """(m,) the diagonal of S = H P Hᵀ + R: each beam's innovation variance (m²)."""
        if self._S_diag is None:
            P_cc = self.P_c[self._columns.position(self.cols)]
            self._S_diag = np.einsum("ij,ij->i", self._H_c @ P_cc, self._H_c) + _noise_diagonal(self._range_variance)
        return self._S_diag

    def _whiten(self, innovation: np.ndarray) -> tuple[np.ndarray, float]:
        """(w, e) with L w the innovation's part in the range of H (all of it when not
        compressed), so that Hᵀ S⁻¹ ν = Yᵀ w and ν S⁻¹ ν = w·w + e."""
        if self._qr is None:
            return _lower_solve(self.L, innovation), 0.0
        qr_, tau = self._qr
        t, _, info = dormqr("L", "T", qr_, tau, innovation, 1)   # Qᵀ ν with the full, square Q
        if info != 0:  # pragma: no cover - only for an invalid argument
            raise FilterError(f"applying the Jacobian's Q failed (ormqr info {info})")
        c = qr_.shape[1]
        return _lower_solve(self.L, t[:c]), float(t[c:] @ t[c:]) / self._range_variance

    def correction(self, innovation: np.ndarray) -> tuple[np.ndarray, float]:
        """(dx (w,), NIS): the mean correction P Hᵀ S⁻¹ ν on the working rows (all n for a
        plain covariance; see :class:`CovarianceColumns`) and ν S⁻¹ ν."""
        w, outside = self._whiten(innovation)
        return self.P_c @ (self.Y.T @ w), float(w @ w) + outside

    def state_correction(self, innovation: np.ndarray) -> tuple[np.ndarray, float]:
        """(dx (n,), NIS): the mean correction P Hᵀ S⁻¹ ν on the whole state, and ν S⁻¹ ν."""
        w, outside = self._whiten(innovation)
        return self._columns.times(self.cols, self.Y.T @ w), float(w @ w) + outside

    def pose_variances(self, prior: np.ndarray) -> np.ndarray:
        """(3,) posterior variances of the pose under this gain, from its ``prior`` (3,)
        variances: diag(P_pp − P_pc Hᵀ S⁻¹ H P_cp) (m², m², rad²); clipped at 0."""
        return np.maximum(prior - self._pose_variance_drop(), 0.0)

    def _pose_variance_drop(self) -> np.ndarray:
        """(3,) diag(P_pc Hᵀ S⁻¹ H P_cp): what this gain takes off the pose's variances."""
        Z = self.Y @ self.P_c[:3].T          # (m, 3)
        return np.einsum("ij,ij->j", Z, Z)

    def posterior_variances(self, cols: np.ndarray, H_c: np.ndarray, range_variance: float | np.ndarray
                            ) -> np.ndarray:
        """(m,) variances H P⁺ Hᵀ + R of beams linearised on ``cols`` under the posterior
        P⁺ = P − P Hᵀ S⁻¹ H P of this gain, without forming P⁺ beyond those columns
        (``cols`` within the gain's working rows)."""
        P = self._columns
        P_cg, P_cc = P.get(self.cols)[P.position(cols)], P.block(cols)
        Z = P_cg @ self.Y.T
        P_post = P_cc - Z @ Z.T
        return np.einsum("ij,ij->i", H_c @ P_post, H_c) + _noise_diagonal(range_variance)

    def posterior_block(self) -> np.ndarray:
        """(w, w) the posterior P⁺ = P − P Hᵀ S⁻¹ H P of this gain on its working rows."""
        Z = self.P_c @ self.Y.T
        return self._columns.block(self._columns.rows) - Z @ Z.T

    def update_covariance(self, state: JointState) -> None:
        """P ← P − P Hᵀ S⁻¹ H P, as P − Z Zᵀ with the smaller of the two possible ranks,
        handed to ``state`` (which defers it, see :class:`JointState`)."""
        # The pose's variances after the update, checked below, from the gain's own numbers
        # when its columns start with the pose (always, in the filter): read from the state
        # they would cost a fresh read of its deferred term, which the next prediction drops.
        pose_first = np.array_equal(self.cols[:3], POSE)
        if pose_first:
            pose_var = self.P_c[POSE, POSE] - self._pose_variance_drop()
        Y = self.Y
        if Y.shape[0] > Y.shape[1]:
            qr_, _, _, _ = dgeqrf(Y)                   # YᵀY = R_yᵀ R_y
            Y = qr_[: Y.shape[1]] * _upper_mask(Y.shape[1])
        state.subtract_column_update(self.cols, Y.T)   # Z = P_c Yᵀ
        if not pose_first:
            pose_var = np.diag(state.pose_covariance)
        # exactly known components (zero variance, e.g. a fixed start) stay 0; negative is broken
        if np.any(pose_var < -1e-12):
            raise FilterError("pose covariance lost positive definiteness in the update")


def _columns_of(P: np.ndarray | CovarianceColumns) -> CovarianceColumns:
    """``P`` itself when it is a :class:`CovarianceColumns` already, else its columns."""
    return P if isinstance(P, CovarianceColumns) else CovarianceColumns(P)


@functools.lru_cache(maxsize=None)
def _upper_mask(c: int) -> np.ndarray:
    """(c, c) ones on and above the diagonal (read only): R of a QR without ``np.triu``'s
    index arrays, which cost more than the rest of a small gain."""
    mask = np.triu(np.ones((c, c)))
    mask.flags.writeable = False
    return mask


def _lower_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """L⁻¹ b for a lower-triangular (m, m) L and (m,) or (m, k) b."""
    x, info = dtrtrs(L, b, lower=1)
    if info != 0:  # pragma: no cover - L has a positive diagonal
        raise FilterError(f"triangular solve failed (trtrs info {info})")
    return x
