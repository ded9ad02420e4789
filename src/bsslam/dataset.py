"""What every data source (log readers, ROS bags, the simulator) yields."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator, Protocol

import numpy as np

from bsslam.scan.laser_scan import LaserScan
from bsslam.trajectory import Trajectory


@dataclass(frozen=True)
class Frame:
    """One scan with the odometry pose at its time.

    Attributes:
        stamp: time (s).
        odometry: (3,) dead-reckoning pose (x m, y m, φ rad) of the robot at ``stamp``.
        scan: the laser scan, its bearings in the *laser* frame.
        laser_offset: (3,) pose of the laser in the robot frame (x m, y m, φ rad); the filter
            applies it (zeros when the laser sits at the robot's origin).
    """

    stamp: float
    odometry: np.ndarray
    scan: LaserScan
    laser_offset: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass
class SkipCounter:
    """Counts of input skipped by a reader, by reason, with the first few locations.

    ``counts`` are skips worth reporting (bad or unusable input); ``ignored`` counts input
    that is not meant for the reader (message types it does not use, a second laser
    stream), silently, and is not part of ``total``.
    """

    counts: dict[str, int] = field(default_factory=dict)
    examples: list[str] = field(default_factory=list)
    max_examples: int = 20
    ignored: dict[str, int] = field(default_factory=dict)

    def add(self, reason: str, where: str | None = None) -> None:
        self.counts[reason] = self.counts.get(reason, 0) + 1
        if where is not None and len(self.examples) < self.max_examples:
            self.examples.append(f"{where}: {reason}")

    def ignore(self, key: str) -> None:
        """Count input not meant for the reader under ``key`` (not a skip)."""
        self.ignored[key] = self.ignored.get(key, 0) + 1

    @property
    def total(self) -> int:
        return sum(self.counts.values())


class Dataset(Protocol):
    """A stream of frames; readers and the simulator implement it.

    A reader may also have ``expected_frames``: how many frames a pass will yield at most
    (int, or None when it cannot tell), for a progress bar's total."""

    name: str
    ground_truth: Trajectory | None
    skipped: SkipCounter

    def __iter__(self) -> Iterator[Frame]: ...
