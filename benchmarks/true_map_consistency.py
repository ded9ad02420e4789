"""Is the filter consistent when the map is right? Localisation in a simulated world's true
walls against the double loop's SLAM runs.

    python benchmarks/true_map_consistency.py [--world corridor-loop] [--runs 20]
        [--knots 1.0] [--estimator invariant]

Each wall of the world (its segments and arcs) is fitted by a cubic spline at ``--knots``
spacing through points every 5 mm and oriented as a scan sees it (counter-clockwise about
the nearest pose of the path), and the filter localises in that fixed map
(:meth:`SplineSLAM.in_fixed_map`) with the double loop's simulated odometry and scans, the
filter configured as in ``bsslam experiment consistency --variant no-extension``. Printed:
the steps whose mean pose NEES over the runs is inside the two-sided 95 % band, the mean
NEES (3.0 if consistent) and the runs' shared bias (mean error in standard errors, RMS over
the steps; 1 if none) — to set beside the same figures of the SLAM runs, where the map is
built as the robot goes. A benchmark, not a test: it prints figures.
"""

from __future__ import annotations

import argparse

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.eval import chi2_band
from bsslam.experiments.consistency import ConsistencyResult, simulation_config, variant_config
from bsslam.se2 import between
from bsslam.sim import SimConfig, get_world, simulate
from bsslam.slam.features import MapSpline
from bsslam.slam.filter import SplineSLAM
from bsslam.spline import fit_curve
from bsslam.trajectory import wrap_angle


def true_map(world, spacing_m: float) -> list[MapSpline]:
    """The world's walls as fixed map splines, each running counter-clockwise about the
    path's pose nearest its middle (the way a scan's beams sweep it, so association can
    match it)."""
    path = world.path.sample(0.25, None)[:, :2]
    out = []
    for k, wall in enumerate(world.walls.walls):
        points = wall.points(0.005)
        middle = points[len(points) // 2]
        seen_from = path[np.argmin(np.hypot(*(path - middle).T))]
        direction = points[min(len(points) // 2 + 1, len(points) - 1)] - points[max(len(points) // 2 - 1, 0)]
        r = middle - seen_from
        if r[0] * direction[1] - r[1] * direction[0] < 0:
            points = points[::-1]
        curve = fit_curve(points, 3, spacing_m).curve
        out.append(MapSpline(k, curve, np.zeros((2 * curve.n_control,) * 2)))
    return out


def localise(world, splines, config: SLAMConfig, sim: SimConfig, seed: int):
    """(NEES (N,), errors (N, 3), σ (N, 3)) of one run localising in ``splines``."""
    data = simulate(world, sim, seed=seed)
    frames = list(data)
    truth = data.ground_truth.poses
    slam = SplineSLAM.in_fixed_map(splines, config, initial_pose=truth[0], initial_covariance=1e-10 * np.eye(3))
    slam.step(None, frames[0].scan)
    nees, errors, sigmas = [], [], []
    for i in range(1, len(frames)):
        slam.step(between(frames[i - 1].odometry, frames[i].odometry), frames[i].scan)
        e = truth[i] - slam.pose
        e[2] = wrap_angle(e[2])
        P = slam.pose_covariance
        nees.append(float(e @ np.linalg.solve(P, e)))
        errors.append(e)
        sigmas.append(np.sqrt(np.diag(P)))
    return np.array(nees), np.array(errors), np.array(sigmas)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", default="corridor-loop")
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--knots", type=float, default=1.0, help="knot spacing of the true walls' splines (m)")
    parser.add_argument("--estimator", default="invariant")
    args = parser.parse_args()
    world, sim = get_world(args.world), SimConfig()
    config = simulation_config(variant_config("no-extension", SLAMConfig(estimator=args.estimator)), sim)
    splines = true_map(world, args.knots)
    runs = [localise(world, splines, config, sim, seed) for seed in range(args.runs)]
    lower, upper = chi2_band(3, args.runs)
    result = ConsistencyResult("no-extension", args.world, mean_nees=np.mean([r[0] for r in runs], axis=0),
                               lower=lower, upper=upper, mean_errors=np.mean([r[1] for r in runs], axis=0),
                               mean_sigmas=np.mean([r[2] for r in runs], axis=0),
                               nees_runs=np.array([r[0] for r in runs]))
    bias = result.shared_bias()
    print(f"{args.world}, true walls at {args.knots:g} m knots, {args.runs} runs, {args.estimator}: "
          f"inside the band on {result.fraction_inside():.0%} of {result.mean_nees.size} steps, "
          f"mean NEES {result.mean_nees.mean():.2f}, shared bias (x, y, φ) {bias[0]:.1f}, {bias[1]:.1f}, {bias[2]:.1f}")

if __name__ == "__main__":
    main()
