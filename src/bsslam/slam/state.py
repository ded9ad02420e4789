"""The joint EKF state: robot pose plus the control points of every map spline.

Layout: ``x[0:3]`` is the pose (x m, y m, φ rad); every other entry is one coordinate of one
control point. A spline does not own a contiguous slice: it owns two index arrays
(``idx_x``, ``idx_y``) into the state. That is what makes extension cheap: new control
points are appended at the end of the state whatever end of the curve they extend, and
only the spline's index arrays record the curve order.

Storage grows with amortised capacity (doubling), so adding a feature costs the copy of the
new rows and columns only, not a reallocation of ``P``.

The EKF update ``P ← P − Z Zᵀ`` (Z of rank k ≈ 10–90 per scan) is deferred: the state keeps
a base matrix and a pending factor D with ``P = base − D Dᵀ``, and folds D into the base
only when it has gathered ``max_pending`` columns. An update costs little arithmetic
(n²k) but one pass over all of P — 62 MB at n = 2800 — and the pass, not the arithmetic,
was the cost; folding several updates at once makes one pass serve them all. Everything
the filter reads per scan (columns, rows and blocks of P, the pose covariance) is served
exactly as base − D Dᵀ on those entries, at O(n·K·c).
"""

from __future__ import annotations

import numpy as np

from bsslam.errors import FilterError

POSE = np.arange(3)

#: Extra columns of the covariance buffer. Capacities double from 64, so without them every
#: row of P would start a power-of-two number of bytes after the previous one, and the rows
#: of the O(n²) update would all compete for the same cache sets: P − W on a 1150 × 1150
#: view of a 2048-wide buffer took 6–7 ms, of a 2056-wide one 2.2–3 ms (one core).
ROW_PAD = 8


#: Pending columns folded into the base at once. Larger means fewer passes over P but dearer
#: column gathers (n·K·c each). Per scan (rank 45, three 60-column gathers, one core) this
#: cost 5.8 ms at n = 1000 and 37 ms at n = 2800, against 7.3 and 50 ms folding every scan;
#: 256 was 6.3 and 29 ms. The full Intel run was the same within noise at 128 and 256.
MAX_PENDING = 128

#: Rows of P per block when the pending factor is folded in: a block row of the product
#: (b × n doubles) stays in the L2 cache while it is subtracted from P.
FOLD_BLOCK = 128


