"""Per-scan cost of turning a real laser scan into observed splines (not a test: prints
figures, asserts nothing).

The first ``--scans`` scans (180 beams, 1°) of the Intel Research Lab log are read once;
then each is passed ``--repeat`` times through

- ``segment``: valid beams → points → segmentation (``bsslam.scan.segment``), and
- ``extract``: the same plus one least-squares spline per segment (``extract_splines``,
  cubic, knot spacing from the default configuration), and
- ``fit``: ``fit_curve`` alone on those segments' points (per call),

single-threaded. Reported: the median over scans of each scan's best time (the best of
the repeats filters out scheduler noise; the median over scans is the typical scan), the
mean, and the segments and splines found per scan. Target: extract < 2 ms per scan.

Run:  python benchmarks/bench_segment.py [--log PATH] [--scans 200] [--repeat 5]
"""

from __future__ import annotations

import os

# Single-threaded BLAS, before numpy is imported: the figure must not depend on cores.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import itertools  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from bsslam.config import SLAMConfig  # noqa: E402
from bsslam.io.carmen import CarmenReader  # noqa: E402
from bsslam.errors import FitError  # noqa: E402
from bsslam.scan import beams_to_points, extract_splines, segment_points, valid_beams  # noqa: E402
from bsslam.spline import fit_curve  # noqa: E402

DEFAULT_LOG = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "intel" / "intel-rawodom.clf"


def segment_only(scan, config: SLAMConfig) -> list[np.ndarray]:
    mask, _ = valid_beams(scan, config.segmentation)
    beam_index = np.flatnonzero(mask)
    points = beams_to_points(scan.angles[beam_index], scan.ranges[beam_index])
    return segment_points(points, config.segmentation, beam_index=beam_index)


def _fit_or_none(points: np.ndarray, config: SLAMConfig):
    """``fit_curve`` as ``extract_splines`` calls it; None where it fails."""
    try:
        return fit_curve(points, config.spline.degree, config.spline.knot_spacing_m,
                         max_noise_gain=config.spline.max_noise_gain)
    except FitError:
        return None


def per_scan_best_ms(call, scans, repeat: int) -> list[float]:
    """For each scan (or other argument), the fastest of ``repeat`` calls (ms)."""
    best = []
    for scan in scans:
        times = []
        for _ in range(repeat):
            start = time.perf_counter()
            call(scan)
            times.append(time.perf_counter() - start)
        best.append(1e3 * min(times))
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--log", type=Path, default=DEFAULT_LOG)
    parser.add_argument("--scans", type=int, default=200)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    if not args.log.exists():
        raise SystemExit(f"log not found: {args.log}")

    config = SLAMConfig()
    scans = [frame.scan for frame in itertools.islice(CarmenReader(args.log), args.scans)]
    for scan in scans[:10]:  # warm-up: imports, caches
        extract_splines(scan, config)

    seg_ms = per_scan_best_ms(lambda s: segment_only(s, config), scans, args.repeat)
    ext_ms = per_scan_best_ms(lambda s: extract_splines(s, config), scans, args.repeat)
    runs = [beams_to_points(s.angles[mask], s.ranges[mask])[rows]
            for s in scans for mask in [valid_beams(s, config.segmentation)[0]]
            for rows in segment_only(s, config)]
    fit_us = [1e3 * t for t in per_scan_best_ms(lambda pts: _fit_or_none(pts, config), runs, args.repeat)]
    segments = [len(segment_only(s, config)) for s in scans]
    splines = [len(extract_splines(s, config).splines) for s in scans]

    print(f"{len(scans)} scans of {args.log.name} ({scans[0].ranges.shape[0]} beams), "
          f"best of {args.repeat}, single-threaded")
    print(f"  segment  median {statistics.median(seg_ms):.3f} ms/scan   mean {statistics.fmean(seg_ms):.3f} ms")
    print(f"  extract  median {statistics.median(ext_ms):.3f} ms/scan   mean {statistics.fmean(ext_ms):.3f} ms"
          f"   (target < 2 ms)")
    print(f"  fit      median {statistics.median(fit_us):.1f} µs/call   mean {statistics.fmean(fit_us):.1f} µs"
          f"   ({len(runs)} segments)")
    print(f"  per scan: {statistics.fmean(segments):.2f} segments, {statistics.fmean(splines):.2f} splines")


if __name__ == "__main__":
    main()
