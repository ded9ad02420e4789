"""How much the front end's matches turn on the last digits of their input.

    python benchmarks/frontend_sensitivity.py LOG [--scans N] [--nudge-m 0.0005] [--from-scan K]

A benchmark, not a test. It runs the laser odometry (the front end alone, default
configuration) over the first ``--scans`` scans of LOG and asks three questions:

- **Knife edges**: before each match, the front end is copied four times, each copy's pose
  (the guess the match starts from) moved by ``--nudge-m`` (x, y; a fiftieth of it in
  radians), and the scan matched in each. A match whose results spread by more than 5 mm
  sits on a knife edge: which local minimum of the refinement it ends in turns on a
  tenth of a millimetre. Printed: the share of such matches (> 5 mm, > 20 mm, heading >
  0.05°) and the median spread.
- **Range noise**: before each match, the front end is copied and the copy matches the
  scan with every return moved by 1 mm of seeded noise; printed: how far the two matched
  poses lie apart (heading: median, 90th percentile, largest, RMS; position: 90th
  percentile). A match whose objective has one clear minimum moves by thousandths of a
  degree; one that ends in one of several minima tenths of a degree apart, by tenths.
- **Growth**: every return of scan ``--from-scan`` moved by 1 mm of seeded noise, the rest
  of the log as it is; printed: the largest difference of the increments from the
  unperturbed run in each of the following 10-scan windows. A front end whose matches
  were continuous in their input would keep it near the first step's; a chaotic one
  grows it to centimetres.

It answers why ten runs of one log with 1 mm of range noise (``bsslam bench --perturb``)
end apart: see docs/real_logs.md, "Why a millimetre of noise parts the runs".
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
from pathlib import Path

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.frontend.laser_odometry import LaserOdometry
from bsslam.io import open_dataset
from bsslam.perturbed_dataset import perturb_scan
from bsslam.trajectory import wrap_angle

#: Copies of the front end matched with nudged guesses before each scan.
COPIES = 4


def knife_edges(frames: list, nudge_m: float, seed: int = 0) -> np.ndarray:
    """(k, 2) per matched scan: the spread (m) of the matched positions and (rad) of the
    headings over :data:`COPIES` copies whose guesses were moved by ``nudge_m``."""
    front = LaserOdometry(SLAMConfig().frontend)
    rng = np.random.default_rng(seed)
    spreads = []
    for frame in frames:
        if front.pose is not None and front._submap() is not None:
            poses = []
            for _ in range(COPIES):
                nudged = copy.deepcopy(front)
                nudged.pose = nudged.pose + np.r_[rng.normal(0.0, nudge_m, 2), rng.normal(0.0, nudge_m / 50.0)]
                poses.append(nudged.step(frame).pose)
            poses = np.array(poses)
            spreads.append((np.hypot(np.ptp(poses[:, 0]), np.ptp(poses[:, 1])), np.ptp(poses[:, 2])))
        front.step(frame)
    return np.array(spreads).reshape(-1, 2)


def range_jumps(frames: list, seed: int = 0) -> np.ndarray:
    """(k, 2) per matched scan: how far (m, rad) the matched pose moves when the scan's
    returns are moved by 1 mm of noise, the front end's state the same."""
    front = LaserOdometry(SLAMConfig().frontend)
    rng = np.random.default_rng(seed)
    jumps = []
    for frame in frames:
        if front.pose is not None and front._submap() is not None:
            moved = copy.deepcopy(front).step(dataclasses.replace(frame, scan=perturb_scan(frame.scan, rng, 0.001)))
            step = front.step(frame)
            if moved.match is not None and moved.match.ok and step.match is not None and step.match.ok:
                jumps.append((np.hypot(*(step.pose[:2] - moved.pose[:2])), abs(wrap_angle(step.pose[2] - moved.pose[2]))))
        else:
            front.step(frame)
    return np.array(jumps).reshape(-1, 2)


def growth(frames: list, at: int) -> np.ndarray:
    """(n, 3) the difference of each increment between the log as it is and the log with
    scan ``at``'s ranges moved by 1 mm of noise (NaN before and where there is none)."""
    def increments(perturb: bool) -> np.ndarray:
        front, out = LaserOdometry(SLAMConfig().frontend), []
        for i, frame in enumerate(frames):
            if perturb and i == at:
                # as bench --perturb moves a scan: its returns only
                frame = dataclasses.replace(frame, scan=perturb_scan(frame.scan, np.random.default_rng(0), 0.001))
            step = front.step(frame)
            out.append(np.full(3, np.nan) if step.increment is None else step.increment)
        return np.array(out)

    d = increments(False) - increments(True)
    d[:, 2] = wrap_angle(d[:, 2])
    return d


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("--scans", type=int, default=400, help="scans of the log to use (default 400)")
    parser.add_argument("--nudge-m", type=float, default=0.0005, help="σ of the guesses' nudge (m)")
    parser.add_argument("--from-scan", type=int, default=100, help="the scan whose ranges the growth test moves")
    args = parser.parse_args()
    frames = [frame for _, frame in zip(range(args.scans), open_dataset(args.log))]

    spread = knife_edges(frames, args.nudge_m)
    print(f"{args.log.name}: {spread.shape[0]} matches with guesses nudged by {1000 * args.nudge_m:g} mm: "
          f"{100 * np.mean(spread[:, 0] > 0.005):.1f} % spread > 5 mm, {100 * np.mean(spread[:, 0] > 0.02):.1f} % "
          f"> 20 mm, {100 * np.mean(spread[:, 1] > np.radians(0.05)):.1f} % > 0.05° in heading; "
          f"median {1000 * np.median(spread[:, 0]):.3f} mm")

    jumps = range_jumps(frames)
    heading = np.degrees(jumps[:, 1])
    print(f"{jumps.shape[0]} matches with the ranges moved by 1 mm: heading median {np.median(heading):.4f}°, "
          f"90th percentile {np.quantile(heading, 0.9):.4f}°, largest {heading.max():.3f}°, "
          f"RMS {np.sqrt(np.mean(heading ** 2)):.4f}°; position 90th percentile {1000 * np.quantile(jumps[:, 0], 0.9):.2f} mm")

    d = growth(frames, args.from_scan)
    moved = np.hypot(d[:, 0], d[:, 1])
    print(f"1 mm of noise on scan {args.from_scan}: largest increment difference (mm, °) per 10 scans after it")
    for start in range(args.from_scan, min(args.from_scan + 60, len(frames)), 10):
        window = slice(start, min(start + 10, len(frames)))
        print(f"  scans {start:4d}–{min(start + 10, len(frames)) - 1:4d}: {1000 * np.nanmax(moved[window]):8.3f} mm "
              f"{np.degrees(np.nanmax(np.abs(d[window, 2]))):7.4f}°")


if __name__ == "__main__":
    main()
