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

    The constructor checks shapes and finiteness only; the physical limits (beam count,
    increasing bearings, ranges) are :mod:`bsslam.input_limits`' checks, which the readers
    apply and API callers can apply to their own scans.
    """

    stamp: float
    angles: np.ndarray
    ranges: np.ndarray
    max_range: float

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
        object.__setattr__(self, "angles", angles)
        object.__setattr__(self, "ranges", ranges)

    def __len__(self) -> int:
        return self.ranges.shape[0]
