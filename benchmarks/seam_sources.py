"""Where the submap graph's seams go wrong: the local filter's end pose against the front
end's own increments over the same scans, and the heading drift both share.

    python benchmarks/seam_sources.py LOG [LOG ...] [--seeds 0 1 2]

A benchmark, not a test (prints figures, asserts nothing). Each LOG (with ``.gt.txt``
beside it) runs once per seed with the default configuration, every range moved by 1 mm
of seeded noise (as ``bsslam bench --perturb``). A *seam* is a submap's base seen from the
one before: the local filter's pose when its submap froze, which the pose graph holds as
the odometry-like constraint between the two (the seams whose two bases have a reference
pose within 50 ms count; the last submap's, frozen at the end of the run, does not: no
scan is placed by it). Per run it prints:

- **seam errors** against the reference, for the filter's end pose, for the front end's
  increments chained over the same scans (no map), and for the raw odometry: median
  translation error (m) and RMS heading error (°) over the seams;
- **heading drift** (° per 100 m of path): the seams' heading errors summed over the path
  they span, for the filter and for the front end — a drift both share is one the graph
  cannot remove without a loop closure;
- **bases chained** through the seams alone (no loop closure), RMS position error after
  the best rigid fit (m), with the filter's seams and with the front end's;
- **ATE** of the run's trajectory, and with a linear heading drift of c ° per 100 m of
  path taken out of it (each step's heading turned by c × its length), for the c in
  −2…2 that minimises it: how much of the error that one drift explains;
- **the filter's own say** in each seam's heading: its seam less the front end's chain
  over the same scans (what the spline updates changed), RMS (°), and its correlation
  with the front end's error. Pooled over every run at the end, with the RMS heading error
  of the front end's chain plus w × that correction for w = 0, ½, 1: where the updates
  correct the front end the correlation is negative and some w < 1 … 1 does best; where
  they only add their own error it is near 0 and w = 0 does.

What the shared logs gave is in docs/real_logs.md ("Where the seams' error comes from").
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.eval.alignment import align_rigid_2d
from bsslam.eval.trajectory_error import ate
from bsslam.se2 import between, compose
from bsslam.trajectory import Trajectory, wrap_angle

sys.path.insert(0, str(Path(__file__).resolve().parent))
from graph_consistency import reference_bases, run_log  # noqa: E402

#: the linear heading drifts tried (° per 100 m of path)
DRIFTS = np.round(np.arange(-2.0, 2.01, 0.25), 2)


def seam_relatives(poses: np.ndarray, base_step: list[int]) -> np.ndarray:
    """(k, 3) the relative pose between consecutive base scans of a trajectory's poses."""
    return np.array([between(poses[a], poses[b]) for a, b in zip(base_step[:-1], base_step[1:])])


def chained(relatives: np.ndarray) -> np.ndarray:
    """(k + 1, 3) poses from the origin through the relative poses."""
    out = [np.zeros(3)]
    for r in relatives:
        out.append(compose(out[-1], r))
    return np.array(out)


def rigid_rms(est_xy: np.ndarray, ref_xy: np.ndarray) -> float:
    rotation, translation = align_rigid_2d(est_xy, ref_xy)
    return float(np.sqrt(np.mean(np.sum((est_xy @ rotation.T + translation - ref_xy) ** 2, axis=1))))


def without_drift(trajectory: Trajectory, deg_per_100m: float) -> Trajectory:
    """The trajectory with each step's heading turned by ``deg_per_100m`` × its length."""
    poses = trajectory.poses
    out = [poses[0]]
    rate = math.radians(deg_per_100m) / 100.0
    for a, b in zip(poses[:-1], poses[1:]):
        step = between(a, b).copy()
        step[2] += rate * math.hypot(step[0], step[1])
        out.append(compose(out[-1], step))
    return Trajectory(trajectory.stamps, np.array(out))


