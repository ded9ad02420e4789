"""Where a submap run's trajectory error lives: in the submaps' bases (the pose graph) or
inside the submaps (the local filter and the second pass).

    python benchmarks/error_budget.py LOG [LOG ...] [--seeds 0 1 2]

A benchmark, not a test (prints figures, asserts nothing). Each LOG (with ``.gt.txt``
beside it) runs once per seed with the default configuration, every range moved by 1 mm of
seeded noise (as ``bsslam bench --perturb``). Per run it prints:

- **the run**: the ATE (m) of its final trajectory (``trajectory.tum``);
- **inside the submaps** (m): the same poses with each submap's share of them moved rigidly
  onto the reference (the best rigid fit of that submap's positions alone), so what is
  left is the shape the submaps give their own stretch of path: the floor that no
  placement of the submaps as rigid pieces (no pose graph, however good) goes below.
  Moving each submap onto the reference pose of its base scan instead would carry that
  one pose's heading error (a few tenths of a degree) over the whole submap;
- **the front end inside the submaps** (m): the front end's own poses (``frontend.tum``) over
  the same stretches, fitted the same way: the local error without the spline map;
- **the bases alone** (m): the submaps' bases (the graph's nodes) against the reference poses
  of their base scans, RMS after the best rigid fit;
- **the submaps' turns**: the rotation of each submap's own fit less its predecessor's,
  RMS (°): how far the seams err in heading once the pose graph has placed the submaps,
  measured over whole submaps (a single reference pose errs by a few tenths of a degree).

The run's ATE less what is left inside the submaps is what better bases (more or better
loop closures, less drift in the seams) could gain at most; a run whose inside error is
already near the target needs better bases, one whose inside error is not needs a better
local estimate. The last submap counts too: its base is a scan like any other.

What the shared logs gave is in docs/real_logs.md ("Where the error lives").
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.eval.trajectory_error import ate
from bsslam.eval.alignment import align_rigid_2d
from bsslam.eval.association import associate
from bsslam.trajectory import Trajectory

sys.path.insert(0, str(Path(__file__).resolve().parent))
from graph_consistency import reference_bases, run_log  # noqa: E402
from seam_sources import logs_and_seeds, rigid_rms  # noqa: E402


def piecewise_fit(estimate: Trajectory, reference: Trajectory, piece: np.ndarray
                  ) -> tuple[float, np.ndarray, np.ndarray, int]:
    """``estimate`` against ``reference`` (poses paired by time) with each piece (``piece``,
    (n,) an integer label per estimate pose) rigidly fitted on its own.

    Returns:
        the RMS position error after the fits (m); (k,) the labels of the pieces fitted and
        (k,) the rotation of each one's fit (rad, unwrapped): the turn that puts the piece
        onto the reference, the reference's heading less the piece's as a whole; and how
        many pieces were left out for having fewer than three matched poses.
    """
    est_idx, ref_idx = associate(estimate, reference, 0.01, 0.0)
    squared, labels, turns, skipped = [], [], [], 0
    for k in np.unique(piece[est_idx]):
        rows = piece[est_idx] == k
        if np.count_nonzero(rows) < 3:
            skipped += 1
            continue
        a, b = estimate.poses[est_idx[rows], :2], reference.poses[ref_idx[rows], :2]
        rotation, translation = align_rigid_2d(a, b)
        squared.append(np.sum((a @ rotation.T + translation - b) ** 2, axis=1))
        labels.append(k)
        turns.append(np.arctan2(rotation[1, 0], rotation[0, 0]))
    rms = float(np.sqrt(np.mean(np.concatenate(squared)))) if squared else float("nan")
    return rms, np.array(labels, dtype=int), np.unwrap(np.array(turns)), skipped


def report(log: Path, seed: int) -> list[float]:
    """Print one run's row; return its figures — the ATE, inside, front end inside and
    bases alone (m), the turn (°) — NaN where not measurable."""
    result = run_log(log, seed, SLAMConfig())
    submaps = result.submaps
    empty = " | ".join([""] * 5)
    if submaps is None or not submaps.frozen:
        print(f"| {log.name} | {seed} | no frozen submap | {empty} |")
        return [np.nan] * 5
    reference, index = reference_bases(result, log)
    if np.any(index < 0):
        print(f"| {log.name} | {seed} | a base without a reference pose | {empty} |")
        return [np.nan] * 5
    truth = reference.poses[index]
    # ``step_submaps`` holds the submap of each pose of the online estimate; the final and
    # the front end's trajectories have a pose at each of its stamps
    steps = np.asarray(result.step_submaps)
    final, frontend = result.trajectory, result.frontend
    for name, trajectory in (("final", final), ("front end", frontend)):
        if not np.array_equal(trajectory.stamps, result.estimate.stamps):
            raise SystemExit(f"{log.name}: the {name} trajectory's stamps are not the online estimate's")
    bases = submaps.graph.poses()
    inside, labels, turns, skipped = piecewise_fit(final, reference, steps)
    fe_inside, _, _, _ = piecewise_fit(frontend, reference, steps)
    # a submap's turn against the one before it: how far its seam errs in heading, with
    # the reference's per-pose error averaged over the submaps' poses
    neighbours = np.diff(labels) == 1
    seam_turn = np.degrees(np.sqrt(np.mean(np.diff(turns)[neighbours] ** 2))) if np.any(neighbours) else np.nan
    figures = [ate(final, reference)[0], inside, fe_inside, rigid_rms(bases[:len(truth), :2], truth[:, :2]),
               seam_turn]
    note = f" ({skipped} left out)" if skipped else ""
    print(f"| {log.name} | {seed} | {len(truth)}{note} | " + " | ".join(f"{v:.3f}" for v in figures[:4])
          + f" | {figures[4]:.2f} |", flush=True)
    return figures


def main() -> None:
    args = logs_and_seeds(__doc__.splitlines()[0])
    print("| log | seed | submaps, the last open one too (those of fewer than three poses left out) | ATE (m) | "
          "inside the submaps | the front end inside the submaps | bases alone | "
          "submaps turned against their predecessors, RMS (°) |")
    print("|---|---|---|---|---|---|---|---|")
    for log in args.logs:
        rows = np.array([report(log, seed) for seed in args.seeds])
        if len(args.seeds) > 1:
            med = np.nanmedian(rows, axis=0)
            print(f"| {log.name} | median | | " + " | ".join(f"{v:.3f}" for v in med[:4]) + f" | {med[4]:.2f} |",
                  flush=True)


if __name__ == "__main__":
    main()
