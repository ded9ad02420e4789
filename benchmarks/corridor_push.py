"""What pushes the estimate ahead down a straight corridor: the same simulated run with the
range noise taken out of one part of the filter at a time.

    python benchmarks/corridor_push.py [--seeds 0 5 2 3] [--steps 101]

A benchmark, not a test (prints figures, asserts nothing). The run is the long corridor of
``corridor_consistency.py`` (80 × 50 m loop, the library's defaults under
``simulation_config``, the single global filter), cut after ``--steps`` scans: by default
the robot has gone 25 m down the first straight, where two straight walls 3 m apart are all
the laser sees, and the far corner is not yet in its 8 m. There the walls say nothing about
where along the corridor the robot is, so a consistent filter keeps the odometry's own error
along it. Each variant runs the same seeds (the same odometry, the same noise draws):

- ``defaults``: as the library runs;
- ``exact ranges``: the simulated laser without noise (the filter still assumes 5 mm);
- ``walls from exact ranges``: new splines and extensions are fitted to the exact ranges
  (at the filter's pose), the updates take the noisy ones;
- ``updates with exact ranges``: the other way round;
- ``segments from exact ranges``: the scan is cut into segments and the splines fitted as
  if it were exact, the ranges of their beams stay noisy (the walls and the updates);
- ``antithetic noise``: every range's noise turned round (2·exact − noisy): an effect of
  the noise's sign flips with it, one of its square does not;
- ``localisation in the exact map``: the walls given exactly (one spline per wall, fixed),
  the noisy ranges localise the pose alone.

Per variant and seed: the along-corridor error x̂ − x at the last scan (m), beside the
odometry's own (its increments' forward noise summed); and the time-averaged pose NEES (3 dof, 3 if consistent). What it gave is in
docs/consistency.md ("Between the walls").
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses

import numpy as np

import bsslam.slam.filter as filter_module
from bsslam.config import SLAMConfig
from bsslam.experiments.consistency import simulation_config
from bsslam.scan.observed import ScanFeatures, extract_splines
from bsslam.se2 import between
from bsslam.sim import SimConfig, simulate
from bsslam.sim.worlds import large_corridor
from bsslam.slam import SplineSLAM
from bsslam.slam.features import MapSpline
from bsslam.slam.measurement import Beams, RangeModel
from bsslam.spline import fit_curve
from bsslam.trajectory import wrap_angle

VARIANTS = ("defaults", "exact ranges", "walls from exact ranges", "updates with exact ranges",
            "segments from exact ranges", "antithetic noise", "localisation in the exact map")


class _ExactRanges:
    """The current scan's exact ranges, looked up by bearing (the simulator's beams are the
    same at every scan)."""

    def __init__(self):
        self.angles = np.empty(0)
        self.exact = np.empty(0)

    def of(self, bearings: np.ndarray) -> np.ndarray:
        i = np.clip(np.searchsorted(self.angles, bearings - 1e-9), 0, self.angles.shape[0] - 1)
        if not np.allclose(self.angles[i], bearings, atol=1e-6):
            raise RuntimeError("a beam's bearing is not one of the scan's")
        return self.exact[i]


@contextlib.contextmanager
def _patched(owner, name, replacement):
    original = getattr(owner, name)
    setattr(owner, name, replacement(original))
    try:
        yield
    finally:
        setattr(owner, name, original)


def exact_map(world) -> list[MapSpline]:
    """Every wall of ``world`` as one spline fitted to its exact outline (2 cm points)."""
    splines = []
    for points in world.polylines(0.02):
        curve = fit_curve(points, 3, 1.0).curve
        k = curve.control_points.shape[0]
        splines.append(MapSpline(len(splines), curve, np.zeros((2 * k, 2 * k))))
    return splines


def run(variant: str, seed: int, steps: int) -> tuple[float, float, float]:
    """(x̂ − x at the last scan, the odometry's x − x there, time-averaged NEES) of one run."""
    sim = SimConfig()
    config = simulation_config(SLAMConfig(), sim).replace(backend="ekf")
    world = large_corridor(80.0, 50.0)
    data = simulate(world, sim, seed=seed, steps=steps)
    noisy = list(data)
    exact = list(simulate(world, dataclasses.replace(sim, sigma_range_m=0.0), seed=seed, steps=steps))
    truth = data.ground_truth.poses
    lookup = _ExactRanges()
    with contextlib.ExitStack() as stack:
        if variant == "walls from exact ranges":
            stack.enter_context(_patched(filter_module, "beam_points", lambda bp: (
                lambda pose, offset, bearings, ranges: bp(pose, offset, bearings, lookup.of(bearings)))))
        if variant == "updates with exact ranges":
            def exact_beams(beams_of):
                def beams(self, observed, matches, curves):
                    b = beams_of(self, observed, matches, curves)
                    return None if b is None else Beams(b.curve, b.bearings, lookup.of(b.bearings), b.t0)
                return beams
            stack.enter_context(_patched(RangeModel, "beams", exact_beams))
        if variant == "localisation in the exact map":
            slam = SplineSLAM.in_fixed_map(exact_map(world), config, initial_pose=truth[0],
                                           initial_covariance=np.diag([1e-6, 1e-6, 1e-8]))
        else:
            slam = SplineSLAM(config, initial_pose=noisy[0].odometry)
        nees = []
        previous = noisy[0].odometry
        for k, (frame, clean) in enumerate(zip(noisy, exact)):
            lookup.angles, lookup.exact = frame.scan.angles, clean.scan.ranges
            delta = None if k == 0 else between(previous, frame.odometry)
            previous = frame.odometry
            scan, features = frame.scan, None
            if variant == "exact ranges":
                scan = clean.scan
            elif variant == "antithetic noise":
                scan = dataclasses.replace(frame.scan, ranges=2.0 * clean.scan.ranges - frame.scan.ranges)
            elif variant == "segments from exact ranges":
                found = extract_splines(clean.scan, config)
                features = ScanFeatures([dataclasses.replace(o, ranges=frame.scan.ranges[o.beam_indices])
                                         for o in found.splines], found.counts)
            slam.step(delta, scan, features=features)
            error = slam.pose - truth[k]
            error[2] = wrap_angle(error[2])
            if k:
                nees.append(float(error @ np.linalg.solve(slam.state.pose_covariance, error)))
    # the odometry's own error along the corridor: its increments' forward noise, summed
    odometry_x = sum(between(a.odometry, b.odometry)[0] - between(s, t)[0]
                     for a, b, s, t in zip(noisy[:-1], noisy[1:], truth[:-1], truth[1:]))
    return float(error[0]), float(odometry_x), float(np.mean(nees))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 5, 2, 3])
    ap.add_argument("--steps", type=int, default=101, help="scans (default 101: 25 m down the first straight)")
    args = ap.parse_args()
    rows = {v: [run(v, s, args.steps) for s in args.seeds] for v in VARIANTS}
    odometry = ", ".join(f"{r[1]:+.2f}" for r in rows["defaults"])
    print(f"80 × 50 m corridor, scan {args.steps - 1}, seeds {', '.join(map(str, args.seeds))}; "
          f"the odometry's own along-corridor error: {odometry} m")
    print("| variant | x̂ − x at the last scan (m), per seed | mean over seeds | time-averaged NEES, per seed |")
    print("|---|---|---|---|")
    for v, r in rows.items():
        x = np.array([e[0] for e in r])
        print(f"| {v} | {', '.join(f'{e:+.2f}' for e in x)} | {x.mean():+.2f} | "
              f"{', '.join(f'{e[2]:.1f}' for e in r)} |")


if __name__ == "__main__":
    main()
