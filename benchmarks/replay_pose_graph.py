"""One run's pose graph solved again with each guard against wrong loop closures.

    python benchmarks/replay_pose_graph.py LOG [--seed N] [--reference LOG.gt.txt] [--config X.yaml]

A benchmark, not a test. It runs LOG once with the submap backend (the default
configuration or ``--config``'s, no second pass; ``--seed`` moves every range by 1 mm of
seeded noise, as ``bsslam bench --perturb``), keeps the submaps' odometry-like constraints
and every accepted loop closure, then builds the pose graph again from them, in the run's
order, with ``loop_outliers`` = ``cauchy``, ``gnc`` and ``none`` (every loop closure a
plain Gaussian), and with no loop closure at all; and with ``gnc`` and a heading drift rate
all seams share (``--drift-rate-sigma``, rad/m; ``submaps.drift_rate_sigma_rad_per_m``).
For each it prints the time spent in the graph (one process, one after the other: compare
them as ratios) and, with a reference, the ATE of
the submap bases (the reference pose at each base's scan) and how many of the loop
closures it keeps are wrong (off by more than 0.3 m + 5 m/rad × heading error against the
reference). With a reference it also solves with only the right loop closures: what a
perfect guard would give.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.eval.alignment import align_rigid_2d
from bsslam.eval.association import nearest_stamps
from bsslam.io import open_dataset
from bsslam.io.config_file import load_config
from bsslam.io.trajectory_file import read_trajectory
from bsslam.perturbed_dataset import PerturbedDataset
from bsslam.pipeline import run_dataset
from bsslam.se2 import between
from bsslam.submaps.backend import _proper
from bsslam.submaps.pose_graph import PoseGraph
from bsslam.trajectory import wrap_angle

#: A loop closure is wrong when its translation error + this × its heading error (m, rad)
#: exceeds WRONG_M.
HEADING_WEIGHT_M = 5.0
WRONG_M = 0.3


def rigid_ate(estimate: np.ndarray, reference: np.ndarray) -> float:
    """RMS position error (m) of (n, 2) points after the best rigid 2D alignment."""
    rotation, translation = align_rigid_2d(estimate, reference)
    return float(np.sqrt(np.mean(np.sum((estimate @ rotation.T + translation - reference) ** 2, axis=1))))


def solve(edges, loops, guard: str | None, distances=None, drift_rate_sigma: float = 0.0) -> tuple[PoseGraph, float]:
    """The graph rebuilt in the run's order: a node per submap, each submap's loop
    closures added and optimised once its node is in. Returns it and its seconds."""
    start = time.perf_counter()
    graph = PoseGraph(np.zeros(3), loop_outliers=guard, drift_rate_sigma=drift_rate_sigma)
    graph.optimize()
    by_query: dict[int, list] = {}
    for loop in loops:
        by_query.setdefault(loop.query, []).append(loop)
    distances = np.zeros(len(edges)) if distances is None else distances
    for k, (pose, covariance) in enumerate(edges):
        graph.add_node(pose, _proper(covariance), distances[k])
        for loop in by_query.get(k + 1, []):
            graph.add_loop(loop.reference, loop.query, loop.relative, _proper(loop.covariance, 5.0))
        graph.optimize()
    return graph, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path)
    parser.add_argument("--seed", type=int, default=None, help="1 mm of range noise with this seed")
    parser.add_argument("--reference", type=Path, default=None, help="default: LOG with .gt.txt if it exists")
    parser.add_argument("--config", type=Path, help="a YAML configuration for the run (the replays are as described)")
    parser.add_argument("--drift-rate-sigma", type=float, default=5e-4,
                        help="σ (rad/m) of the seams' shared heading drift rate in the last variant")
    args = parser.parse_args()

    dataset = open_dataset(args.log)
    if args.seed is not None:
        dataset = PerturbedDataset(dataset, 0.001, args.seed)
    config = load_config(args.config) if args.config else SLAMConfig()
    result = run_dataset(dataset, config.replace(backend="submaps", relocalize=False))
    slam = result.submaps
    edges = [(f.end_pose, f.end_covariance) for f in slam.frozen]
    distances = slam.graph.distances
    loops = list(slam.loops)
    print(f"{args.log.name}{'' if args.seed is None else f' (seed {args.seed})'}: {len(edges) + 1} submap "
          f"bases, {len(loops)} loop closures")

    reference_path = args.reference or args.log.with_suffix(".gt.txt")
    truth = wrong = None
    if reference_path.exists():
        ref = read_trajectory(reference_path)
        sub = result.step_submaps
        # base k is the pose of the scan that ended submap k − 1 (the first scan for k = 0)
        records = [0] + [int(np.flatnonzero(sub == k - 1)[-1]) for k in range(1, len(edges) + 1)]
        index = nearest_stamps(ref.stamps, result.estimate.stamps[records], 0.05)
        truth = np.where((index >= 0)[:, None], ref.poses[np.maximum(index, 0)], np.nan)
        known = np.all(np.isfinite(truth), axis=1)
        wrong = np.zeros(len(loops), dtype=bool)
        for m, loop in enumerate(loops):
            if known[loop.reference] and known[loop.query]:
                e = loop.relative - between(truth[loop.reference], truth[loop.query])
                e[2] = wrap_angle(e[2])
                wrong[m] = np.hypot(e[0], e[1]) + HEADING_WEIGHT_M * abs(e[2]) > WRONG_M
        print(f"  wrong loop closures against the reference: {int(wrong.sum())}")

    variants = [("cauchy", loops, "cauchy", 0.0), ("gnc", loops, "gnc", 0.0), ("none (all Gaussian)", loops, None, 0.0),
                ("no loop closure", [], None, 0.0), ("gnc, shared drift rate", loops, "gnc", args.drift_rate_sigma)]
    if wrong is not None:
        variants.append(("only the right ones", [lp for lp, w in zip(loops, wrong) if not w], None, 0.0))
    for name, subset, guard, sigma in variants:
        graph, seconds = solve(edges, subset, guard, distances, sigma)
        line = f"  {name:22s} graph {seconds:6.2f} s"
        if truth is not None:
            known = np.all(np.isfinite(truth), axis=1)
            line += f"   base ATE {rigid_ate(graph.poses()[known, :2], truth[known, :2]):6.3f} m"
            if subset is loops and loops:
                kept = graph.loop_weights() >= 0.5
                line += f"   kept {int(kept.sum())}/{len(loops)}, of them wrong {int(np.sum(kept & wrong))}"
        if sigma > 0:
            rate, rate_sigma = graph.drift_rate()
            line += f"   rate {np.degrees(rate) * 100:+.2f} ± {np.degrees(rate_sigma) * 100:.2f}°/100 m"
        print(line)


if __name__ == "__main__":
    main()
