"""Synthetic scans with exact geometry, and a tiny FLASER parser for the Intel log."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bsslam.scan import LaserScan
from bsslam.sim.geometry import Arc, Segment, ray_cast

DATA_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data"
INTEL_RAWODOM = DATA_DIR / "intel" / "intel-rawodom.clf"
CARMEN_NO_RETURN_M = 80.0


def cast_scan(walls, *, origin=(0.0, 0.0), fov_deg=180.0, step_deg=1.0, max_range=8.0,
              sigma_m=0.0, seed=0) -> LaserScan:
    """A scan from ``origin`` facing +x: bearings from −fov/2 to +fov/2 inclusive, exact
    ranges to ``walls`` plus N(0, σ²) noise; beams that hit nothing are +inf."""
    half = fov_deg / 2.0
    angles = np.deg2rad(np.arange(-half, half + step_deg / 2, step_deg))
    ranges = ray_cast(walls, np.asarray(origin, dtype=float), angles, max_range)
    if sigma_m > 0:
        ranges = ranges + np.random.default_rng(seed).normal(0.0, sigma_m, ranges.shape)
    return LaserScan(stamp=0.0, angles=angles, ranges=ranges, max_range=max_range)


def room_walls():
    """Three walls of a room seen from the origin: y = −2, x = 3, y = 2 (corners at x = 3)."""
    return [Segment((-1.0, -2.0), (3.0, -2.0)), Segment((3.0, -2.0), (3.0, 2.0)), Segment((3.0, 2.0), (-1.0, 2.0))]


def pillar(center, radius_m):
    return Arc(center, radius_m, 0.0, 2 * np.pi)


def load_flaser(path: Path, limit: int) -> list[LaserScan]:
    """The first ``limit`` FLASER scans: beams from −90° in steps of 180°/n; ≥ 80 m = no return."""
    scans = []
    with open(path) as f:
        for line in f:
            if not line.startswith("FLASER "):
                continue
            fields = line.split()
            n = int(fields[1])
            ranges = np.array(fields[2:2 + n], dtype=float)
            angles = np.deg2rad(-90.0 + np.arange(n) * 180.0 / n)
            scans.append(LaserScan(float(fields[2 + n + 6]), angles, ranges, CARMEN_NO_RETURN_M))
            if len(scans) == limit:
                break
    return scans


def on_line(points: np.ndarray, a, b, tol: float) -> np.ndarray:
    """(k,) whether each point lies within ``tol`` of the infinite line through a and b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    u = (b - a) / np.linalg.norm(b - a)
    d = points - a
    return np.abs(d[:, 0] * u[1] - d[:, 1] * u[0]) <= tol
