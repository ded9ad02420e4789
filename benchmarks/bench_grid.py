"""How navigable a run's occupancy grid is (not a test: prints figures, asserts nothing).

Reads a results folder of ``bsslam run`` (``grid.yaml``/``grid.pgm``, ``trajectory.tum``,
``map.json``, ``config.yaml``) and the log it came from, and reports

- poses on free cells: the share of ``trajectory.tum``'s poses whose cell in the written
  grid, read as map_server reads it (trinary, ``p = (255 − value)/255``), is free;
- the same in the scans' evidence alone (no footprint, no splines drawn in), the grid
  rebuilt from the log's first N scans at the trajectory's poses;
- spline cells on occupied: the share of points along the map splines (every 1 cm) whose
  cell in that evidence-only grid is occupied, and within one cell (3 × 3) of an occupied
  one. In the written grid the splines are drawn in, so there it is 100 % by construction.

Run:  python benchmarks/bench_grid.py RUN_DIR LOG
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
from pathlib import Path

import numpy as np
import yaml
from PIL import Image

from bsslam.io import open_dataset
from bsslam.io.config_file import load_config
from bsslam.io.grid import FREE, OCCUPIED, build_occupancy_grid
from bsslam.io.map_file import read_map_json
from bsslam.io.trajectory_file import read_trajectory
from bsslam.spline import BSplineCurve

# map_server's classes of a cell
OCCUPIED_CLASS, FREE_CLASS, UNKNOWN_CLASS = 1, 0, -1


def _cells(xy: np.ndarray, origin, resolution: float, height: int) -> tuple[np.ndarray, np.ndarray]:
    col = np.floor((xy[:, 0] - origin[0]) / resolution).astype(int)
    row = height - 1 - np.floor((xy[:, 1] - origin[1]) / resolution).astype(int)
    return row, col


def _written_classes(run_dir: Path):
    meta = yaml.safe_load((run_dir / "grid.yaml").read_text())
    value = np.asarray(Image.open(run_dir / meta["image"]), dtype=float)
    p = value / 255 if meta["negate"] else (255 - value) / 255
    classes = np.full(value.shape, UNKNOWN_CLASS)
    classes[p > meta["occupied_thresh"]] = OCCUPIED_CLASS
    classes[p < meta["free_thresh"]] = FREE_CLASS
    return classes, meta["origin"], meta["resolution"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("log", type=Path)
    args = parser.parse_args()

    trajectory = read_trajectory(args.run_dir / "trajectory.tum")
    config = load_config(args.run_dir / "config.yaml")
    classes, origin, resolution = _written_classes(args.run_dir)
    row, col = _cells(trajectory.poses[:, :2], origin, resolution, classes.shape[0])
    print(f"poses: {len(trajectory)}; grid {classes.shape[1]} × {classes.shape[0]} cells of {resolution} m")
    print(f"written grid:  poses on free cells {100 * np.mean(classes[row, col] == FREE_CLASS):.2f} %")

    frames = itertools.islice(open_dataset(args.log), len(trajectory))
    scans = [(f.scan, np.asarray(f.laser_offset, float)) for f in frames]
    evidence = build_occupancy_grid(scans, trajectory.poses, dataclasses.replace(config.grid, footprint_radius_m=0.0))
    image = evidence.image(config.grid.occupied_thresh, config.grid.free_thresh)
    h, w = image.shape
    row, col = _cells(trajectory.poses[:, :2], evidence.origin, evidence.resolution_m, h)
    print(f"scans alone:   poses on free cells {100 * np.mean(image[row, col] == FREE):.2f} %")

    points = []
    for s in read_map_json(args.run_dir / "map.json").splines:
        curve = BSplineCurve(s.curve.control_points, s.curve.knots, s.curve.degree)
        lo, hi = curve.domain
        points.append(curve.evaluate(np.linspace(lo, hi, max(2, int(np.ceil((hi - lo) / 0.01)) + 1))))
    points = np.vstack(points)
    row, col = _cells(points, evidence.origin, evidence.resolution_m, h)
    near = np.zeros(len(points), bool)
    for dr, dc in itertools.product((-1, 0, 1), repeat=2):
        near |= image[np.clip(row + dr, 0, h - 1), np.clip(col + dc, 0, w - 1)] == OCCUPIED
    print(f"scans alone:   spline points on occupied cells {100 * np.mean(image[row, col] == OCCUPIED):.2f} %, "
          f"within one cell {100 * np.mean(near):.2f} % ({len(points)} points every 1 cm)")


if __name__ == "__main__":
    main()
