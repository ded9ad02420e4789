"""Time per scan against state size, from a simulated run that grows the map past 1000
state dimensions, single-threaded; then a profile of the per-scan work at the largest size.

    python benchmarks/bench_filter.py [--steps N]
"""

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import cProfile  # noqa: E402
import pstats  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from bsslam.config import MappingConfig, SLAMConfig, SplineConfig  # noqa: E402
from bsslam.experiments.consistency import simulation_config  # noqa: E402
from bsslam.sim import SimConfig, get_world, simulate  # noqa: E402
from bsslam.slam import SplineSLAM  # noqa: E402
from bsslam.se2 import between as relative  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--world", default="mixed")
    args = ap.parse_args()
    sim = SimConfig()
    # no extension: the map grows by new splines, which is what drives the state past 1000
    base = SLAMConfig(spline=SplineConfig(degree=3, knot_spacing_m=0.2, min_knot_spacing_m=0.2),
                      mapping=MappingConfig(extend=False))
    config = simulation_config(base, sim)
    data = simulate(get_world(args.world), sim, seed=0, steps=args.steps)
    frames = list(data)
    slam = SplineSLAM(config, initial_pose=frames[0].odometry)
    sizes, times = [], []
    prev = frames[0].odometry
    for fr in frames:
        delta = relative(prev, fr.odometry)
        prev = fr.odometry
        t0 = time.perf_counter()
        slam.step(delta, fr.scan)
        times.append(time.perf_counter() - t0)
        sizes.append(slam.state_size)
    sizes, times = np.array(sizes), np.array(times) * 1000
    print(f"world {args.world}: {len(frames)} scans, final state size {sizes[-1]}, {len(slam.features)} splines")
    print(f"{'state size':>14} {'scans':>6} {'median ms/scan':>15} {'p90 ms/scan':>12}")
    edges = [0, 250, 500, 750, 1000, 1250, 1500, 2000, 3000, 10**9]
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (sizes >= lo) & (sizes < hi)
        if sel.sum() >= 3:
            print(f"{lo:>6}–{min(hi, sizes.max()):<7} {sel.sum():>6} {np.median(times[sel]):>15.2f} {np.percentile(times[sel], 90):>12.2f}")
    # profile the last 40 scans again from a copy of the state at that point
    k = max(0, len(frames) - 40)
    slam2 = SplineSLAM(config, initial_pose=frames[0].odometry)
    prev = frames[0].odometry
    for fr in frames[:k]:
        slam2.step(relative(prev, fr.odometry), fr.scan)
        prev = fr.odometry
    prof = cProfile.Profile()
    prof.enable()
    for fr in frames[k:]:
        slam2.step(relative(prev, fr.odometry), fr.scan)
        prev = fr.odometry
    prof.disable()
    print(f"\nprofile of the last {len(frames) - k} scans (state size {slam2.state_size}):")
    pstats.Stats(prof).sort_stats("cumulative").print_stats(20)


if __name__ == "__main__":
    main()
