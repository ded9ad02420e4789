"""The laser-odometry front end on its own, on the real logs (prints figures, asserts nothing).

For each log, :class:`bsslam.frontend.LaserOdometry` (default ``FrontendConfig``) runs over
the frames; its increments are composed from the first odometry pose into a trajectory,
and both that and the raw odometry are scored against the log's reference
(``<log>.gt.txt``) by ATE (RMSE after the best rigid alignment). Reported per log:

- scans, ms/scan (median and mean of ``LaserOdometry.step``, single-threaded, reading the
  log excluded), fallbacks to odometry (and degenerate matches),
- ATE of the raw odometry and of the front end (m),
- for consecutive scans that both have a reference pose: the RMS error of the increments
  (translation m, rotation deg) of odometry and front end, and the mean NEES of the front
  end's increments under its covariance (3 would be consistent; the references themselves
  are only good to a few cm, which inflates it).

Run:  python benchmarks/bench_frontend.py [--steps N] [--logs intel-noisy aces-noisy …] [--config X.yaml]

(``--config``: a ``bsslam`` YAML configuration whose ``frontend`` section is used, e.g.
``frontend: {submap_keyframes: 100}``.)
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from bsslam.eval import ate  # noqa: E402
from bsslam.eval.association import associate  # noqa: E402
from bsslam.frontend import FrontendConfig, LaserOdometry  # noqa: E402
from bsslam.io.config_file import load_config  # noqa: E402
from bsslam.io.open_dataset import open_dataset  # noqa: E402
from bsslam.io.trajectory_file import read_trajectory  # noqa: E402
from bsslam.se2 import between  # noqa: E402
from bsslam.trajectory import Trajectory, wrap_angle  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
LOGS = {
    "intel-noisy": "intel/intel-noisy.clf",
    "aces-noisy": "aces/aces-noisy.clf",
    "csail-rawodom": "csail/csail-rawodom.clf",
    "intel-rawodom": "intel/intel-rawodom.clf",
    "edmonton-noisy": "edmonton/edmonton-noisy.clf",
    "acapulco-noisy": "acapulco/acapulco-noisy.clf",
    "freiburg-campus-noisy": "freiburg-campus/freiburg-campus-noisy.clf",
}


def run_log(path: Path, steps: int | None, config: FrontendConfig) -> dict:
    frames = []
    for i, frame in enumerate(open_dataset(path)):
        if steps is not None and i >= steps:
            break
        frames.append(frame)
    lo = LaserOdometry(config)
    poses, covs, times = [], [], []
    for frame in frames:
        t0 = time.perf_counter()
        out = lo.step(frame)
        times.append(time.perf_counter() - t0)
        poses.append(out.pose)
        covs.append(np.zeros((3, 3)) if out.covariance is None else out.covariance)
    stamps = np.array([f.stamp for f in frames])
    odo = Trajectory(stamps, np.array([f.odometry for f in frames]))
    est = Trajectory(stamps, np.array(poses))
    ref = read_trajectory(str(path)[: -len(".clf")] + ".gt.txt")
    row = {"scans": len(frames), "ms_median": 1e3 * float(np.median(times[1:])),
           "ms_mean": 1e3 * float(np.mean(times[1:])), "fallbacks": lo.stats.fallbacks,
           "reasons": dict(lo.stats.reasons), "degenerate": lo.stats.degenerate,
           "keyframes": lo.stats.keyframes}
    row["ate_odo"] = ate(odo, ref)[0]
    row["ate_fe"] = ate(est, ref)[0]
    # Increments between consecutive scans that both have a reference pose.
    ei, ri = associate(est, ref, 0.01, 0.0)
    ei, ri = np.asarray(ei), np.asarray(ri)
    pair = np.flatnonzero(np.diff(ei) == 1)
    if pair.shape[0]:
        a, b = ei[pair], ei[pair + 1]
        true = between(ref.poses[ri[pair]], ref.poses[ri[pair + 1]])
        for name, traj in (("odo", odo), ("fe", est)):
            e = between(true, between(traj.poses[a], traj.poses[b]))
            e[:, 2] = wrap_angle(e[:, 2])
            row[f"inc_xy_{name}"] = float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)))
            row[f"inc_deg_{name}"] = float(np.degrees(np.sqrt(np.mean(e[:, 2] ** 2))))
            if name == "fe":
                # covariance of increment a→b is the one reported at frame b
                C = np.array(covs)[b]
                nees = np.einsum("ni,ni->n", e, np.linalg.solve(C, e[..., None])[..., 0])
                row["nees_mean"] = float(np.mean(nees))
                row["nees_median"] = float(np.median(nees))
    row["pairs"] = int(pair.shape[0])
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=None, help="only the first N scans of each log")
    ap.add_argument("--logs", nargs="*", default=list(LOGS), choices=list(LOGS))
    ap.add_argument("--config", type=Path, default=None, help="YAML configuration; its frontend section is used")
    args = ap.parse_args()
    config = load_config(args.config).frontend if args.config else FrontendConfig()
    header = (f"{'log':21s} {'scans':>5s} {'ms/scan':>12s} {'fallbacks':>9s} {'degen':>5s} "
              f"{'ATE odo':>8s} {'ATE fe':>7s} {'Δ odo m/deg':>13s} {'Δ fe m/deg':>13s} {'NEES':>11s}")
    print(header)
    for name in args.logs:
        path = DATA / LOGS[name]
        if not path.exists():
            print(f"{name:21s} skipped: {path} not found")
            continue
        r = run_log(path, args.steps, config)
        inc = lambda k: (f"{r[f'inc_xy_{k}']:.3f}/{r[f'inc_deg_{k}']:.2f}" if f"inc_xy_{k}" in r else "-")  # noqa: E731
        nees = f"{r['nees_mean']:.1f}/{r['nees_median']:.1f}" if "nees_mean" in r else "-"
        print(f"{name:21s} {r['scans']:5d} {r['ms_median']:5.1f}/{r['ms_mean']:5.1f}ms {r['fallbacks']:9d} "
              f"{r['degenerate']:5d} {r['ate_odo']:7.2f}m {r['ate_fe']:6.2f}m {inc('odo'):>13s} {inc('fe'):>13s} "
              f"{nees:>11s}", flush=True)
        if r["reasons"]:
            print(f"{'':21s} fallback reasons: {r['reasons']}; keyframes {r['keyframes']}; increment pairs {r['pairs']}")
    print("ms/scan: median/mean of LaserOdometry.step; Δ: RMS increment error between consecutive "
          "referenced scans (m / deg); NEES: mean/median of the front end's increments (3 = consistent)")


if __name__ == "__main__":
    main()
