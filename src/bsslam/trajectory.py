"""Time-stamped 2D pose sequences, shared by the simulator, readers, writers and metrics."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def wrap_angle(a):
    """Wrap angle(s) to (−π, π] (rad)."""
    return np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2.0 * np.pi)


@dataclass(frozen=True)
class Trajectory:
    """A sequence of planar poses.

    Attributes:
        stamps: (N,) times (s), non-decreasing.
        poses: (N, 3) poses (x m, y m, φ rad) in the world frame.
        covariances: optional (N, 3, 3) pose covariances.
    """

    stamps: np.ndarray
    poses: np.ndarray
    covariances: np.ndarray | None = None

    def __post_init__(self) -> None:
        stamps = np.asarray(self.stamps, dtype=float).reshape(-1)
        poses = np.asarray(self.poses, dtype=float).reshape(-1, 3)
        if stamps.shape[0] != poses.shape[0]:
            raise ValueError(f"{stamps.shape[0]} stamps but {poses.shape[0]} poses")
        object.__setattr__(self, "stamps", stamps)
        object.__setattr__(self, "poses", poses)
        if self.covariances is not None:
            cov = np.asarray(self.covariances, dtype=float).reshape(-1, 3, 3)
            if cov.shape[0] != poses.shape[0]:
                raise ValueError(f"{cov.shape[0]} covariances but {poses.shape[0]} poses")
            object.__setattr__(self, "covariances", cov)

    def __len__(self) -> int:
        return self.stamps.shape[0]
