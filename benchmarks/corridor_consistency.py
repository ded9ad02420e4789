"""Pose NEES of the paper's filter down long simulated corridors, the figure the consistency
issue targets (time-averaged NEES ≤ 4.5), with each of the filter's options that bear on it.

    python benchmarks/corridor_consistency.py [--seeds N]

The two corridor loops of ``bench_filter.py`` (the global EKF, simulated odometry under the
paper's motion model, no front end, no second pass: ``simulation_config``):

* ``defaults``: the library's spline and mapping settings (ρ = 1 m, extension on) in the
  80 × 50 m loop driven once (1200 scans);
* ``rho-0.2``: ρ = 0.2 m without extension in the 30 × 20 m loop driven twice;

each with the paper's EKF, the observability-constrained EKF and the invariant EKF, with spline extension on
and off, and with ``observation.significant_bends_only`` off (the paper's update) and on. For each: the pose NEES (3 dof, exact ground truth, no alignment)
averaged over the steps and over ``--seeds`` runs (3.0 if consistent), the final position
error and the final heading σ. A benchmark, not a test: it prints figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from bsslam.config import MappingConfig, SLAMConfig, SplineConfig
from bsslam.eval.consistency import pose_errors
from bsslam.experiments.consistency import simulation_config
from bsslam.pipeline import run_dataset
from bsslam.sim import SimConfig, simulate
from bsslam.sim.worlds import large_corridor


def setups() -> dict[str, tuple[SLAMConfig, object, int | None]]:
    """name → (base configuration, world, steps)."""
    fine = SLAMConfig(spline=SplineConfig(degree=3, knot_spacing_m=0.2, min_knot_spacing_m=0.2),
                      mapping=MappingConfig(extend=False))
    return {"defaults": (SLAMConfig(), large_corridor(80.0, 50.0), 1200),
            "rho-0.2": (fine, large_corridor(), None)}


def one(base: SLAMConfig, world, steps, estimator: str, extend: bool, seed: int,
        bends: bool = False) -> tuple[float, float, float]:
    """(time-averaged NEES, final position error m, final σ_φ rad) of one seeded run."""
    sim = SimConfig()
    config = simulation_config(base.replace(estimator=estimator), sim).replace(backend="ekf")
    config = config.replace(mapping=dataclasses.replace(config.mapping, extend=extend),
                            observation=dataclasses.replace(config.observation, significant_bends_only=bends))
    data = simulate(world, sim, seed=seed, steps=steps)
    errors = pose_errors(run_dataset(data, config, point_stride=0).estimate, data.ground_truth)
    # step 0 has no uncertainty (it fixes the map frame)
    return float(np.mean(errors.nees[1:])), float(np.hypot(*errors.errors[-1, :2])), float(errors.sigmas[-1, 2])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3, help="runs per row (seeds 0 … N−1)")
    args = ap.parse_args()
    print(f"{'corridor':>9} {'estimator':>9} {'extension':>9} {'bends':>5} {'mean NEES':>10} {'min–max over runs':>18} "
          f"{'final error m':>14} {'final σ_φ rad':>14} {'s/run':>6}")
    for name, (base, world, steps) in setups().items():
        for estimator in ("ekf", "oc-ekf", "invariant"):
            for extend, bends in ((True, False), (True, True), (False, False), (False, True)):
                if extend and not base.mapping.extend:
                    continue   # rho-0.2 is the no-extension setting of bench_filter
                start = time.perf_counter()
                runs = np.array([one(base, world, steps, estimator, extend, seed, bends) for seed in range(args.seeds)])
                per_run = (time.perf_counter() - start) / args.seeds
                print(f"{name:>9} {estimator:>9} {'on' if extend else 'off':>9} {'on' if bends else 'off':>5} "
                      f"{runs[:, 0].mean():>10.1f} "
                      f"{runs[:, 0].min():>8.1f}–{runs[:, 0].max():<9.1f} {np.median(runs[:, 1]):>14.2f} "
                      f"{np.median(runs[:, 2]):>14.4f} {per_run:>6.0f}", flush=True)


if __name__ == "__main__":
    main()