class JointState:
    """Mean ``x`` (n,) and covariance ``P`` (n, n) with room to grow.

    ``x`` and ``P`` are views of the live part of larger buffers; they are replaced (not
    resized in place) when the buffers grow, so never keep them across an ``append``.
    Reading ``P`` first folds any pending low-rank update into it (one O(n²) pass); the
    per-scan code uses :meth:`columns`, :meth:`block` and :attr:`pose_covariance` instead.
    """

    def __init__(self, pose: np.ndarray, pose_covariance: np.ndarray, capacity: int = 64,
                 max_pending: int = MAX_PENDING):
        capacity = max(int(capacity), 3)
        self._x = np.zeros(capacity)
        self._P = np.zeros((capacity, capacity + ROW_PAD))
        self._D = np.zeros((capacity, max_pending))   # pending factor, its first k columns live
        self._k = 0
        self.size = 3
        self._x[:3] = np.asarray(pose, dtype=float)
        C = np.asarray(pose_covariance, dtype=float)
        self._P[:3, :3] = 0.5 * (C + C.T)   # exactly symmetric: rows are served as columns

    # -- views ---------------------------------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        """(n,) live mean (a view)."""
        return self._x[: self.size]

    @property
    def P(self) -> np.ndarray:
        """(n, n) live covariance (a view), with every pending update folded in."""
        self.fold()
        return self._P[: self.size, : self.size]

    @property
    def base(self) -> np.ndarray:
        """(n, n) the covariance less the pending term D Dᵀ (a view). Only for code that
        transforms rows and columns of P and carries :attr:`pending` along."""
        return self._P[: self.size, : self.size]

    @property
    def pending(self) -> np.ndarray:
        """(n, k) the pending factor D of ``P = base − D Dᵀ`` (a view; k may be 0)."""
        return self._D[: self.size, : self._k]

    @property
    def capacity(self) -> int:
        return self._x.shape[0]

    @property
    def pose(self) -> np.ndarray:
        return self._x[:3]

    @property
    def pose_covariance(self) -> np.ndarray:
        """(3, 3) covariance of the pose (a new array)."""
        D = self._D[:3, : self._k]
        return self._P[:3, :3] - D @ D.T

    def rows(self, rows: np.ndarray) -> np.ndarray:
        """(r, n) ``P[rows, :]`` (a new, C-ordered array)."""
        out = self.base[rows]
        if self._k:
            D = self.pending
            out -= D[rows] @ D.T
        return out

    def columns(self, cols: np.ndarray) -> np.ndarray:
        """(n, c) ``P[:, cols]`` (a new array, Fortran-ordered). P is kept exactly symmetric,
        so its columns are gathered as rows: c contiguous runs of memory instead of n·c
        scattered entries (5–8× faster at n = 2000)."""
        return self.rows(cols).T

    def block(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(r, c) ``P[np.ix_(rows, cols)]`` (a new array)."""
        out = self.base[np.ix_(rows, cols)]
        if self._k:
            D = self.pending
            out -= D[rows] @ D[cols].T
        return out

    def diagonal(self, rows: np.ndarray) -> np.ndarray:
        """(r,) ``P[rows, rows]`` (a new array)."""
        out = self.base[rows, rows]
        if self._k:
            D = self.pending[rows]
            out -= np.einsum("ij,ij->i", D, D)
        return out

    # -- the update ----------------------------------------------------------------------
    def subtract_low_rank(self, Z: np.ndarray) -> None:
        """P ← P − Z Zᵀ for Z (n, k), deferred (see the module docstring)."""
        n, k = Z.shape
        if n != self.size:
            raise FilterError(f"low-rank update of {n} rows for a state of size {self.size}")
        if self._k + k > self._D.shape[1]:
            self.fold()
        if k > self._D.shape[1]:        # wider than the whole buffer: straight into the base
            _subtract_outer(self.base, Z)
            return
        self._D[:n, self._k : self._k + k] = Z
        self._k += k

    def fold(self) -> None:
        """Fold the pending update into the base: base ← base − D Dᵀ, D ← empty."""
        if self._k:
            _subtract_outer(self.base, self.pending)
            self._k = 0

    def transform(self, idx: np.ndarray, T: np.ndarray) -> None:
        """x[idx] ← T x[idx] and P ← A P Aᵀ, A the identity with T on the block ``idx``.

        Only the rows and columns ``idx`` change; they are written exactly symmetric (the
        rows T P once, copied transposed to the columns; the block T P Tᵀ symmetrised).
        """
        x, P = self.x, self.base
        x[idx] = T @ x[idx]
        rows = T @ P[idx, :]
        P[idx, :] = rows
        P[:, idx] = rows.T
        block = rows[:, idx] @ T.T
        P[np.ix_(idx, idx)] = 0.5 * (block + block.T)
        self.transform_pending(idx, T)

    def transform_pending(self, idx: np.ndarray, T: np.ndarray) -> None:
        """Carry A P Aᵀ (A as in :meth:`transform`) through the pending term: D[idx] ← T D[idx].
        For code that transforms the rows and columns ``idx`` of :attr:`base` itself."""
        if self._k:
            D = self.pending
            D[idx] = T @ D[idx]

    # -- growth --------------------------------------------------------------------------
    def _reserve(self, new_size: int) -> None:
        if new_size <= self.capacity:
            return
        capacity = self.capacity
        while capacity < new_size:
            capacity *= 2
        x = np.zeros(capacity)
        P = np.zeros((capacity, capacity + ROW_PAD))
        D = np.zeros((capacity, self._D.shape[1]))
        x[: self.size] = self.x
        P[: self.size, : self.size] = self.base
        D[: self.size, : self._k] = self.pending
        self._x, self._P, self._D = x, P, D

    def append(self, mean: np.ndarray, cross: np.ndarray, block: np.ndarray) -> np.ndarray:
        """Augment the state with k new entries.

        Args:
            mean: (k,) their values.
            cross: (k, n) their covariance with the current state.
            block: (k, k) their own covariance.
        Returns:
            (k,) the new state indices.
        """
        mean = np.asarray(mean, dtype=float).reshape(-1)
        k, n = mean.shape[0], self.size
        if cross.shape != (k, n) or block.shape != (k, k):
            raise FilterError(f"append: cross {cross.shape} / block {block.shape} do not fit k={k}, n={n}")
        self._reserve(n + k)
        self._x[n : n + k] = mean
        # P = base − D Dᵀ with zero rows of D for the new entries: the base holds them exactly
        self._P[n : n + k, :n] = cross
        self._P[:n, n : n + k] = cross.T
        self._P[n : n + k, n : n + k] = 0.5 * (block + block.T)
        self._D[n : n + k, : self._k] = 0.0
        self.size = n + k
        return np.arange(n, n + k)

    def remove(self, indices: np.ndarray) -> np.ndarray:
        """Delete state entries (never the pose). O(n²), meant to be rare.

        Returns:
            (n_old,) map from old index to new index (−1 for removed entries).
        """
        indices = np.unique(np.asarray(indices, dtype=int))
        if indices.size == 0:
            return np.arange(self.size)
        if indices.min() < 3 or indices.max() >= self.size:
            raise FilterError("remove: indices must address map entries of the live state")
        n = self.size
        keep = np.ones(n, dtype=bool)
        keep[indices] = False
        kept = np.flatnonzero(keep)
        m = kept.size
        # Compact in place, moving only what lies after the first removed entry: pruned
        # splines are usually the newest, at the end of the state, so this is mostly a
        # shrink. (Gathering P[kept][:, kept] copied all of P twice: 30 ms at n = 2800.)
        first = int(indices[0])
        tail = kept[first:]                       # kept entries that move (kept[:first] stay)
        if tail.size:
            self._x[first:m] = self._x[tail]
            self._P[first:m, :n] = self._P[tail, :n]
            self._P[:m, first:m] = self._P[:m, tail]
            self._D[first:m, : self._k] = self._D[tail, : self._k]
        self.size = m
        mapping = np.full(n, -1)
        mapping[kept] = np.arange(m)
        return mapping

    def symmetrize(self) -> None:
        P = self.P
        P += P.T
        P *= 0.5


def _subtract_outer(P: np.ndarray, D: np.ndarray, block: int = FOLD_BLOCK) -> None:
    """P ← P − D Dᵀ in place for a symmetric (n, n) P and D (n, k), exactly symmetric.

    By row blocks of the lower triangle: each off-diagonal product block is subtracted from
    the block below the diagonal and, transposed, from its mirror above, so both get the
    same numbers; the diagonal blocks are ``D_b @ D_b.T``, which numpy computes with syrk
    (exactly symmetric). One read and one write of P, n²k multiply-adds.
    """
    n = P.shape[0]
    # one scratch for the product blocks: fresh multi-megabyte temporaries per block would
    # each be mapped and page-faulted anew
    scratch = np.empty(min(block, n) * n)
    for i0 in range(0, n, block):
        i1 = min(i0 + block, n)
        Db = D[i0:i1]
        if i0:
            T = scratch[: (i1 - i0) * i0].reshape(i1 - i0, i0)
            np.matmul(Db, D[:i0].T, out=T)
            P[i0:i1, :i0] -= T
            P[:i0, i0:i1] -= T.T
        P[i0:i1, i0:i1] -= Db @ Db.T
