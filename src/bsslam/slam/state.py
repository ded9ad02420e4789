"""The joint EKF state: robot pose plus the control points of every map spline.

Layout: ``x[0:3]`` is the pose (x m, y m, φ rad); every other entry is one coordinate of one
control point. A spline does not own a contiguous slice: it owns two index arrays
(``idx_x``, ``idx_y``) into the state. That is what makes extension cheap: new control
points are appended at the end of the state whatever end of the curve they extend, and
only the spline's index arrays record the curve order.

Storage grows with amortised capacity (doubling), so adding a feature costs the copy of the
new rows and columns only, not a reallocation of ``P``.
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


class JointState:
    """Mean ``x`` (n,) and covariance ``P`` (n, n) with room to grow.

    ``x`` and ``P`` are views of the live part of larger buffers; they are replaced (not
    resized in place) when the buffers grow, so never keep them across an ``append``.
    """

    def __init__(self, pose: np.ndarray, pose_covariance: np.ndarray, capacity: int = 64):
        capacity = max(int(capacity), 3)
        self._x = np.zeros(capacity)
        self._P = np.zeros((capacity, capacity + ROW_PAD))
        self.size = 3
        self._x[:3] = np.asarray(pose, dtype=float)
        self._P[:3, :3] = np.asarray(pose_covariance, dtype=float)

    # -- views ---------------------------------------------------------------------------
    @property
    def x(self) -> np.ndarray:
        """(n,) live mean (a view)."""
        return self._x[: self.size]

    @property
    def P(self) -> np.ndarray:
        """(n, n) live covariance (a view)."""
        return self._P[: self.size, : self.size]

    @property
    def capacity(self) -> int:
        return self._x.shape[0]

    @property
    def pose(self) -> np.ndarray:
        return self._x[:3]

    # -- growth --------------------------------------------------------------------------
    def _reserve(self, new_size: int) -> None:
        if new_size <= self.capacity:
            return
        capacity = self.capacity
        while capacity < new_size:
            capacity *= 2
        x = np.zeros(capacity)
        P = np.zeros((capacity, capacity + ROW_PAD))
        x[: self.size] = self.x
        P[: self.size, : self.size] = self.P
        self._x, self._P = x, P

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
        self._P[n : n + k, :n] = cross
        self._P[:n, n : n + k] = cross.T
        self._P[n : n + k, n : n + k] = 0.5 * (block + block.T)
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
        self.size = m
        mapping = np.full(n, -1)
        mapping[kept] = np.arange(m)
        return mapping

    def symmetrize(self) -> None:
        P = self.P
        P += P.T
        P *= 0.5
