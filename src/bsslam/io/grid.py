"""Occupancy grids in the ROS ``map_server`` format (a PGM image and a YAML description).

The grid holds the PGM grey values directly, "trinary" mode: 0 = occupied (black),
254 = free, 205 = unknown. Row 0 is the top of the image (largest y); ``origin`` is the
world pose (x m, y m, θ rad) of the lower-left corner of the lower-left cell, as
map_server expects, so cell (row, col) covers x ∈ [ox + col·res, ox + (col+1)·res) and
y ∈ [oy + (H−1−row)·res, oy + (H−row)·res).
"""

from __future__ import annotations

import os
from typing import Iterable, Sequence

import numpy as np
import yaml

from bsslam.errors import InputError
from bsslam.io.path_or_file import PathOrFile, describe, open_path_or_file

OCCUPIED = 0
FREE = 254
UNKNOWN = 205

# Samples per cell along lines: finer than the cell so a diagonal line leaves no gaps.
_SAMPLES_PER_CELL = 4


def _sample_segments(starts: np.ndarray, ends: np.ndarray, step_m: float) -> np.ndarray:
    """Points every ≤ ``step_m`` along each segment, both ends included.

    Args:
        starts, ends: (m, 2) segment end points (m).
    Returns:
        (k, 2) points, all segments together (one vectorised pass, no loop per segment).
    """
    delta = ends - starts
    length = np.hypot(delta[:, 0], delta[:, 1])
    pieces = np.maximum(np.ceil(length / step_m), 1).astype(np.int64)
    counts = pieces + 1
    segment = np.repeat(np.arange(len(starts)), counts)
    first = np.cumsum(counts) - counts
    k = np.arange(counts.sum()) - np.repeat(first, counts)
    fraction = k / np.repeat(pieces, counts)
    return starts[segment] + fraction[:, None] * delta[segment]


