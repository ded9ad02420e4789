"""Pose NEES of the paper's filter down long simulated corridors, the figure the consistency
issue targets (time-averaged NEES ≤ 4.5), with each of the filter's options that bear on it.

    python benchmarks/corridor_consistency.py [--seeds N] [--plot PNG | --defaults [--workers W] [--second-order]]

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


def run_errors(base: SLAMConfig, world, steps, estimator: str, extend: bool, seed: int, bends: bool = False):
    """The pose errors (:func:`bsslam.eval.consistency.pose_errors`) of one seeded run."""
    sim = SimConfig()
    config = simulation_config(base.replace(estimator=estimator), sim).replace(backend="ekf")
    config = config.replace(mapping=dataclasses.replace(config.mapping, extend=extend),
                            observation=dataclasses.replace(config.observation, significant_bends_only=bends))
    data = simulate(world, sim, seed=seed, steps=steps)
    return pose_errors(run_dataset(data, config, point_stride=0).estimate, data.ground_truth)


def one(base: SLAMConfig, world, steps, estimator: str, extend: bool, seed: int,
        bends: bool = False) -> tuple[float, float, float]:
    """(time-averaged NEES, final position error m, final σ_φ rad) of one seeded run."""
    errors = run_errors(base, world, steps, estimator, extend, seed, bends)
    # step 0 has no uncertainty (it fixes the map frame)
    return float(np.mean(errors.nees[1:])), float(np.hypot(*errors.errors[-1, :2])), float(errors.sigmas[-1, 2])


def plot(path: str, seeds: int) -> None:
    """Pose NEES against the step down the 80 × 50 m loop at the defaults (extension on),
    the paper's EKF beside the invariant EKF, each with the paper's update and with
    significant bends only: every seed's run thin, their mean thick, the 95 % band of one
    run's 3-dof NEES shaded."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.stats import chi2

    base, world, steps = setups()["defaults"]
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5), sharey=True)
    for ax, estimator in zip(axes, ("ekf", "invariant")):
        for bends, colour in ((False, "tab:red"), (True, "tab:blue")):
            runs = np.array([run_errors(base, world, steps, estimator, True, seed, bends).nees[1:]
                             for seed in range(seeds)])
            for r in runs:
                ax.plot(np.arange(1, r.size + 1), r, color=colour, lw=0.4, alpha=0.4)
            ax.plot(np.arange(1, runs.shape[1] + 1), runs.mean(axis=0), color=colour, lw=1.6,
                    label=f"{'significant bends only' if bends else 'paper update'} (mean {runs.mean():.1f})")
        ax.axhspan(*chi2.ppf([0.025, 0.975], 3), color="0.85", zorder=0)
        ax.set_yscale("log")
        ax.set_title({"ekf": "the paper's EKF", "invariant": "invariant EKF"}[estimator])
        ax.set_xlabel("step")
        ax.legend(loc="upper left", fontsize=8)
    axes[0].set_ylabel("pose NEES (3 dof)")
    fig.suptitle(f"80 × 50 m corridor loop, defaults (ρ = 1 m, extension on), {seeds} seeds")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _defaults_base(second_order: bool) -> tuple[SLAMConfig, object, int | None]:
    base, world, steps = setups()["defaults"]
    if second_order:
        base = base.replace(observation=dataclasses.replace(base.observation, second_order=True))
    return base, world, steps


def _defaults_run(seed: int, second_order: bool = False) -> tuple[float, float, float]:
    base, world, steps = _defaults_base(second_order)
    return one(base, world, steps, base.estimator, base.mapping.extend, seed, base.observation.significant_bends_only)


def defaults_only(seeds: int, workers: int, second_order: bool = False) -> None:
    """The issue's figure: the library's defaults (its estimator, extension and update) in the
    80 × 50 m loop, seed by seed, ``workers`` runs at a time; with ``second_order``, and
    ``observation.second_order`` on."""
    import functools
    from multiprocessing import Pool

    with Pool(workers) as pool:
        runs = np.array(pool.map(functools.partial(_defaults_run, second_order=second_order), range(seeds),
                                 chunksize=1))
    base = _defaults_base(second_order)[0]
    print(f"80 × 50 m loop, the defaults ({base.estimator}, extension {'on' if base.mapping.extend else 'off'}, "
          f"significant bends only {'on' if base.observation.significant_bends_only else 'off'}, "
          f"second order {'on' if base.observation.second_order else 'off'}), seeds 0–{seeds - 1}")
    print(f"time-averaged pose NEES: mean {runs[:, 0].mean():.1f}, median {np.median(runs[:, 0]):.1f} "
          f"(3.0 if consistent); per seed {', '.join(f'{v:.1f}' for v in runs[:, 0])}")
    print(f"final position error: median {np.median(runs[:, 1]):.2f} m")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=3, help="runs per row (seeds 0 … N−1)")
    ap.add_argument("--plot", metavar="PNG", help="instead of the table, draw the NEES over the steps of the "
                    "defaults loop for the paper's EKF and the invariant EKF side by side")
    ap.add_argument("--defaults", action="store_true", help="instead of the table, only the library's defaults "
                    "in the 80 × 50 m loop, seed by seed")
    ap.add_argument("--workers", type=int, default=1, help="runs at a time with --defaults")
    ap.add_argument("--second-order", action="store_true",
                    help="with --defaults: and observation.second_order on (the ranges' second-order error)")
    args = ap.parse_args()
    if args.plot:
        plot(args.plot, args.seeds)
        return
    if args.defaults:
        defaults_only(args.seeds, args.workers, args.second_order)
        return
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
