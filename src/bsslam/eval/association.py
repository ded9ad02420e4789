"""Matching two trajectories' poses by timestamp."""

from __future__ import annotations

import numpy as np

from bsslam.trajectory import Trajectory


def nearest_stamps(stamps: np.ndarray, queries: np.ndarray, max_dt: float) -> np.ndarray:
    """For each query time, the index of the nearest of ``stamps`` (s) if it is within
    ``max_dt`` (s), else −1. ``stamps`` need not be sorted. Returns (len(queries),) ints."""
    stamps = np.asarray(stamps, dtype=float)
    queries = np.asarray(queries, dtype=float)
    if stamps.size == 0:
        return np.full(queries.shape, -1, dtype=np.int64)
    order = np.argsort(stamps, kind="stable")
    ordered = stamps[order]
    right = np.clip(np.searchsorted(ordered, queries), 0, len(ordered) - 1)
    left = np.clip(right - 1, 0, len(ordered) - 1)
    use_left = np.abs(ordered[left] - queries) <= np.abs(ordered[right] - queries)
    best = np.where(use_left, left, right)
    found = np.abs(ordered[best] - queries) <= max_dt
    return np.where(found, order[best], -1)


def associate(est: Trajectory, ref: Trajectory, max_dt: float = 0.01,
              offset: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Pair estimate and reference poses by nearest timestamp, one to one.

    Args:
        est, ref: the trajectories.
        max_dt: largest accepted |t_est + offset − t_ref| (s).
        offset: added to the estimate's stamps to put them on the reference clock (s).

    Returns:
        (est_idx, ref_idx), two (M,) int arrays in increasing estimate time; a reference
        pose claimed by several estimate poses goes to the closest one.
    """
    queries = est.stamps + offset
    ref_idx = nearest_stamps(ref.stamps, queries, max_dt)
    est_idx = np.nonzero(ref_idx >= 0)[0]
    ref_idx = ref_idx[est_idx]
    dt = np.abs(ref.stamps[ref_idx] - queries[est_idx])
    # by reference index, then by time difference: the first of each group is the closest
    order = np.lexsort((dt, ref_idx))
    first = np.ones(len(order), dtype=bool)
    first[1:] = ref_idx[order][1:] != ref_idx[order][:-1]
    keep = np.sort(order[first])  # estimate stamps are non-decreasing: index order is time order
    return est_idx[keep], ref_idx[keep]
