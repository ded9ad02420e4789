"""The laser scan type shared by readers, the simulator and the filter."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.errors import InputError


@dataclass(frozen=True)
class LaserScan:
    """One 2D laser scan in the robot frame.

    Attributes:
        stamp: time of the scan (s).
        angles: (n,) beam bearings in the robot frame (rad), increasing.
        ranges: (n,) measured ranges (m); NaN/inf/no-return values are allowed here and
            removed by :func:`bsslam.scan.valid_beams`.
        max_range: the sensor's maximum range (m); ranges ≥ it mean "no return".
        sweep_time_s: time from the first beam to the last (s): the beams were measured one
            after another, in order of increasing bearing (negative: decreasing), over this
            time. 0 (default) for a scan taken at one instant, as the simulator's are and as
            :func:`bsslam.scan.deskew` leaves a scan.

    The constructor checks shapes and finiteness only; the physical limits (beam count,
    increasing bearings, ranges) are :mod:`bsslam.input_limits`' checks, which the readers
    apply and API callers can apply to their own scans.
    """

    stamp: float
    angles: np.ndarray
    ranges: np.ndarray
    max_range: float
    sweep_time_s: float = 0.0

    def __post_init__(self) -> None:
        angles = np.asarray(self.angles, dtype=float)
        ranges = np.asarray(self.ranges, dtype=float)
        if angles.ndim != 1 or ranges.shape != angles.shape:
            raise InputError(f"scan angles {angles.shape} and ranges {ranges.shape} must be equal 1-D arrays")
        if not np.all(np.isfinite(angles)):
            raise InputError("scan angles must be finite")
        if not (self.max_range > 0 and np.isfinite(self.max_range)):
            raise InputError(f"scan max_range must be finite and > 0, got {self.max_range}")
        if not np.isfinite(self.stamp):
            raise InputError(f"scan stamp must be finite, got {self.stamp}")
        if not (np.isfinite(self.sweep_time_s) and abs(self.sweep_time_s) <= 1.0):
            raise InputError(f"scan sweep_time_s must be finite and within ±1 s, got {self.sweep_time_s}")
        object.__setattr__(self, "angles", angles)
        object.__setattr__(self, "ranges", ranges)

    def __len__(self) -> int:
        return self.ranges.shape[0]
