"""Is the submap graph's covariance honest, and can a run tell by itself?

    python benchmarks/graph_consistency.py LOG [LOG ...] [--seed N] [--reference-sigma 0.03,0.5]

A benchmark, not a test. It runs each LOG once with the default configuration (no second
pass; ``--seed`` moves every range by 1 mm of seeded noise, as ``bsslam bench --perturb``)
and compares the pose graph's constraints with what they claim, two ways:

- **Against the reference** (``LOG`` with ``.gt.txt`` for ``.clf``, the reference's own σ
  added at both ends): the median NEES of the seams (each submap's base seen from the one
  before) with the local filter's covariance alone and with the drift the backend adds
  (``submaps.seam_drift_*``), and of the loop closures the graph keeps; and the share of
  each beyond the χ²(3) 95 % quantile (7.81). Calibrated: median 2.37, 5 % beyond.
- **From inside the run**, with no reference: the graph's a-posteriori variance factor
  (χ² of the solved graph over its redundancy, 3 per kept loop closure; 1 if its
  covariances are right), and each kept loop closure's innovation against the chain of
  seams between its submaps (median NIS with and without the drift; 3 if right), and the
  drift scale that makes those innovations most likely.

If the inside figures tracked the reference ones, a run could calibrate its drift from its
own loop closures. README, Limits, says what they gave on the shared logs.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar

import bsslam.submaps.backend as backend
from bsslam.config import SLAMConfig
from bsslam.eval.association import nearest_stamps
from bsslam.io import open_dataset
from bsslam.io.trajectory_file import read_trajectory
from bsslam.perturbed_dataset import PerturbedDataset
from bsslam.pipeline import run_dataset
from bsslam.se2 import between, compose, compose_jacobians
from bsslam.trajectory import wrap_angle

#: χ²(3) at 95 %.
CHI2_95 = 7.815


def run_recording_seams(log: Path, seed: int | None, config: SLAMConfig):
    """One run; returns it and, per frozen submap, the local filter's end covariance (3, 3)
    as the backend's ``seam_covariance`` saw it (the frozen submap keeps only the sum with
    the drift)."""
    seams: list[np.ndarray] = []
    original = backend.seam_covariance

    def recording(filter_covariance, distance_m, cfg):
        seams.append(np.array(filter_covariance, dtype=float))
        return original(filter_covariance, distance_m, cfg)

    backend.seam_covariance = recording
    try:
        result = run_log(log, seed, config)
    finally:
        backend.seam_covariance = original
    return result, seams


def run_log(log: Path, seed: int | None, config: SLAMConfig):
    """One run of ``log`` without the pictures' points; with ``seed``, every range moved by
    1 mm of seeded noise (as ``bsslam bench --perturb``)."""
    data = open_dataset(log)
    if seed is not None:
        data = PerturbedDataset(data, 0.001, seed)
    return run_dataset(data, config, point_stride=0)


def nees(error: np.ndarray, covariance: np.ndarray) -> float:
    return float(error @ np.linalg.solve(covariance, error))


def median_and_beyond(values: list[float]) -> str:
    if not values:
        return "–"
    v = np.asarray(values)
    return f"{np.median(v):.2f}, {100 * np.mean(v > CHI2_95):.0f} %"


def reference_bases(result, log: Path):
    """The reference trajectory (``LOG.gt.txt``) of a submap run and, per submap base, the
    index of its reference pose (−1 where none lies within 50 ms): a base is the scan its
    submap started at, the last step of the submap before it (the first scan for base 0)."""
    steps = np.asarray(result.step_submaps)
    base_step = [0] + [int(np.flatnonzero(steps == k)[-1]) for k in range(len(result.submaps.frozen))]
    reference = read_trajectory(log.with_suffix(".gt.txt"))
    return reference, nearest_stamps(reference.stamps, result.estimate.stamps[base_step], 0.05)


def report(log: Path, seed: int | None, reference_sigma: tuple[float, float]) -> None:
    config = SLAMConfig()
    result, seams = run_recording_seams(log, seed, config)
    submaps = result.submaps
    if submaps is None or not submaps.frozen:
        print(f"{log.name}: no frozen submap")
        return
    frozen = submaps.frozen
    # what the backend added to each seam for the distance travelled in the submap
    drift = [f.end_covariance - alone for f, alone in zip(frozen, seams)]
    weights = submaps.loop_weights()
    kept = [loop for loop, w in zip(submaps.loops, weights) if w > 0.5]

    reference, index = reference_bases(result, log)
    ref_var = np.square([reference_sigma[0], reference_sigma[0], math.radians(reference_sigma[1])])
    ref_cov = np.diag(2 * ref_var)                 # the reference's error at both ends

    def against_reference(i: int, j: int, relative: np.ndarray, covariance: np.ndarray) -> float | None:
        if index[i] < 0 or index[j] < 0:
            return None
        error = relative - between(reference.poses[index[i]], reference.poses[index[j]])
        error[2] = wrap_angle(error[2])
        return nees(error, covariance + ref_cov)

    seam_alone, seam_drift = [], []
    # the last submap froze at the end of the run: no scan starts from its end pose (its
    # "successor's base" would be the last scan, not the filter step it ended at)
    last = len(frozen) - 1 if np.asarray(result.step_submaps).max() == len(frozen) - 1 else len(frozen)
    for f in frozen:
        if f.index >= last or f.index >= len(seams):
            continue
        a = against_reference(f.index, f.index + 1, f.end_pose, seams[f.index])
        b = against_reference(f.index, f.index + 1, f.end_pose, f.end_covariance)
        if a is not None:
            seam_alone.append(a)
            seam_drift.append(b)
    loop_nees = [x for x in (against_reference(lp.reference, lp.query, lp.relative, lp.covariance) for lp in kept)
                 if x is not None]

    # inside the run: the graph's variance factor …
    chi2 = submaps.graph.solution_chi2()
    redundancy = 3 * len(kept)
    # … and each loop closure's innovation against the chain of seams between its submaps
    innovations = []
    for lp in kept:
        pose, alone, added = np.zeros(3), np.zeros((3, 3)), np.zeros((3, 3))
        for f in range(lp.reference, lp.query):
            ja, jb = compose_jacobians(pose, frozen[f].end_pose)
            alone = ja @ alone @ ja.T + jb @ seams[f] @ jb.T
            added = ja @ added @ ja.T + jb @ drift[f] @ jb.T
            pose = compose(pose, frozen[f].end_pose)
        nu = lp.relative - pose
        nu[2] = wrap_angle(nu[2])
        innovations.append((nu, alone, added, np.asarray(lp.covariance)))

    def nis(scale: float) -> np.ndarray:
        return np.array([nees(nu, a + scale * d + c) for nu, a, d, c in innovations])

    def negative_log_likelihood(log_scale: float) -> float:
        s = math.exp(log_scale)
        return sum(0.5 * (np.linalg.slogdet(a + s * d + c)[1] + nees(nu, a + s * d + c))
                   for nu, a, d, c in innovations)

    if innovations:
        low = -8.0
        fit = minimize_scalar(negative_log_likelihood, bounds=(low, 4.0), method="bounded").x
        best = f"{math.exp(fit):.2g}" if fit > low + 0.01 else f"< {math.exp(low + 0.01):.1g}"
        inside = f"{chi2 / redundancy:.2f} | {np.median(nis(1.0)):.2f} / {np.median(nis(0.0)):.2f} | {best}"
    else:
        inside = "– | – | –"
    name = log.name + ("" if seed is None else f" (seed {seed})")
    print(f"| {name} | {median_and_beyond(seam_alone)} | {median_and_beyond(seam_drift)} | "
          f"{median_and_beyond(loop_nees)} ({len(loop_nees)}) | {inside} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("logs", nargs="+", type=Path, help="CARMEN logs with a .gt.txt reference beside them")
    parser.add_argument("--seed", type=int, default=None, help="1 mm of range noise with this seed")
    parser.add_argument("--reference-sigma", default="0.03,0.5",
                        help="the reference's own σ: metres, degrees (default 0.03,0.5)")
    args = parser.parse_args()
    sxy, sphi = (float(v) for v in args.reference_sigma.split(","))
    print("| log | seams vs reference, filter's covariance: median NEES, beyond 95 % | … with the drift | "
          "kept loop closures vs reference (count) | graph's variance factor | loop NIS along the seams, "
          "with / without the drift | most likely drift scale |")
    print("|---|---|---|---|---|---|---|")
    for log in args.logs:
        report(log, args.seed, (sxy, sphi))


if __name__ == "__main__":
    main()
