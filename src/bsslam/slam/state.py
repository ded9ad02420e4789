"""The joint EKF state: robot pose plus the control points of every map spline.

Layout: ``x[0:3]`` is the pose (x m, y m, φ rad); every other entry is one coordinate of one
control point. A spline does not own a contiguous slice: it owns two index arrays
(``idx_x``, ``idx_y``) into the state. That is what makes extension cheap: new control
points are appended at the end of the state whatever end of the curve they extend, and
only the spline's index arrays record the curve order.

Storage grows with amortised capacity (doubling), so adding a feature costs the copy of the
new rows and columns only, not a reallocation of ``P``.

The EKF update ``P ← P − Z Zᵀ`` (Z = P[:, cols] W, rank k ≈ 10–90 per scan) is deferred,
and stored compressed (the compressed filter of Guivant and Nebot, with the active set
found on the fly). The entries are of two kinds:

* **eager** entries, the pose and the entries appended since the last fold: their rows of
  P are kept exactly, as a small dense block ``P_EE`` among themselves and, against the
  other entries, as ``P[L, e] = B_L K[:, e]`` with a coefficient matrix K (a, |E|);
* **lazy** entries (L), all others: ``P_LL = base − B G Bᵀ`` with a base matrix, a basis
  B (n, a, zero on eager rows) and a small PSD matrix G (a, a).

When an update touches a lazy index j for the first time since the last fold, the column
``base[L, j]`` joins the basis; then ``P[L, cols] = B_L C`` for a small coefficient matrix C,
so the update changes only G (by (C W)(C W)ᵀ), K and P_EE: no O(n) work. A prediction
changes only the pose's rows of P_EE and its columns of K, and new features enter as
eager entries whose K columns are linear in those of the entries they depend on, so
neither adds to the basis: it grows only by old walls seen again, which after a loop is
a few columns a scan. The pending term is folded into the base (the one O(n²·a) pass,
where the arithmetic of the whole O(n²) update now happens) when the basis or the eager
block is full; then every entry but the pose becomes lazy again. Everything the filter
reads per scan (rows, columns, blocks of P, the pose covariance) is served exactly from
these parts.

A registered basis column stays equal to its base column (on the lazy rows) under the row
operations the filter applies to both (an extension's T on lazy entries, removal).
Operations that change a base column otherwise only unregister it: it joins the basis
again, as a new column, when it is next updated.
"""

from __future__ import annotations

import numpy as np

from bsslam.errors import FilterError, MemoryBudgetError
from bsslam.slam.kernels import take_block

POSE = np.arange(3)

#: Extra columns of the covariance buffer. Capacities double from 64, so without them every
#: row of P would start a power-of-two number of bytes after the previous one, and the rows
#: of the O(n²) update would all compete for the same cache sets: P − W on a 1150 × 1150
#: view of a 2048-wide buffer took 6–7 ms, of a 2056-wide one 2.2–3 ms (one core).
ROW_PAD = 8

#: Basis columns of the pending term before it is folded in. Larger means fewer passes over P
#: but dearer reads (a² per row read, n·a per column). The fold's arithmetic (n²·a) is paid
#: per column of the basis however often it happens, so a fold costs beyond it only its
#: pass over P; 128 against 256 took the simulated corridor's scans at 1000–2000 dimensions
#: from a median of 3.5 to 3.1 ms and a mean of 4.0–4.7 to 3.5–3.8 ms (one core, the same
#: run; ``benchmarks/bench_filter.py --defaults``), and intel-rawodom's run 4–6 % sooner.
MAX_PENDING = 128