def _polyline_segments(polylines: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(m, 2) starts and ends of all consecutive point pairs; a single point is a
    zero-length segment so that it is still drawn."""
    starts, ends = [], []
    for line in polylines:
        pts = np.asarray(line, dtype=float).reshape(-1, 2)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if len(pts) == 1:
            starts.append(pts)
            ends.append(pts)
        elif len(pts) > 1:
            starts.append(pts[:-1])
            ends.append(pts[1:])
    if not starts:
        return np.empty((0, 2)), np.empty((0, 2))
    return np.concatenate(starts), np.concatenate(ends)


def _ray_segments(free_rays: Iterable[tuple[np.ndarray, np.ndarray]],
                  resolution_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Starts, shortened ends and the true end points of all rays.

    Each ray stops half a cell short of its end point: the end is where the beam hit
    something, so its own cell must not be cleared.
    """
    starts, ends = [], []
    for origin, endpoints in free_rays:
        pts = np.asarray(endpoints, dtype=float).reshape(-1, 2)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        starts.append(np.broadcast_to(np.asarray(origin, dtype=float).reshape(2), pts.shape))
        ends.append(pts)
    if not starts:
        return np.empty((0, 2)), np.empty((0, 2)), np.empty((0, 2))
    starts_all, ends_all = np.concatenate(starts), np.concatenate(ends)
    delta = ends_all - starts_all
    length = np.hypot(delta[:, 0], delta[:, 1])
    keep = np.clip(length - 0.5 * resolution_m, 0.0, None) / np.where(length > 0, length, 1.0)
    return starts_all, starts_all + keep[:, None] * delta, ends_all


def render_grid(polylines: Sequence[np.ndarray], resolution_m: float = 0.05, margin_m: float = 1.0,
                free_rays: Iterable[tuple[np.ndarray, np.ndarray]] | None = None
                ) -> tuple[np.ndarray, tuple[float, float, float]]:
    """Rasterise map curves (and optionally the free space seen by laser rays).

    Args:
        polylines: list of (k, 2) world points (m), e.g. map splines sampled densely;
            every cell they pass through becomes occupied.
        resolution_m: cell size (m).
        margin_m: unknown border around everything drawn (m).
        free_rays: optional iterable of (origin (2,), endpoints (m, 2)) in world
            coordinates (m); cells a ray traverses become free (drawn before the
            occupied cells, which win).

    Returns:
        grid: (H, W) uint8 with 0 occupied, 254 free, 205 unknown; row 0 = largest y.
        origin: (x m, y m, θ = 0 rad) of the lower-left corner of the lower-left cell.
        With nothing to draw, an all-unknown grid of ±``margin_m`` around (0, 0).

    Raises:
        InputError: non-positive resolution or negative margin.
    """
    if not resolution_m > 0 or not margin_m >= 0:
        raise InputError(f"resolution_m must be > 0 and margin_m ≥ 0, got {resolution_m}, {margin_m}")
    occ_starts, occ_ends = _polyline_segments(polylines)
    ray_starts, ray_ends, ray_hits = _ray_segments(free_rays or (), resolution_m)
    everything = np.concatenate([occ_starts, occ_ends, ray_starts, ray_hits])
    if len(everything) == 0:
        # an empty map (e.g. a run too short to map anything) is still a valid, unknown grid
        everything = np.zeros((1, 2))

    low = everything.min(axis=0) - margin_m
    high = everything.max(axis=0) + margin_m
    width, height = np.maximum(np.ceil((high - low) / resolution_m).astype(int), 1)
    grid = np.full((height, width), UNKNOWN, dtype=np.uint8)

    def paint(points: np.ndarray, value: int) -> None:
        cols = np.floor((points[:, 0] - low[0]) / resolution_m).astype(np.int64)
        rows_up = np.floor((points[:, 1] - low[1]) / resolution_m).astype(np.int64)
        cols = np.clip(cols, 0, width - 1)
        rows = height - 1 - np.clip(rows_up, 0, height - 1)
        grid[rows, cols] = value

    step = resolution_m / _SAMPLES_PER_CELL
    if len(ray_starts):
        paint(_sample_segments(ray_starts, ray_ends, step), FREE)
    if len(occ_starts):
        paint(_sample_segments(occ_starts, occ_ends, step), OCCUPIED)
    return grid, (float(low[0]), float(low[1]), 0.0)


def _image_reference(pgm: PathOrFile, yaml_target: PathOrFile) -> str:
    """The ``image:`` entry: the PGM path relative to the YAML file's folder when both are
    paths (map_server resolves it that way), else the PGM's name."""
    pgm_name = describe(pgm)
    if isinstance(yaml_target, (str, os.PathLike)) and isinstance(pgm, (str, os.PathLike)):
        folder = os.path.dirname(os.path.abspath(os.fspath(yaml_target)))
        return os.path.relpath(os.path.abspath(pgm_name), folder)
    return os.path.basename(pgm_name)


def write_grid(pgm_path: PathOrFile, yaml_path: PathOrFile, grid: np.ndarray,
               origin: Sequence[float], resolution_m: float) -> None:
    """Write ``grid`` as a binary PGM (P5, maxval 255) and its map_server YAML.

    Args:
        pgm_path: path or binary file for the image.
        yaml_path: path or text file for the description.
        grid: (H, W) uint8 as returned by :func:`render_grid`.
        origin: (x m, y m, θ rad) of the lower-left corner.
        resolution_m: cell size (m).

    Raises:
        InputError: a grid that is not a 2-D uint8 array, or an unwritable file.
    """
    grid = np.asarray(grid)
    if grid.ndim != 2 or grid.dtype != np.uint8:
        raise InputError(f"grid must be a 2-D uint8 array, got {grid.dtype} {grid.shape}")
    height, width = grid.shape
    with open_path_or_file(pgm_path, "wb") as f:
        f.write(f"P5\n{width} {height}\n255\n".encode("ascii"))
        f.write(np.ascontiguousarray(grid).tobytes())
    description = {
        "image": _image_reference(pgm_path, yaml_path),
        "resolution": float(resolution_m),
        "origin": [float(v) for v in origin],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
        "mode": "trinary",
    }
    with open_path_or_file(yaml_path, "w") as f:
        yaml.safe_dump(description, f, sort_keys=False)
