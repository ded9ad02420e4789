"""Synthetic scans for the front-end tests: ray casting of simple walls and simulator runs."""

from __future__ import annotations

import math

import numpy as np

from bsslam.scan.laser_scan import LaserScan
from bsslam.sim import Segment, WallSet, ray_cast
from bsslam.trajectory import wrap_angle

#: 180° scan, 1° beams, as on the Intel/ACES logs.
ANGLES = np.radians(np.arange(-90.0, 90.5, 1.0))


def cast_scan(walls: WallSet, pose: np.ndarray, rng: np.random.Generator | None = None, sigma: float = 0.01,
              max_range: float = 30.0, angles: np.ndarray = ANGLES) -> LaserScan:
    """The scan a laser at robot ``pose`` sees of ``walls`` (no return → max_range)."""
    ranges = ray_cast(walls, np.asarray(pose[:2], dtype=float), pose[2] + angles, max_range)
    if rng is not None:
        ranges = ranges + rng.normal(0.0, sigma, ranges.shape)
    ranges = np.where(np.isfinite(ranges), ranges, max_range)
    return LaserScan(0.0, angles, ranges, max_range)


def room(width: float = 8.0, depth: float = 6.0) -> WallSet:
    """A rectangular room with a pillar and a niche, so every direction is constrained."""
    w, d = width / 2, depth / 2
    return WallSet((
        Segment((-w, -d), (w, -d)), Segment((w, -d), (w, -0.5)), Segment((w, -0.5), (w + 1.0, -0.5)),
        Segment((w + 1.0, -0.5), (w + 1.0, 0.8)), Segment((w + 1.0, 0.8), (w, 0.8)), Segment((w, 0.8), (w, d)),
        Segment((w, d), (-w, d)), Segment((-w, d), (-w, -d)),
        Segment((1.0, 1.0), (1.6, 1.0)), Segment((1.6, 1.0), (1.6, 1.5)), Segment((1.6, 1.5), (1.0, 1.5)),
        Segment((1.0, 1.5), (1.0, 1.0)),
    ))


def corridor(length: float = 200.0, width: float = 2.0) -> WallSet:
    """Two long parallel walls along x: nothing fixes the motion along the corridor."""
    return WallSet((Segment((-length / 2, -width / 2), (length / 2, -width / 2)),
                    Segment((-length / 2, width / 2), (length / 2, width / 2))))


def pose_error(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    e = np.asarray(estimate, dtype=float) - np.asarray(truth, dtype=float)
    e[..., 2] = wrap_angle(e[..., 2])
    return e


def perturbation(rng: np.random.Generator, metres: float = 0.3, degrees: float = 20.0) -> np.ndarray:
    """A guess error of exactly ``metres`` in a random direction and ±``degrees``."""
    a = rng.uniform(-math.pi, math.pi)
    return np.array([metres * math.cos(a), metres * math.sin(a), math.radians(degrees) * rng.choice([-1.0, 1.0])])