#: Eager entries (the pose and the entries appended since the last fold) before a fold.
#: Each update costs about |E|²·k for their block and a·|E|·k for their coefficients.
MAX_EAGER = 128

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
                 max_pending: int = MAX_PENDING, max_eager: int = MAX_EAGER):
        capacity = max(int(capacity), 3)
        if max_pending < 3 or max_eager < 3:
            raise FilterError("the pending basis and the eager block need room for the pose (≥ 3)")
        self._x = np.zeros(capacity)
        self._P = np.zeros((capacity, capacity + ROW_PAD))
        self._B = np.zeros((capacity, max_pending))   # basis of the pending term, first a columns live
        self._G = np.zeros((max_pending, max_pending))
        self._a = 0
        self._reg = np.full(capacity, -1, dtype=np.intp)   # basis column equal to base[L, j], or −1
        self._E = np.zeros(max_eager, dtype=np.intp)       # state index of each eager entry
        self._epos = np.full(capacity, -1, dtype=np.intp)  # place of entry j among the eager, or −1
        self._PE = np.zeros((max_eager, max_eager))        # P among the eager entries
        self._K = np.zeros((max_pending, max_eager))       # P[L, E] = B_L K
        self._e = 0
        # rows B[j] G of the pending term, kept until G or B change: a scan reads them for
        # the update's columns twice (the gain's P[cols, rows], then the update itself);
        # each costs a² multiply-adds
        self._bg = np.empty((64, max_pending))
        self._bg_index = np.empty(64, dtype=np.intp)   # the state index of each kept row
        self._bg_slot = np.full(capacity, -1, dtype=np.intp)   # row of _bg holding index j, or −1
        self._bg_count = 0
        self.size = 3
        self.max_bytes: int | None = None   # growth beyond this raises MemoryBudgetError
        self._x[:3] = np.asarray(pose, dtype=float)
        C = np.asarray(pose_covariance, dtype=float)
        self._P[:3, :3] = 0.5 * (C + C.T)   # exactly symmetric: rows are served as columns
        self._reset()

    # -- pickling ------------------------------------------------------------------------
    def __getstate__(self) -> dict:
        """Only the live part of each buffer (a checkpoint of a run must not carry the
        capacity's slack: the covariance buffer is up to 4× its live block)."""
        n, a, e, m = self.size, self._a, self._e, self._bg_count
        state = {k: v for k, v in self.__dict__.items() if not isinstance(v, np.ndarray)}
        state["_shapes"] = {k: (v.shape, v.dtype.str) for k, v in self.__dict__.items() if isinstance(v, np.ndarray)}
        state["_live"] = {
            "_x": self._x[:n].copy(), "_P": self._P[:n, :n].copy(), "_B": self._B[:n, :a].copy(),
            "_G": self._G[:a, :a].copy(), "_reg": self._reg[:n].copy(), "_E": self._E[:e].copy(),
            "_epos": self._epos[:n].copy(), "_PE": self._PE[:e, :e].copy(), "_K": self._K[:a, :e].copy(),
            "_bg": self._bg[:m, :a].copy(), "_bg_index": self._bg_index[:m].copy(),
            "_bg_slot": self._bg_slot.copy(),
        }
        return state

    def __setstate__(self, state: dict) -> None:
        """The buffers at their capacity again (same shapes, so the same strides and the
        same arithmetic), the live parts copied in; the rest is never read before it is
        written (−1 for the index maps, zeros elsewhere: G and K are zero outside their
        live blocks anyway)."""
        state = dict(state)
        shapes, live = state.pop("_shapes"), state.pop("_live")
        self.__dict__.update(state)
        for name, (shape, dtype) in shapes.items():
            fill = -1 if name in ("_reg", "_epos", "_bg_slot") else 0
            buffer = np.full(shape, fill, dtype=np.dtype(dtype))
            part = live[name]
            buffer[tuple(slice(0, k) for k in part.shape)] = part
            setattr(self, name, buffer)

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
        """(n, n) the base of the lazy entries' covariance (a view; see the module docstring).
        Only exact after :meth:`fold`."""
        return self._P[: self.size, : self.size]

    @property
    def pending_rank(self) -> int:
        """Columns of the pending term's basis (3, the pose's, right after a fold)."""
        return self._a

    @property
    def eager_count(self) -> int:
        """Entries whose rows of P are kept exactly (the pose and the newest entries)."""
        return self._e

    @property
    def capacity(self) -> int:
        return self._x.shape[0]

    @property
    def nbytes(self) -> int:
        """Bytes of the state's buffers (the covariance's dominate: 8 capacity² bytes)."""
        return sum(a.nbytes for a in (self._x, self._P, self._B, self._G, self._reg, self._E, self._epos,
                                      self._PE, self._K, self._bg, self._bg_index, self._bg_slot))

    @property
    def pose(self) -> np.ndarray:
        return self._x[:3]

    @property
    def pose_covariance(self) -> np.ndarray:
        """(3, 3) covariance of the pose (a new array)."""
        return self._PE[:3, :3].copy()

    # -- the parts of P -------------------------------------------------------------------
    def _reset(self) -> None:
        """The pending term is empty and the base exact: only the pose stays eager, with the
        base's pose columns as the first three basis columns (P[L, pose] = B_L I)."""
        n, a, e = self.size, self._a, self._e
        self._G[:a, :a] = 0.0
        self._K[:a, :e] = 0.0
        self._reg[:n] = -1
        self._epos[:n] = -1
        self._E[:3] = POSE
        self._epos[:3] = POSE
        self._e = 3
        self._PE[:3, :3] = self._P[:3, :3]
        self._B[:n, :3] = self._P[:3, :n].T     # base is symmetric: its pose rows are its pose columns
        self._B[:3, :3] = 0.0                   # eager rows of the basis are zero
        self._K[:3, :3] = np.eye(3)
        self._a = 3
        self._pending = False   # base is P: a fold would change nothing
        self._forget_pending_rows()

    def _pending_rows(self, rows: np.ndarray, keep: bool = True) -> np.ndarray:
        """(r, a) B[rows] G: the pending term's rows are this times Bᵀ (a new array). The
        rows are kept for later calls, unless ``keep`` is False: a read outside the filter's
        own steps must leave no trace, since a row's rounding depends on the rows computed
        with it."""
        rows = np.asarray(rows, dtype=np.intp)
        slot = self._bg_slot[rows]
        missing = rows[slot < 0]
        if missing.size and not keep:
            out = np.empty((rows.shape[0], self._a))
            held = slot >= 0
            out[held] = self._bg[slot[held], : self._a]
            out[~held] = self._B[missing, : self._a] @ self._G[: self._a, : self._a]
            return out
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

    def _join(self, cols: np.ndarray) -> bool:
        """Register the lazy, unregistered ``cols`` as basis columns, folding first when the
        basis has no room. Returns False (nothing registered) when they are more than a
        whole basis: the caller then works on the folded base."""
        lazy = cols[self._epos[cols] < 0]
        joining = np.unique(lazy[self._reg[lazy] < 0])
        # a basis as wide as the state saves nothing: its fold is as cheap as an update
        if self._a + joining.shape[0] > min(self._B.shape[1], self.size):
            self.fold()
            joining = np.unique(cols[self._epos[cols] < 0])   # all lazy and unregistered now, but the pose
            if self._a + joining.shape[0] > self._B.shape[1]:
                return False
        if joining.shape[0]:
            a0, a = self._a, self._a + joining.shape[0]
            n, e = self.size, self._e
            B = self._B[:n, a0:a]
            B[:] = self._P[joining, :n].T    # base is symmetric: its rows are its columns
            B[self._E[:e]] = 0.0              # eager rows of the basis are zero
            self._reg[joining] = np.arange(a0, a)
            self._K[a0:a, :e] = 0.0
            # G is zero outside its live block, so the kept rows B[j] G only gain zero entries
            self._bg[: self._bg_count, a0:a] = 0.0
            self._a = a
        return True

    def _coefficients(self, cols: np.ndarray) -> np.ndarray:
        """(a, c) C with P[L, cols] = B_L C, for registered lazy or eager ``cols``."""
        pos = self._epos[cols]
        eager = pos >= 0
        a = self._a
        C = np.empty((a, cols.shape[0]))
        if eager.any():
            C[:, eager] = self._K[:a, pos[eager]]
        lazy = ~eager
        if lazy.any():
            lc = cols[lazy]
            # P[L, j] = base[L, j] − B_L G B[j]ᵀ, base[L, j] a basis column
            Cl = -self._pending_rows(lc).T
            Cl[self._reg[lc], np.arange(lc.shape[0])] += 1.0
            C[:, lazy] = Cl
        return C

    def _eager_rows(self, cols: np.ndarray) -> np.ndarray:
        """(|E|, c) P[E, cols] (a new array)."""
        pos = self._epos[cols]
        eager = pos >= 0
        e, a = self._e, self._a
        out = np.empty((e, cols.shape[0]))
        if eager.any():
            out[:, eager] = self._PE[:e, pos[eager]]
        lazy = ~eager
        if lazy.any():
            out[:, lazy] = (self._B[cols[lazy], :a] @ self._K[:a, :e]).T
        return out

    # -- reads ---------------------------------------------------------------------------
    def rows(self, rows: np.ndarray) -> np.ndarray:
        """(r, n) ``P[rows, :]`` (a new, C-ordered array)."""
        return self.block(rows, np.arange(self.size))

    def columns(self, cols: np.ndarray) -> np.ndarray:
        """(n, c) ``P[:, cols]`` (a new array, Fortran-ordered). P is kept exactly symmetric,
        so its columns are gathered as rows: c contiguous runs of memory instead of n·c
        scattered entries (5–8× faster at n = 2000)."""
        return self.rows(cols).T

    def columns_times(self, cols: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(n,) ``P[:, cols] v`` for (c,) ``v``, without gathering ``P[:, cols]``: n·(c + a)
        multiply-adds instead of n·c·a."""
        cols = np.asarray(cols, dtype=np.intp)
        pos = self._epos[cols]
        eager = pos >= 0
        lazy = ~eager
        n, a, e = self.size, self._a, self._e
        lc, vl = cols[lazy], v[lazy]
        out = vl @ self._P[lc, :n]               # base is symmetric: its rows are its columns
        # the lazy rows: − B G B[lc]ᵀ v_L + B K[:, eager cols] v_E (zero on the eager rows)
        u = self._K[:a, pos[eager]] @ v[eager]
        if lc.shape[0]:
            u -= self._pending_rows(lc).T @ vl
        out += self._B[:n, :a] @ u
        # the eager rows, exactly
        out[self._E[:e]] = self._K[:a, :e].T @ (self._B[lc, :a].T @ vl) + self._PE[:e, pos[eager]] @ v[eager]
        return out

    def block(self, rows: np.ndarray, cols: np.ndarray, keep: bool = True) -> np.ndarray:
        """(r, c) ``P[np.ix_(rows, cols)]`` (a new array); indices of the live state. With
        ``keep`` False a pure read (see :meth:`_pending_rows`)."""
        rows = np.asarray(rows, dtype=np.intp)
        cols = np.asarray(cols, dtype=np.intp)
        pr, pc = self._epos[rows], self._epos[cols]
        er, ec = pr >= 0, pc >= 0
        a = self._a
        if er.all():     # the pose's rows, say: no base, no G
            out = (self._B[cols, :a] @ self._K[:a, pr]).T
        else:
            out = take_block(self._P, rows, cols)
            out -= self._pending_rows(rows, keep) @ self._B[cols, :a].T
            if ec.any():
                out[:, ec] = self._B[rows, :a] @ self._K[:a, pc[ec]]
            if er.any():
                out[er] = (self._B[cols, :a] @ self._K[:a, pr[er]]).T
        if ec.any() and er.any():
            ri, ci = np.flatnonzero(er), np.flatnonzero(ec)
            out[np.ix_(ri, ci)] = take_block(self._PE, pr[ri], pc[ci])
        return np.ascontiguousarray(out)

    def diagonal(self, rows: np.ndarray) -> np.ndarray:
        """(r,) ``P[rows, rows]`` (a new array)."""
        rows = np.asarray(rows, dtype=np.intp)
        out = self._P[rows, rows]
        out -= np.einsum("ij,ij->i", self._pending_rows(rows), self._B[rows, : self._a])
        pos = self._epos[rows]
        eager = pos >= 0
        if eager.any():
            out[eager] = self._PE[pos[eager], pos[eager]]
        return out

    # -- the update ----------------------------------------------------------------------
    def subtract_column_update(self, cols: np.ndarray, W: np.ndarray) -> None:
        """P ← P − Z Zᵀ with Z = P[:, cols] W, for cols (c,) and W (c, k): the EKF update
        (W = Hᵀ L⁻ᵀ), deferred and compressed (see the module docstring).

        Costs O(a²·k + a·|E|·k + |E|²·k) when the touched lazy columns are in the basis,
        plus n·c copied for each column that joins it; the O(n²·a) fold happens when the
        basis is full."""
        cols = np.asarray(cols, dtype=np.intp)
        W = np.asarray(W, dtype=float)
        if W.shape[0] != cols.shape[0]:
            raise FilterError(f"column update: {cols.shape[0]} columns but W has {W.shape[0]} rows")
        if not self._join(cols):   # wider than the whole basis: straight into the folded base
            _subtract_outer(self.base, self.columns(cols) @ W)
            self._reset()
            return
        a, e = self._a, self._e
        Ec = self._coefficients(cols) @ W        # Z_L = B_L Ec
        Ze = self._eager_rows(cols) @ W          # Z_E, exactly
        self._G[:a, :a] += Ec @ Ec.T
        self._K[:a, :e] -= Ec @ Ze.T
        self._PE[:e, :e] -= Ze @ Ze.T
        self._pending = True
        self._forget_pending_rows()

    def fold(self) -> None:
        """Fold the pending update into the base: base ← P, basis emptied, every entry
        but the pose lazy again."""
        if not self._pending:
            return
        n, a, e = self.size, self._a, self._e
        eager = self._E[:e].copy()
        R = self.block(eager, np.arange(n))      # the eager rows, exactly
        B = self._B[:n, :a]
        _subtract_outer(self.base, B @ self._G[:a, :a], B)    # exact on the lazy block
        self._P[eager, :n] = R
        self._P[:n, eager] = R.T
        self._reset()

    def shear(self, w: np.ndarray, k: int) -> None:
        """P ← A P Aᵀ for A = I + w e_kᵀ, w (n,) and k a pose entry (0, 1, 2): the state's
        entries each move by their w times the pose entry k's (the invariant EKF carries its
        covariance to a corrected mean this way). That is P + w aᵀ + a wᵀ + P_kk w wᵀ with
        a = P[:, k], deferred like an update: the lazy rows of a are B_L K[:, k] already,
        so only w's lazy rows join the basis, as one new (unregistered) column whose
        coefficients in G couple it to the basis through K[:, k]; the eager rows go into K
        and the eager block. O(n + a·|E| + |E|²); folds first when the basis has no room."""
        w = np.asarray(w, dtype=float)
        n = self.size
        if w.shape != (n,) or k not in (0, 1, 2):
            raise FilterError(f"shear: w {w.shape} / pose entry {k} do not fit n={n}")
        if self._a + 1 > min(self._B.shape[1], n):
            self.fold()
            if self._a + 1 > min(self._B.shape[1], n):   # no lazy room (n ≤ 3): into the base
                a = self.base[:, k].copy()
                V = np.outer(w, a + 0.5 * a[k] * w)
                self.base[:] += V + V.T
                self._reset()
                return
        a0, e = self._a, self._e
        eager = self._E[:e]
        pk = self._epos[k]
        coeffs = self._K[:a0, pk].copy()        # P[L, k] = B_L coeffs
        a_E = self._PE[:e, pk].copy()           # P[E, k]
        p = self._PE[pk, pk]
        w_E = w[eager]
        self._B[:n, a0] = w
        self._B[eager, a0] = 0.0                # eager rows of the basis are zero
        # − [B u] G' [B u]ᵀ gains B c uᵀ + u cᵀ Bᵀ + p u uᵀ
        self._G[a0, :a0] = -coeffs
        self._G[:a0, a0] = -coeffs
        self._G[a0, a0] = -p
        # P[L, E] gains u (a_E + p w_E)ᵀ + B_L c w_Eᵀ
        self._K[:a0, :e] += np.outer(coeffs, w_E)
        self._K[a0, :e] = a_E + p * w_E
        V = np.outer(w_E, a_E + 0.5 * p * w_E)
        self._PE[:e, :e] += V + V.T
        self._a = a0 + 1
        self._pending = True
        self._forget_pending_rows()

    def transform_pose(self, F: np.ndarray, Q: np.ndarray) -> None:
        """The prediction's P ← A P Aᵀ + Q on the pose, A the identity with F (3, 3) on
        the pose block, Q (3, 3): O(|E| + a), the pose being eager (its places are 0, 1, 2)."""
        self._transform_eager(POSE, F, Q)

    def _transform_eager(self, pos: np.ndarray, T: np.ndarray, Q: np.ndarray | None = None) -> None:
        """P ← A P Aᵀ (+ Q on the block) for eager entries at places ``pos``: their rows of the
        eager block, and their columns of K (P[L, e] = B_L K[:, e] becomes P[L, idx] Tᵀ)."""
        e, a = self._e, self._a
        _congruence(self._PE[:e, :e], pos, T, Q)
        self._K[:a, pos] = self._K[:a, pos] @ T.T
        self._pending = True

    def transform(self, idx: np.ndarray, T: np.ndarray) -> None:
        """x[idx] ← T x[idx] and P ← A P Aᵀ, A the identity with T on the block ``idx``
        (map entries, never the pose).

        Only the rows and columns ``idx`` change; they are written exactly symmetric.
        """
        idx = np.asarray(idx, dtype=np.intp)
        x = self.x
        x[idx] = T @ x[idx]
        if (self._epos[idx] >= 0).any() and not self._promote(idx):
            self.fold()       # no room among the eager: all of idx lazy
        if self._epos[idx[0]] >= 0:     # all of idx, promoted
            self._transform_eager(self._epos[idx], T)
            return
        # lazy entries: the base's rows and columns, and the basis rows (which carry P[idx, E])
        _congruence(self.base, idx, T)
        B = self._B[:, : self._a]
        B[idx] = T @ B[idx]
        self._reg[idx] = -1
        self._forget_pending_rows()

    def _promote(self, idx: np.ndarray) -> bool:
        """Make the lazy ones of ``idx`` eager (their rows of P kept exactly), so that all of
        ``idx`` is; False if there is no room (the basis or the eager block is full)."""
        idx = np.unique(idx)
        if not self._join(idx):
            return False
        idx = idx[self._epos[idx] < 0]    # (all of them if the join folded)
        a, e, m = self._a, self._e, idx.shape[0]
        if e + m > self._PE.shape[0]:
            return False
        if not m:
            return True
        K = self._coefficients(idx)                      # P[L, idx] = B_L K
        cross = self._eager_rows(idx)                    # P[E, idx]
        own = self.block(idx, idx)
        own = 0.5 * (own + own.T)
        pos = np.arange(e, e + m)
        self._PE[:e, pos] = cross
        self._PE[pos, :e] = cross.T
        self._PE[np.ix_(pos, pos)] = own
        self._K[:a, pos] = K
        self._E[pos] = idx
        self._epos[idx] = pos
        self._reg[idx] = -1
        self._B[idx, :] = 0.0
        self._e = e + m
        self._pending = True
        self._forget_pending_rows()
        return True

    # -- growth --------------------------------------------------------------------------
    def _reserve(self, new_size: int) -> None:
        if new_size <= self.capacity:
            return
        capacity = self.capacity
        while capacity < new_size:
            capacity *= 2
        # old and new buffers coexist while copying: check before allocating, so a map too
        # large for the budget is a clear error, never a MemoryError deep in numpy
        grown = 8 * capacity * (capacity + ROW_PAD + self._B.shape[1] + 3)
        if self.max_bytes is not None and self.nbytes + grown > self.max_bytes:
            raise MemoryBudgetError(
                f"the joint covariance would grow to {capacity} × {capacity} ({grown / 2 ** 20:.0f} MB, "
                f"{(self.nbytes + grown) / 2 ** 20:.0f} MB while copying) for a state of {new_size}, beyond "
                f"the budget of {self.max_bytes / 2 ** 20:.0f} MB (max_memory_mb)", self.nbytes + grown)
        n = self.size
        x = np.zeros(capacity)
        P = np.zeros((capacity, capacity + ROW_PAD))
        B = np.zeros((capacity, self._B.shape[1]))
        reg = np.full(capacity, -1, dtype=np.intp)
        epos = np.full(capacity, -1, dtype=np.intp)
        x[:n] = self.x
        P[:n, :n] = self.base
        B[:n, : self._a] = self._B[:n, : self._a]
        reg[:n] = self._reg[:n]
        epos[:n] = self._epos[:n]
        self._forget_pending_rows()
        self._x, self._P, self._B, self._reg, self._epos = x, P, B, reg, epos
        self._bg_slot = np.full(capacity, -1, dtype=np.intp)

    def append(self, mean: np.ndarray, cross: np.ndarray, block: np.ndarray) -> np.ndarray:
        """Augment the state with k new entries of given covariance (folds the pending
        update first: meant for building a state, not for every scan).

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
        self.fold()
        self._reserve(n + k)
        self._x[n : n + k] = mean
        self._P[n : n + k, :n] = cross
        self._P[:n, n : n + k] = cross.T
        self._P[n : n + k, n : n + k] = 0.5 * (block + block.T)
        self.size = n + k
        self._reset()   # the new lazy entries' pose columns join the basis with the others
        return np.arange(n, n + k)

    def append_dependent(self, mean: np.ndarray, cols: np.ndarray, J: np.ndarray,
                         noise: np.ndarray) -> np.ndarray:
        """Augment the state with k entries v = J x[cols] + w, w independent of the state
        with covariance ``noise``: Cov(v, x) = J P[cols, :], Cov(v) = J P_cc Jᵀ + noise.

        They enter as eager entries: P[L, v] = B_L C Jᵀ with P[L, cols] = B_L C, so neither
        the base nor the basis changes (only the lazy ``cols`` not yet in the basis join it).

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
        if self._e + k > self._PE.shape[0]:
            self.fold()
        if self._e + k > self._PE.shape[0] or not self._join(cols):
            # more than the eager block or the basis holds: lazy entries, appended to the base
            cross = J @ self.rows(cols)
            return self.append(mean, cross, cross[:, cols] @ J.T + noise)
        a, e = self._a, self._e
        K = self._coefficients(cols) @ J.T        # (a, k)
        cross = J @ self._eager_rows(cols).T      # (k, |E|)
        own = J @ self.block(cols, cols) @ J.T + noise
        self._reserve(n + k)
        self._x[n : n + k] = mean
        new = np.arange(n, n + k)
        pos = np.arange(e, e + k)
        self._B[new, :] = 0.0
        self._reg[new] = -1
        self._PE[pos, :e] = cross
        self._PE[:e, pos] = cross.T
        self._PE[np.ix_(pos, pos)] = 0.5 * (own + own.T)
        self._K[:a, pos] = K
        self._E[pos] = new
        self._epos[new] = pos
        self._e = e + k
        self.size = n + k
        self._pending = True
        return new

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
        # eager entries leave the eager block
        e = self._e
        stay = keep[self._E[:e]]
        if not stay.all():
            sp = np.flatnonzero(stay)
            self._PE[: sp.size, : sp.size] = self._PE[np.ix_(sp, sp)]
            self._K[: self._a, : sp.size] = self._K[: self._a, sp]
            self._K[: self._a, sp.size : e] = 0.0
            self._E[: sp.size] = self._E[sp]
            self._e = sp.size
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
        mapping = np.full(n, -1)
        mapping[kept] = np.arange(m)
        e = self._e
        self._E[:e] = mapping[self._E[:e]]
        self._epos[:n] = -1
        self._epos[self._E[:e]] = np.arange(e)
        self._forget_pending_rows()
        self.size = m
        return mapping


def _congruence(M: np.ndarray, idx: np.ndarray, T: np.ndarray, Q: np.ndarray | None = None) -> None:
    """M ← A M Aᵀ in place (plus Q on the block ``idx``), for a symmetric (n, n) M and A the
    identity with (k, k) T on the block ``idx``. Only the rows and columns ``idx`` change;
    they are written exactly symmetric (the rows T M once, copied transposed to the
    columns; the block T M Tᵀ symmetrised)."""
    rows = T @ M[idx, :]
    M[idx, :] = rows
    M[:, idx] = rows.T
    block = rows[:, idx] @ T.T
    if Q is not None:
        block = block + Q
    M[np.ix_(idx, idx)] = 0.5 * (block + block.T)


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
