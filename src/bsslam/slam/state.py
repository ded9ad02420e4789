"""The joint EKF state: robot pose plus the control points of every map spline.

Layout: ``x[0:3]`` is the pose (x m, y m, φ rad); every other entry is one coordinate of one
control point. A spline does not own a contiguous slice: it owns two index arrays
(``idx_x``, ``idx_y``) into the state. That is what makes extension cheap: new control
points are appended at the end of the state whatever end of the curve they extend, and
only the spline's index arrays record the curve order.

Storage grows with amortised capacity (doubling), so adding a feature costs the copy of the
new rows and columns only, not a reallocation of ``P``.

The EKF update ``P ← P − Z Zᵀ`` (Z = P[:, cols] W, rank k ≈ 10–90 per scan) is deferred,
and stored compressed. The state keeps a base matrix, a basis B (n, a) and a small PSD
matrix G (a, a) with ``P = base − B G Bᵀ``. When an update touches the state index j for
the first time since the last fold, the column ``base[:, j]`` joins the basis; then
``P[:, cols] = B C`` for a small coefficient matrix C, so the update only adds
``(C W)(C W)ᵀ`` to G. Successive scans see mostly the same walls, so the basis grows by far
less than the rank of each update (this is the compressed filter of Guivant and Nebot, with
the active set found on the fly). The pending term is folded into the base (the one O(n²·a)
pass, where the arithmetic of the whole O(n²) update now happens) only when the basis is
full. Everything the filter reads per scan (rows, columns, blocks of P, the pose
covariance) is served exactly as base − B G Bᵀ on those entries.

A basis column stays equal to its base column under the row operations the filter applies
to both (prediction on the pose rows, an extension's T, new entries that are linear in old
ones, removal). Operations that change a base column otherwise (the prediction's Q on the
pose, an extension's T on its own columns, new entries with a given cross covariance) only
unregister it: it joins the basis again, as a new column, when it is next updated.
"""

from __future__ import annotations

import numpy as np

from bsslam.errors import FilterError
from bsslam.slam.kernels import take_block

POSE = np.arange(3)

#: Extra columns of the covariance buffer. Capacities double from 64, so without them every
#: row of P would start a power-of-two number of bytes after the previous one, and the rows
#: of the O(n²) update would all compete for the same cache sets: P − W on a 1150 × 1150
#: view of a 2048-wide buffer took 6–7 ms, of a 2056-wide one 2.2–3 ms (one core).
ROW_PAD = 8


#: Basis columns of the pending term before it is folded in. Larger means fewer passes over P
#: but dearer reads (n·a per row read). On intel-rawodom the updates touch 36 state indices
#: on average; with 256 the basis fills after about 17 updates (43 folds in 717 updates,
#: against 255 folds of 128 columns when each update's own rank was stored), and the folds'
#: time went from 9.4 s to 2.7 s (cProfile of the whole run). 128 and 512 were no better
#: within the run-to-run noise of this machine.
MAX_PENDING = 256

#: Rows of P per block when the pending factor is folded in: a block row of the product
#: (b × n doubles) stays in the L2 cache while it is subtracted from P.
FOLD_BLOCK = 128