def report(log: Path, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Print one run's row; return the filter's heading correction over the front end and
    the front end's heading error (rad) of each seam kept, both (k,)."""
    result = run_log(log, seed, SLAMConfig())
    submaps = result.submaps
    none = (np.zeros(0), np.zeros(0))
    if submaps is None or not submaps.frozen:
        print(f"| {log.name} | {seed} | no frozen submap |")
        return none
    steps = np.asarray(result.step_submaps)
    base_step = [0] + [int(np.flatnonzero(steps == k)[-1]) for k in range(len(submaps.frozen))]
    reference, index = reference_bases(result, log)
    truth_poses = reference.poses[np.maximum(index, 0)]
    truth = seam_relatives(truth_poses, list(range(len(index))))
    sources = {
        "filter": np.array([f.end_pose for f in submaps.frozen]),
        "front end": seam_relatives(result.frontend.poses, base_step),
        "odometry": seam_relatives(result.odometry.poses, base_step),
    }
    keep = (index[:-1] >= 0) & (index[1:] >= 0)
    if steps.max() == len(submaps.frozen) - 1:
        # the last submap froze at the end of the run: no scan starts from its end pose, so
        # the graph places nothing by that seam (and the online pose there is not what the
        # second pass gives)
        keep[-1] = False
    if not np.any(keep):
        print(f"| {log.name} | {seed} | no seam with a reference pose at both ends |")
        return none
    length = np.hypot(truth[keep, 0], truth[keep, 1])
    cells = []
    drift = {}
    errors = {}
    for name, rel in sources.items():
        err = rel[keep] - truth[keep]
        err[:, 2] = wrap_angle(err[:, 2])
        errors[name] = err[:, 2]
        cells.append(f"{np.median(np.hypot(err[:, 0], err[:, 1])):.3f} m, {rms_degrees(err[:, 2]):.2f}°")
        drift[name] = 100 * math.degrees(np.sum(err[:, 2])) / np.sum(length)
    ok = index >= 0
    chains = {name: rigid_rms(chained(sources[name])[ok, :2], truth_poses[ok, :2]) for name in ("filter", "front end")}
    final = result.trajectory
    by_drift = [ate(without_drift(final, c), reference)[0] for c in DRIFTS]
    best = int(np.argmin(by_drift))
    correction = wrap_angle(errors["filter"] - errors["front end"])
    print(f"| {log.name} | {seed} | {int(np.sum(keep))} | {cells[0]} | {cells[1]} | {cells[2]} | "
          f"{drift['filter']:+.2f} / {drift['front end']:+.2f} | {chains['filter']:.3f} / {chains['front end']:.3f} | "
          f"{ate(final, reference)[0]:.3f} | {by_drift[best]:.3f} at {DRIFTS[best]:+.2f} | "
          f"{rms_degrees(correction):.2f}°, {correlation(correction, errors['front end']):+.2f} |",
          flush=True)
    return correction, errors["front end"]


def rms_degrees(angles: np.ndarray) -> float:
    """RMS (°) of angles (k,) in radians."""
    return math.degrees(float(np.sqrt(np.mean(angles ** 2))))


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson's correlation of two (k,) arrays; NaN with fewer than three values."""
    return float(np.corrcoef(a, b)[0, 1]) if a.shape[0] > 2 else math.nan


def logs_and_seeds(description: str) -> argparse.Namespace:
    """The command line of a benchmark that runs LOG [LOG ...] once per ``--seeds`` seed:
    ``args.logs`` (paths) and ``args.seeds`` (ints, [0] by default)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("logs", nargs="+", type=Path, help="CARMEN logs with a .gt.txt reference beside them")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0], help="seeds of the 1 mm range noise")
    return parser.parse_args()


def main() -> None:
    args = logs_and_seeds(__doc__.splitlines()[0])
    print("| log | seed | seams | filter's seams: median error, RMS heading | front end's chain | odometry | "
          "heading drift °/100 m, filter / front end | bases through the seams alone, RMS after a rigid fit (m), "
          "filter / front end | ATE (m) | ATE without the best linear heading drift (°/100 m) | "
          "filter's heading correction over the front end: RMS, correlation with the front end's error |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for log in args.logs:
        pooled = [report(log, seed) for seed in args.seeds]
        correction = np.concatenate([c for c, _ in pooled])
        front_end = np.concatenate([e for _, e in pooled])
        if correction.shape[0] > 2:
            blends = ", ".join(f"w = {w:g}: {rms_degrees(front_end + w * correction):.2f}°"
                               for w in (0.0, 0.5, 1.0))
            print(f"\n{log.name}, {correction.shape[0]} seams pooled: the filter's correction RMS "
                  f"{rms_degrees(correction):.2f}°, correlation with the front end's error "
                  f"{correlation(correction, front_end):+.2f}; RMS heading error of the front end's chain plus w × "
                  f"the correction: {blends}\n")


if __name__ == "__main__":
    main()
