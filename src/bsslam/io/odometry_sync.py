"""Pairing scans with odometry interpolated at the scan stamps, in one streaming pass.

Scans and odometry arrive interleaved; a scan can only be paired once odometry at or after
its stamp has arrived, so scans wait in a short queue. Only a bounded window of odometry
is kept, so memory stays small however long the log is.
"""

from __future__ import annotations

import bisect
from collections import deque
from typing import Any, Iterator

import numpy as np

from bsslam.trajectory import wrap_angle

BEFORE_FIRST = "scan before the first odometry"
AFTER_LAST = "scan after the last odometry"
TOO_OLD = "scan older than the kept odometry window"


def interpolate_pose(t: float, t0: float, pose0: np.ndarray, t1: float, pose1: np.ndarray) -> np.ndarray:
    """Pose (3,) at time ``t`` between (t0, pose0) and (t1, pose1): linear in x, y and in the
    heading along the shorter way round; heading wrapped to (−π, π]."""
    if t1 == t0:
        return np.array(pose1, dtype=float)
    a = (t - t0) / (t1 - t0)
    delta = np.asarray(pose1, dtype=float) - pose0
    delta[2] = wrap_angle(delta[2])
    pose = pose0 + a * delta
    pose[2] = wrap_angle(pose[2])
    return pose


class OdometrySync:
    """Queue of scans waiting for odometry.

    Usage: ``add_odometry``/``add_scan`` in stream order (odometry stamps increasing,
    scan stamps increasing), then drain ``ready()`` after each call and ``ready(final=True)``
    at the end of the stream.

    Args:
        window: odometry samples kept for interpolation; a scan older than all of them is
            released unpaired.
    """

    def __init__(self, window: int = 2000):
        self._window = window
        self._stamps: list[float] = []
        self._poses: list[np.ndarray] = []
        self._trimmed = False
        self._pending: deque[tuple[float, Any]] = deque()

    @property
    def last_odometry_stamp(self) -> float | None:
        return self._stamps[-1] if self._stamps else None

    def add_odometry(self, stamp: float, pose: np.ndarray) -> None:
        """Append an odometry pose (3,) (x m, y m, φ rad); ``stamp`` must exceed the last one."""
        self._stamps.append(float(stamp))
        self._poses.append(np.asarray(pose, dtype=float))
        if len(self._stamps) > 2 * self._window:
            # trim in halves: amortised O(1) per sample instead of a shift per sample
            del self._stamps[: self._window]
            del self._poses[: self._window]
            self._trimmed = True

    def add_scan(self, stamp: float, item: Any) -> None:
        """Queue ``item`` (anything) taken at ``stamp`` (s)."""
        self._pending.append((float(stamp), item))

    def ready(self, final: bool = False) -> Iterator[tuple[Any, np.ndarray | None, str | None]]:
        """Release queued scans that can be decided now, in queue order.

        Yields:
            (item, odometry pose (3,), None) for a paired scan, or (item, None, reason) for
            one that cannot be paired (before the first / after the last odometry, or older
            than the kept window). With ``final=True`` every queued scan is released.
        """
        stamps = self._stamps
        while self._pending:
            t, item = self._pending[0]
            if not stamps or t > stamps[-1]:
                if not final:
                    return  # later odometry may still bracket this scan
                self._pending.popleft()
                yield item, None, (BEFORE_FIRST if not stamps else AFTER_LAST)
                continue
            self._pending.popleft()
            if t < stamps[0]:
                yield item, None, (TOO_OLD if self._trimmed else BEFORE_FIRST)
                continue
            j = bisect.bisect_left(stamps, t)
            if stamps[j] == t:
                yield item, self._poses[j].copy(), None
            else:
                yield item, interpolate_pose(t, stamps[j - 1], self._poses[j - 1], stamps[j], self._poses[j]), None
