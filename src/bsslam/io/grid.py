"""Occupancy grids: log-odds evidence from a run's scans at their final poses, with the map
curves drawn in, written in the ROS ``map_server`` format (a PGM image and a YAML description).

The image holds the PGM grey values directly, "trinary" mode: 0 = occupied (black),
254 = free, 205 = unknown. Row 0 is the top of the image (largest y); ``origin`` is the
world pose (x m, y m, θ rad) of the lower-left corner of the lower-left cell, as
map_server expects, so cell (row, col) covers x ∈ [ox + col·res, ox + (col+1)·res) and
y ∈ [oy + (H−1−row)·res, oy + (H−row)·res).
"""

from __future__ import annotations

import io

import os
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np
import yaml
from PIL import Image

from bsslam.config import GridConfig
from bsslam.errors import InputError
from bsslam.io.grid_kernels import draw_segments, integrate_scans
from bsslam.io.path_or_file import PathOrFile, describe, open_path_or_file

OCCUPIED = 0
FREE = 254
UNKNOWN = 205


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


@dataclass(frozen=True, eq=False)
class OccupancyGrid:
    """Log-odds occupancy evidence on a regular grid.

    Attributes:
        log_odds: (H, W) float32 log-odds of "occupied"; 0 = never observed. Row 0 is the
            top of the image (largest y), as in the PGM.
        origin: (x m, y m, θ = 0 rad) of the lower-left corner of the lower-left cell.
        resolution_m: cell size (m).
    """

    log_odds: np.ndarray
    origin: tuple[float, float, float]
    resolution_m: float

    def probabilities(self) -> np.ndarray:
        """(H, W) probability of "occupied", 1 / (1 + e^(−log-odds)); 0.5 where unobserved."""
        return 1.0 / (1.0 + np.exp(-self.log_odds.astype(float)))

    def image(self, occupied_thresh: float = 0.65, free_thresh: float = 0.196) -> np.ndarray:
        """(H, W) uint8 trinary image: OCCUPIED where p > ``occupied_thresh``, FREE where
        p < ``free_thresh``, UNKNOWN elsewhere (map_server's own classification)."""
        # compared in log-odds (p is monotonic in it): no float64 copy of a campus-sized grid
        free, occupied = (np.float64(np.log(t / (1.0 - t))) for t in (free_thresh, occupied_thresh))
        image = np.full(self.log_odds.shape, UNKNOWN, dtype=np.uint8)
        image[self.log_odds < free] = FREE
        image[self.log_odds > occupied] = OCCUPIED
        return image


def _laser_poses(poses: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(S, 3) world poses of the lasers: each robot pose (S, 3) composed with its laser's
    mounting offset (S, 3) in the robot frame (m, rad)."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    return np.column_stack([poses[:, 0] + c * offsets[:, 0] - s * offsets[:, 1],
                            poses[:, 1] + s * offsets[:, 0] + c * offsets[:, 1],
                            poses[:, 2] + offsets[:, 2]])


@dataclass(frozen=True)
class _BeamBatch:
    """The beams of consecutive scans in world coordinates (m): ``origins`` (S, 2) of the
    lasers, beams of scan s at ``beam_start[s] : beam_start[s+1]`` of ``ends`` (B, 2) and
    ``hit`` (B,) (a return, else a no-return beam cleared up to its end)."""

    first_scan: int
    origins: np.ndarray
    beam_start: np.ndarray
    ends: np.ndarray
    hit: np.ndarray


def _beam_batch(first_scan: int, scans: list, poses: np.ndarray, config: GridConfig) -> _BeamBatch:
    """One batch of scans (list of (LaserScan, laser offset (3,))) at ``poses`` (S, 3)."""
    counts = np.array([len(scan.ranges) for scan, _ in scans], dtype=np.int64)
    laser = _laser_poses(poses, np.array([np.asarray(offset, dtype=float).reshape(3) for _, offset in scans]))
    ranges = np.concatenate([scan.ranges for scan, _ in scans])
    angles = np.concatenate([scan.angles for scan, _ in scans])
    max_range = np.repeat([float(scan.max_range) for scan, _ in scans], counts)
    scan_of = np.repeat(np.arange(len(scans)), counts)
    with np.errstate(invalid="ignore"):
        valid = ranges > config.min_range_m                   # NaN (a measurement error) is not
        hit = valid & (ranges < max_range)                    # inf and ≥ max_range: no return
    clear = valid & ~hit & (config.no_return_clear_m > 0)
    length = np.where(hit, ranges, np.minimum(config.no_return_clear_m, max_range))
    bearing = laser[scan_of, 2] + angles
    ends = laser[scan_of, :2] + length[:, None] * np.column_stack([np.cos(bearing), np.sin(bearing)])
    origin_ok = np.all(np.isfinite(laser[:, :2]), axis=1)
    keep = (hit | clear) & np.all(np.isfinite(ends), axis=1) & origin_ok[scan_of]
    beam_start = np.searchsorted(scan_of[keep], np.arange(len(scans) + 1))
    origins = np.where(origin_ok[:, None], laser[:, :2], 0.0)   # a scan without beams is never walked
    return _BeamBatch(first_scan, origins, beam_start, ends[keep], hit[keep])


