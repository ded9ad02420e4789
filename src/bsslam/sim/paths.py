"""Robot paths of simulated worlds: closed loops of constant-curvature pieces, or a
stationary pose.

A loop made of straight lines and circular arcs has a continuous heading and closed-form
poses at any arc length, so the ground truth is exact and the robot never turns on the spot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from bsslam.errors import ConfigError
from bsslam.trajectory import wrap_angle

# Below this curvature (1/m) a piece is integrated as a straight line (avoids 0/0).
_STRAIGHT_CURVATURE = 1e-12


class Path(Protocol):
    """Where the simulated robot is at each scan."""

    def sample(self, step_m: float, count: int | None = None) -> np.ndarray:
        """(N, 3) poses (x m, y m, φ rad in (−π, π]) about ``step_m`` apart along the path;
        ``count=None`` gives the path's natural length (a loop: all its laps)."""
        ...


@dataclass(frozen=True)
class LoopPath:
    """A closed path driven ``laps`` times, made of pieces of constant curvature.

    Attributes:
        start: (x m, y m, φ rad) pose at arc length 0.
        pieces: ((length m, curvature 1/m), …); positive curvature turns left.
        laps: how many times the loop is driven by :meth:`sample` with ``count=None``.
    """

    start: tuple[float, float, float]
    pieces: tuple[tuple[float, float], ...]
    laps: int = 2

    def __post_init__(self) -> None:
        if not self.pieces or any(length <= 0 for length, _ in self.pieces):
            raise ConfigError("a loop path needs pieces of positive length")
        if self.laps < 1:
            raise ConfigError(f"laps must be ≥ 1, got {self.laps}")
        end = self._piece_starts[-1]
        turns = (end[2] - self.start[2]) / (2 * math.pi)
        if math.dist(end[:2], self.start[:2]) > 1e-6 or abs(turns - round(turns)) > 1e-9:
            raise ConfigError(f"loop path does not close: ends at {end.tolist()}, starts at {list(self.start)}")

    @property
    def length_m(self) -> float:
        """Length of one lap (m)."""
        return float(sum(length for length, _ in self.pieces))

    @property
    def _piece_starts(self) -> np.ndarray:
        """(P + 1, 3) pose at the start of each piece and at the end of the lap (heading
        not wrapped)."""
        poses = [np.asarray(self.start, dtype=float)]
        for length, curvature in self.pieces:
            poses.append(_advance(poses[-1][None, :], np.array([length]), curvature)[0])
        return np.array(poses)

    def poses_at(self, s: np.ndarray) -> np.ndarray:
        """(k, 3) poses at arc lengths ``s`` (k,) (m, any value ≥ 0: laps repeat); headings
        wrapped to (−π, π]."""
        s = np.asarray(s, dtype=float).reshape(-1)
        lap_length = self.length_m
        starts = self._piece_starts
        bounds = np.concatenate([[0.0], np.cumsum([length for length, _ in self.pieces])])
        lap = np.floor(s / lap_length)
        local = s - lap * lap_length
        piece = np.clip(np.searchsorted(bounds, local, side="right") - 1, 0, len(self.pieces) - 1)
        curvatures = np.array([c for _, c in self.pieces])
        out = np.empty((s.shape[0], 3))
        for p in np.unique(piece):  # a loop per piece (a handful), vectorised over samples
            sel = piece == p
            out[sel] = _advance(starts[p][None, :], local[sel] - bounds[p], curvatures[p])
        out[:, 2] = wrap_angle(out[:, 2])
        return out

    def sample(self, step_m: float, count: int | None = None) -> np.ndarray:
        """(N, 3) poses spaced evenly along the loop, the spacing being the closest to
        ``step_m`` that divides a lap exactly, so the laps end exactly at the start.
        ``count=None`` covers all laps (N = laps · spans + 1, the last pose equals the first)."""
        if not step_m > 0:
            raise ConfigError(f"step_m must be > 0, got {step_m}")
        spans_per_lap = max(1, round(self.length_m / step_m))
        step = self.length_m / spans_per_lap
        n = self.laps * spans_per_lap + 1 if count is None else count
        if n < 1:
            raise ConfigError(f"count must be ≥ 1, got {count}")
        return self.poses_at(np.arange(n) * step)


@dataclass(frozen=True)
class StationaryPath:
    """A robot standing still at ``pose`` (x m, y m, φ rad) for ``scans`` scans."""

    pose: tuple[float, float, float]
    scans: int = 100

    def __post_init__(self) -> None:
        if self.scans < 1:
            raise ConfigError(f"scans must be ≥ 1, got {self.scans}")

    def sample(self, step_m: float, count: int | None = None) -> np.ndarray:
        """(N, 3) copies of the pose; ``step_m`` is irrelevant, N = ``count`` or ``scans``."""
        n = self.scans if count is None else count
        if n < 1:
            raise ConfigError(f"count must be ≥ 1, got {count}")
        pose = np.array(self.pose, dtype=float)
        pose[2] = wrap_angle(pose[2])
        return np.tile(pose, (n, 1))


def _advance(pose: np.ndarray, ds: np.ndarray, curvature: float) -> np.ndarray:
    """(k, 3) poses after driving ``ds`` (k,) metres from ``pose`` (1, 3) along a circle of
    the given curvature (1/m); headings not wrapped."""
    x, y, phi = pose[:, 0], pose[:, 1], pose[:, 2]
    heading = phi + curvature * ds
    if abs(curvature) < _STRAIGHT_CURVATURE:
        return np.column_stack([x + ds * np.cos(phi), y + ds * np.sin(phi), heading])
    return np.column_stack([
        x + (np.sin(heading) - np.sin(phi)) / curvature,
        y - (np.cos(heading) - np.cos(phi)) / curvature,
        heading,
    ])


def rounded_rectangle_loop(
    xmin: float, ymin: float, xmax: float, ymax: float, radii: tuple[float, float, float, float], laps: int = 2
) -> LoopPath:
    """A counter-clockwise loop around a rectangle (m) with quarter-circle corners.

    Args:
        radii: corner radii (bottom-left, bottom-right, top-right, top-left) (m), all > 0 so
            that the robot never turns on the spot.
        laps: laps driven.

    Returns:
        The loop, starting halfway along the bottom edge heading east (+x).
    """
    bl, br, tr, tl = radii
    if min(radii) <= 0:
        raise ConfigError(f"path corner radii must be > 0 (no turning on the spot), got {radii}")
    bottom, right = xmax - xmin - bl - br, ymax - ymin - br - tr
    top, left = xmax - xmin - tr - tl, ymax - ymin - tl - bl
    if min(bottom, right, top, left) <= 0:
        raise ConfigError(f"corner radii {radii} leave no straight edge on a {xmax - xmin} × {ymax - ymin} m loop")
    quarter = math.pi / 2
    pieces = (
        (bottom / 2, 0.0), (quarter * br, 1 / br),
        (right, 0.0), (quarter * tr, 1 / tr),
        (top, 0.0), (quarter * tl, 1 / tl),
        (left, 0.0), (quarter * bl, 1 / bl),
        (bottom / 2, 0.0),
    )
    return LoopPath(start=(xmin + bl + bottom / 2, ymin, 0.0), pieces=pieces, laps=laps)