class JointState:
    """Mean ``x`` (n,) and covariance ``P`` (n, n) with room to grow.

    ``x`` and ``P`` are views of the live part of larger buffers; they are replaced (not
    resized in place) when the buffers grow, so never keep them across an ``append``.
    Reading ``P`` first folds any pending update into it (one O(n²) pass); the per-scan code
    uses :meth:`rows`, :meth:`columns`, :meth:`block` and :attr:`pose_covariance` instead.
    """

    def __init__(self, pose: np.ndarray, pose_covariance: np.ndarray, capacity: int = 64,
                 max_pending: int = MAX_PENDING):
        capacity = max(int(capacity), 3)
        self._x = np.zeros(capacity)
        self._P = np.zeros((capacity, capacity + ROW_PAD))
        self._B = np.zeros((capacity, max_pending))   # basis of the pending term, first a columns live
        self._G = np.zeros((max_pending, max_pending))
        self._a = 0
        self._reg = np.full(capacity, -1, dtype=np.intp)   # basis column equal to base[:, j], or −1
        # rows B[j] G of the pending term, kept until G or B change: a scan reads them for
        # the pose several times, and for the update's columns twice (the gain's P[cols, rows],
        # then the update itself); each costs a² multiply-adds
        self._bg = np.empty((64, max_pending))
        self._bg_index = np.empty(64, dtype=np.intp)   # the state index of each kept row
        self._bg_slot = np.full(capacity, -1, dtype=np.intp)   # row of _bg holding index j, or −1
        self._bg_count = 0
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
        """(n, n) the covariance less the pending term B G Bᵀ (a view). Only for code that
        transforms rows and columns of P and then calls :meth:`transform_pending`."""
        return self._P[: self.size, : self.size]

    @property
    def pending_rank(self) -> int:
        """Columns of the pending term's basis (0 when nothing is pending)."""
        return self._a

    @property
    def capacity(self) -> int:
        return self._x.shape[0]

    @property
    def pose(self) -> np.ndarray:
        return self._x[:3]

    @property
    def pose_covariance(self) -> np.ndarray:
        """(3, 3) covariance of the pose (a new array)."""
        return self.block(POSE, POSE)

    def _pending_rows(self, rows: np.ndarray) -> np.ndarray:
        """(r, a) B[rows] G: the pending term's rows are this times Bᵀ (a new array)."""
        rows = np.asarray(rows, dtype=np.intp)
        slot = self._bg_slot[rows]
        missing = rows[slot < 0]
        if missing.size:
            new = np.unique(missing)
            start, end = self._bg_count, self._bg_count + new.shape[0]
            if end > self._bg.shape[0]:
                grown = max(2 * self._bg.shape[0], end)
                self._bg = np.concatenate([self._bg[:start], np.empty((grown - start, self._bg.shape[1]))])
                self._bg_index = np.concatenate([self._bg_index[:start], np.empty(grown - start, dtype=np.intp)])
            a = self._a
            self._bg[start:end, :a] = self._B[new, :a] @ self._G[:a, :a]
            self._bg_index[start:end] = new
            self._bg_slot[new] = np.arange(start, end)
            self._bg_count = end
            slot = self._bg_slot[rows]
        return self._bg[slot, : self._a]

    def _forget_pending_rows(self) -> None:
        """G or B changed: the kept rows B[j] G are stale."""
        self._bg_slot[self._bg_index[: self._bg_count]] = -1
        self._bg_count = 0

    def _widen(self, a: int) -> None:
        """The basis grows to ``a`` columns (new columns of B written by the caller). G is
        zero outside its live block, so the kept rows B[j] G only gain zero entries."""
        self._bg[: self._bg_count, self._a : a] = 0.0
        self._a = a

    def rows(self, rows: np.ndarray) -> np.ndarray:
        """(r, n) ``P[rows, :]`` (a new, C-ordered array)."""
        out = self.base[rows]
        if self._a:
            out -= self._pending_rows(rows) @ self._B[: self.size, : self._a].T
        return out

    def columns(self, cols: np.ndarray) -> np.ndarray:
        """(n, c) ``P[:, cols]`` (a new array, Fortran-ordered). P is kept exactly symmetric,
        so its columns are gathered as rows: c contiguous runs of memory instead of n·c
        scattered entries (5–8× faster at n = 2000)."""
        return self.rows(cols).T

    def columns_times(self, cols: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(n,) ``P[:, cols] v`` for (c,) ``v``, without gathering ``P[:, cols]``: n·(c + a)
        multiply-adds instead of n·c·a."""
        out = v @ self.base[cols]          # base is symmetric: its rows are its columns
        if self._a:
            a = self._a
            out -= self._B[: self.size, :a] @ (self._pending_rows(cols).T @ v)
        return out

    def block(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(r, c) ``P[np.ix_(rows, cols)]`` (a new array); indices of the live state."""
        out = take_block(self.base, np.asarray(rows, dtype=np.intp), np.asarray(cols, dtype=np.intp))
        if self._a:
            out -= self._pending_rows(rows) @ self._B[cols, : self._a].T
        return out

    def diagonal(self, rows: np.ndarray) -> np.ndarray:
        """(r,) ``P[rows, rows]`` (a new array)."""
        out = self.base[rows, rows]
        if self._a:
            out -= np.einsum("ij,ij->i", self._pending_rows(rows), self._B[rows, : self._a])
        return out

    # -- the update ----------------------------------------------------------------------
    def subtract_column_update(self, cols: np.ndarray, W: np.ndarray) -> None:
        """P ← P − Z Zᵀ with Z = P[:, cols] W, for cols (c,) and W (c, k): the EKF update
        (W = Hᵀ L⁻ᵀ), deferred and compressed (see the module docstring).

        Costs O(a²·(c + k)) when the touched columns are in the basis, plus n·c copied for
        each column that joins it; the O(n²·a) fold happens when the basis is full."""
        cols = np.asarray(cols, dtype=np.intp)
        W = np.asarray(W, dtype=float)
        if W.shape[0] != cols.shape[0]:
            raise FilterError(f"column update: {cols.shape[0]} columns but W has {W.shape[0]} rows")
        joining = np.unique(cols[self._reg[cols] < 0])
        # a basis as wide as the state saves nothing: its fold is as cheap as an update
        if self._a + joining.shape[0] > min(self._B.shape[1], self.size):
            self.fold()
            joining = np.unique(cols)
        if joining.shape[0] > self._B.shape[1]:   # wider than the whole basis: straight into the base
            _subtract_outer(self.base, self.columns(cols) @ W)
            return
        a0, a = self._a, self._a + joining.shape[0]
        n = self.size
        self._B[:n, a0:a] = self.base[joining].T    # base is symmetric: its rows are its columns
        self._reg[joining] = np.arange(a0, a)
        self._widen(a)
        # P[:, cols] = base[:, cols] − B G B[cols]ᵀ = B C: base[:, cols] is a basis column
        C = -self._pending_rows(cols).T
        C[self._reg[cols], np.arange(cols.shape[0])] += 1.0
        E = C @ W
        self._G[:a, :a] += E @ E.T
        self._forget_pending_rows()

    def fold(self) -> None:
        """Fold the pending update into the base: base ← base − B G Bᵀ, basis emptied."""
        a, n = self._a, self.size
        if a:
            B = self._B[:n, :a]
            _subtract_outer(self.base, B @ self._G[:a, :a], B)
            self._G[:a, :a] = 0.0
            self._reg[:n] = -1
            self._a = 0
            self._forget_pending_rows()

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
        """Carry A P Aᵀ (A as in :meth:`transform`) through the pending term, B[idx] ← T B[idx],
        for code that has transformed the rows and columns ``idx`` of :attr:`base` itself
        (and possibly added to them, as the prediction adds Q): those base columns leave
        the basis."""
        if self._a:
            B = self._B[:, : self._a]
            B[idx] = T @ B[idx]
        self._reg[idx] = -1
        self._forget_pending_rows()

    # -- growth --------------------------------------------------------------------------
    def _reserve(self, new_size: int) -> None:
        if new_size <= self.capacity:
            return
        capacity = self.capacity
        while capacity < new_size:
            capacity *= 2
        n = self.size
        x = np.zeros(capacity)
        P = np.zeros((capacity, capacity + ROW_PAD))
        B = np.zeros((capacity, self._B.shape[1]))
        reg = np.full(capacity, -1, dtype=np.intp)
        x[:n] = self.x
        P[:n, :n] = self.base
        B[:n, : self._a] = self._B[:n, : self._a]
        reg[:n] = self._reg[:n]
        self._forget_pending_rows()
        self._x, self._P, self._B, self._reg = x, P, B, reg
        self._bg_slot = np.full(capacity, -1, dtype=np.intp)

    def append(self, mean: np.ndarray, cross: np.ndarray, block: np.ndarray) -> np.ndarray:
        """Augment the state with k new entries of given covariance.

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
        # P = base − B G Bᵀ with zero rows of B for the new entries: the base holds them
        # exactly, and no base column is a basis column any more (its new rows are not B's)
        self._P[n : n + k, :n] = cross
        self._P[:n, n : n + k] = cross.T
        self._P[n : n + k, n : n + k] = 0.5 * (block + block.T)
        self._B[n : n + k, : self._a] = 0.0
        self._reg[: n + k] = -1
        self.size = n + k
        return np.arange(n, n + k)

    def append_dependent(self, mean: np.ndarray, cols: np.ndarray, J: np.ndarray,
                         noise: np.ndarray) -> np.ndarray:
        """Augment the state with k entries v = J x[cols] + w, w independent of the state
        with covariance ``noise``: Cov(v, x) = J P[cols, :], Cov(v) = J P_cc Jᵀ + noise.

        Both parts of P = base − B G Bᵀ get the new rows by the same map (base rows J base[cols],
        basis rows J B[cols]), so the pending term carries over and the basis stays valid.

        Args:
            mean: (k,) their values; cols: (c,) state indices; J: (k, c); noise: (k, k).
        Returns:
            (k,) the new state indices.
        """
        mean = np.asarray(mean, dtype=float).reshape(-1)
        cols = np.asarray(cols, dtype=np.intp)
        k, n = mean.shape[0], self.size
        if J.shape != (k, cols.shape[0]) or noise.shape != (k, k):
            raise FilterError(f"append: J {J.shape} / noise {noise.shape} do not fit k={k}, c={cols.shape[0]}")
        self._reserve(n + k)
        self._x[n : n + k] = mean
        cross = J @ self.base[cols]                        # (k, n) rows: base is symmetric
        block = cross[:, cols] @ J.T + noise
        self._P[n : n + k, :n] = cross
        self._P[:n, n : n + k] = cross.T
        self._P[n : n + k, n : n + k] = 0.5 * (block + block.T)
        if self._a:
            self._B[n : n + k, : self._a] = J @ self._B[cols, : self._a]
        self._reg[n : n + k] = -1
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
            self._B[first:m, : self._a] = self._B[tail, : self._a]
            self._reg[first:m] = self._reg[tail]
        self._reg[m:n] = -1
        self._forget_pending_rows()
        self.size = m
        mapping = np.full(n, -1)
        mapping[kept] = np.arange(m)
        return mapping


def _subtract_outer(P: np.ndarray, D: np.ndarray, E: np.ndarray | None = None, block: int = FOLD_BLOCK) -> None:
    """P ← P − D Eᵀ in place (E = D by default) for a symmetric (n, n) P and (n, k) D, E
    whose product is symmetric in exact arithmetic; the result is exactly symmetric.

    By row blocks of the lower triangle: each off-diagonal product block is subtracted from
    the block below the diagonal and, transposed, from its mirror above, so both get the
    same numbers; the diagonal blocks are symmetrised (with E = D, ``D_b @ D_b.T`` is
    computed by syrk and exactly symmetric already). One read and one write of P, n²k/2
    multiply-adds.
    """
    if E is None:
        E = D
    n = P.shape[0]
    # one scratch for the product blocks: fresh multi-megabyte temporaries per block would
    # each be mapped and page-faulted anew
    scratch = np.empty(min(block, n) * n)
    for i0 in range(0, n, block):
        i1 = min(i0 + block, n)
        Db = D[i0:i1]
        if i0:
            T = scratch[: (i1 - i0) * i0].reshape(i1 - i0, i0)
            np.matmul(Db, E[:i0].T, out=T)
            P[i0:i1, :i0] -= T
            P[:i0, i0:i1] -= T.T
        diag = Db @ E[i0:i1].T
        if E is not D:
            diag = 0.5 * (diag + diag.T)
        P[i0:i1, i0:i1] -= diag
