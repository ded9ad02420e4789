"""How much of each scan the filter can see: the share of the valid beams that the
segmentation puts into a spline.

    python benchmarks/scan_coverage.py LOG [LOG ...] [--every K] [--config X.yaml]

A benchmark, not a test (prints figures, asserts nothing). The filter's map and its
updates are made only of the beams in the splines fitted to a scan (segments of at least
``segmentation.min_points`` points and ``min_length_m``, cut where the direction (α_max) and
spacing (η) tests or ``max_gap_m`` say a wall ends); the front end matches every point.
For every K-th scan of each LOG (default 5) this prints the share of the valid beams that
end in a spline, the splines per scan, the median range of the valid beams (m) and the
segmenter's counts per scan (gap cuts, shape cuts, runs rejected as too short). What a
whole run then updates with is in its ``summary.json``: ``beams_used`` over
``filter_steps`` beams a filter step (after association, the grazing limit and the gates).

What the shared logs gave is in docs/real_logs.md ("How much of a scan the filter sees").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.io import open_dataset
from bsslam.io.config_file import load_config
from bsslam.scan import extract_splines
from bsslam.scan.segment import valid_beams


def coverage(log: Path, config: SLAMConfig, every: int) -> str:
    """One table row for ``log``: its every-th scans segmented under ``config``."""
    valid = in_splines = splines = scans = 0
    counts = {"gap_cuts": 0, "shape_cuts": 0, "rejected_segments": 0}
    ranges = []
    for i, frame in enumerate(open_dataset(log)):
        if i % every:
            continue
        features = extract_splines(frame.scan, config)
        mask, _ = valid_beams(frame.scan, config.segmentation)
        valid += int(np.count_nonzero(mask))
        in_splines += sum(s.beam_indices.shape[0] for s in features.splines)
        splines += len(features.splines)
        scans += 1
        for key in counts:
            counts[key] += features.counts.get(key, 0)
        if mask.any():
            ranges.append(float(np.median(frame.scan.ranges[mask])))
    if scans == 0 or valid == 0:
        return f"| {log.name} | {scans} | no valid beam |"
    per_scan = " / ".join(f"{counts[k] / scans:.1f}" for k in counts)
    return (f"| {log.name} | {scans} | {in_splines / valid:.2f} | {splines / scans:.1f} | "
            f"{np.median(ranges):.1f} | {per_scan} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="+", type=Path, help="laser logs (CARMEN or bags)")
    parser.add_argument("--every", type=int, default=5, help="segment every K-th scan (default 5)")
    parser.add_argument("--config", type=Path, help="a YAML configuration (e.g. other segmentation settings)")
    args = parser.parse_args()
    if args.every < 1:
        parser.error("--every must be ≥ 1")
    config = load_config(args.config) if args.config else SLAMConfig()
    print("| log | scans | share of valid beams in splines | splines a scan | median range (m) | "
          "gap cuts / shape cuts / runs rejected, a scan |")
    print("|---|---|---|---|---|---|")
    for log in args.logs:
        print(coverage(log, config, args.every), flush=True)


if __name__ == "__main__":
    main()