def _beam_batches(scans: Sequence, poses: np.ndarray, config: GridConfig,
                  batch_beams: int = 1 << 20) -> Iterator[_BeamBatch]:
    """The scans in batches of about ``batch_beams`` beams, so memory stays bounded
    whatever the length of the run."""
    first, count = 0, 0
    for k, (scan, _) in enumerate(scans):
        count += len(scan.ranges)
        if count >= batch_beams or k == len(scans) - 1:
            yield _beam_batch(first, list(scans[first:k + 1]), poses[first:k + 1], config)
            first, count = k + 1, 0


def _clear_footprints(log_odds: np.ndarray, centres: np.ndarray, radius: float, value: float) -> None:
    """Set every cell whose centre is within ``radius`` of a centre (k, 2) to ``value``
    (cell units, y-up ``log_odds``); the centres' own cells always."""
    centres = centres[np.all(np.isfinite(centres), axis=1)]
    if not len(centres):
        return
    reach = int(np.ceil(radius)) + 1
    d = np.arange(-reach, reach + 1)
    offsets = np.stack(np.meshgrid(d, d, indexing="ij"), axis=-1).reshape(-1, 2)     # (row, col)
    cell = np.floor(centres).astype(np.int64)                                         # (col, row)
    rows = cell[:, 1, None] + offsets[None, :, 0]
    cols = cell[:, 0, None] + offsets[None, :, 1]
    inside = np.hypot(cols + 0.5 - centres[:, 0, None], rows + 0.5 - centres[:, 1, None]) <= radius
    inside |= (offsets[:, 0] == 0) & (offsets[:, 1] == 0)
    height, width = log_odds.shape
    inside &= (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
    log_odds[rows[inside], cols[inside]] = value


def build_occupancy_grid(scans: Sequence, poses: np.ndarray, config: GridConfig,
                         polylines: Sequence[np.ndarray] = ()) -> OccupancyGrid:
    """The occupancy grid of a run: every scan's beams at their poses, then the map curves.

    Each beam lowers the log-odds of the cells it crosses (``log_odds_miss``) and raises
    that of the cell of its return (``log_odds_hit``); a "no return" beam (inf, or ≥ the
    scan's max_range) clears up to ``no_return_clear_m``; beams at or below
    ``min_range_m`` or NaN are ignored. A cell takes one update per scan, a return first.
    Then the cells within ``footprint_radius_m`` of a pose are set to the free limit, and
    every cell a map curve passes through to the occupied limit.

    Args:
        scans: one (LaserScan, laser offset (3,) in the robot frame (m, rad)) per pose.
        poses: (N, 3) robot poses (m, rad), one per scan (e.g. the final trajectory).
        config: the ``grid`` section (resolution, log-odds, limits).
        polylines: map curves as (k, 2) world points (m), e.g. the splines sampled densely.

    Returns:
        The grid, just large enough for every pose, laser position, beam end and curve
        point plus ``margin_m``; with nothing to draw, ±``margin_m`` around (0, 0).

    Raises:
        InputError: scans and poses of different lengths, or a grid that would exceed
            ``grid.max_cells`` (a wild range or pose).
    """
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    if len(scans) != len(poses):
        raise InputError(f"{len(scans)} scans but {len(poses)} poses")
    res = config.resolution_m
    occ_starts, occ_ends = _polyline_segments(polylines)
    low, high = np.full(2, np.inf), np.full(2, -np.inf)
    only = None     # the batch, when there is one (most runs): not computed twice
    for count, batch in enumerate(_beam_batches(scans, poses, config)):
        only = batch if count == 0 else None
        for pts in (batch.origins[np.diff(batch.beam_start) > 0], batch.ends):
            if len(pts):
                low, high = np.minimum(low, pts.min(axis=0)), np.maximum(high, pts.max(axis=0))
    robot = poses[np.all(np.isfinite(poses[:, :2]), axis=1), :2]
    for pts in (occ_starts, occ_ends, robot):
        if len(pts):
            low, high = np.minimum(low, pts.min(axis=0)), np.maximum(high, pts.max(axis=0))
    if not np.all(np.isfinite(low)):
        # nothing observed (e.g. a run too short to map anything): still a valid, unknown grid
        low, high = np.zeros(2), np.zeros(2)
    low, high = low - config.margin_m, high + config.margin_m
    size = np.maximum(np.ceil((high - low) / res), 1.0)   # float: a wild extent cannot overflow
    if size[0] * size[1] > config.max_cells:
        raise InputError(
            f"the occupancy grid would have {size[0]:.3g} × {size[1]:.3g} cells, more than grid.max_cells = "
            f"{config.max_cells}: x ∈ [{low[0]:.6g}, {high[0]:.6g}] m, y ∈ [{low[1]:.6g}, {high[1]:.6g}] m "
            f"(a wild range or pose?); raise grid.max_cells or grid.resolution_m")
    width, height = int(size[0]), int(size[1])
    log_odds = np.zeros((height, width), dtype=np.float32)     # y-up while building
    stamp = np.full((height, width), -1, dtype=np.int32)   # 2s + 1 < 2³¹: at most ~10⁹ scans
    for batch in [only] if only is not None else _beam_batches(scans, poses, config):
        integrate_scans(log_odds, stamp, batch.first_scan, (batch.origins - low) / res, batch.beam_start,
                        (batch.ends - low) / res, batch.hit, np.float32(config.log_odds_hit),
                        np.float32(config.log_odds_miss), np.float32(config.log_odds_limit))
    del stamp
    _clear_footprints(log_odds, (poses[:, :2] - low) / res, config.footprint_radius_m / res, -config.log_odds_limit)
    draw_segments(log_odds, (occ_starts - low) / res, (occ_ends - low) / res, np.float32(config.log_odds_limit))
    return OccupancyGrid(np.ascontiguousarray(log_odds[::-1]), (float(low[0]), float(low[1]), 0.0), float(res))


def _image_reference(pgm: PathOrFile, yaml_target: PathOrFile) -> str:
    """The ``image:`` entry: the PGM path relative to the YAML file's folder when both are
    paths (map_server resolves it that way), else the PGM's name."""
    pgm_name = describe(pgm)
    if isinstance(yaml_target, (str, os.PathLike)) and isinstance(pgm, (str, os.PathLike)):
        folder = os.path.dirname(os.path.abspath(os.fspath(yaml_target)))
        return os.path.relpath(os.path.abspath(pgm_name), folder)
    return os.path.basename(pgm_name)


def write_grid(pgm_path: PathOrFile, yaml_path: PathOrFile, grid: np.ndarray,
               origin: Sequence[float], resolution_m: float, occupied_thresh: float = 0.65,
               free_thresh: float = 0.196) -> None:
    """Write a trinary image as a binary PGM (P5, maxval 255, by Pillow) and its map_server
    YAML (``negate: 0``, ``mode: trinary``).

    Args:
        pgm_path: path or binary file for the image.
        yaml_path: path or text file for the description.
        grid: (H, W) uint8 trinary image, e.g. :meth:`OccupancyGrid.image`; row 0 = top.
        origin: (x m, y m, θ rad) of the lower-left corner.
        resolution_m: cell size (m).
        occupied_thresh, free_thresh: the probabilities map_server classifies with; with
            ``1/255 < free_thresh < 50/255 < occupied_thresh < 1`` it reads 0, 254 and 205
            back as occupied, free and unknown.

    Raises:
        InputError: a grid that is not a 2-D uint8 array, or an unwritable file.
    """
    grid = np.asarray(grid)
    if grid.ndim != 2 or grid.dtype != np.uint8:
        raise InputError(f"grid must be a 2-D uint8 array, got {grid.dtype} {grid.shape}")
    with open_path_or_file(pgm_path, "wb") as f:
        # encoded in memory, then written through ``f``: Pillow writes a real file by its
        # descriptor, around the file object that reports a full disk or a failed write
        encoded = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(grid)).save(encoded, format="PPM")   # uint8 (H, W) → "L" → P5
        f.write(encoded.getvalue())
    description = {
        "image": _image_reference(pgm_path, yaml_path),
        "resolution": float(resolution_m),
        "origin": [float(v) for v in origin],
        "negate": 0,
        "occupied_thresh": float(occupied_thresh),
        "free_thresh": float(free_thresh),
        "mode": "trinary",
    }
    with open_path_or_file(yaml_path, "w") as f:
        yaml.safe_dump(description, f, sort_keys=False)
