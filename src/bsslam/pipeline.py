"""Run a Dataset through the filter: the step loop, progress, and the collected results.

The loop never branches on "show progress?": it calls a progress callback that is a no-op
by default (the CLI passes a rich progress bar).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from threadpoolctl import threadpool_limits

from bsslam.config import SLAMConfig
from bsslam.dataset import Dataset, SkipCounter
from bsslam.frontend import LaserOdometry
from bsslam.slam import MapSpline, SplineSLAM
from bsslam.slam.enlarge import beam_points
from bsslam.se2 import between
from bsslam.trajectory import Trajectory

Progress = Callable[[int, int | None], None]


def _no_progress(done: int, total: int | None) -> None:
    return None


@dataclass
class RunResult:
    """Everything a run produced.

    Attributes:
        name: the dataset's name.
        estimate: estimated trajectory with per-step pose covariances (one pose per scan).
        odometry: the dead-reckoning trajectory at the same stamps.
        ground_truth: the dataset's reference, if it has one.
        map: the final map splines with their covariance blocks.
        wall_time_s: time spent in the filter (s), excluding reading the input.
        step_times_s: (N,) time of each filter step (s).
        state_sizes: (N,) state dimension after each step.
        totals: summed counters of the step reports (beams used/dropped, new/extended splines …).
        nis: (N,) NIS of each step's update and (N,) its degrees of freedom.
        points: (k, 2) world scan points at the estimated poses (subsampled) for pictures.
        skipped: the reader's skipped-input counter.
    """

    name: str
    estimate: Trajectory
    odometry: Trajectory
    ground_truth: Trajectory | None
    map: list[MapSpline]
    wall_time_s: float
    step_times_s: np.ndarray
    state_sizes: np.ndarray
    totals: dict[str, int]
    nis: np.ndarray
    nis_dof: np.ndarray
    points: np.ndarray
    skipped: SkipCounter = field(default_factory=SkipCounter)

    @property
    def steps(self) -> int:
        return len(self.estimate)


def run_dataset(dataset: Dataset, config: SLAMConfig, *, steps: int | None = None,
                progress: Progress = _no_progress, total: int | None = None,
                point_stride: int = 4, slam: SplineSLAM | None = None) -> RunResult:
    """Run the filter over (the first ``steps`` frames of) a dataset.

    The map frame is the first frame's odometry pose, so estimate, odometry and a reference
    that starts at the same pose are directly comparable.

    Args:
        point_stride: keep every k-th valid beam of every scan for ``RunResult.points``.
        slam: an existing filter to continue (its state is not reset).
    """
    # The per-scan matrices are small (hundreds of rows): BLAS threads only add overhead,
    # and under load they make a 170×170 Cholesky 100× slower. One thread for the loop.
    with threadpool_limits(limits=1, user_api="blas"):
        return _run(dataset, config, steps, progress, total, point_stride, slam)


def _run(dataset, config, steps, progress, total, point_stride, slam) -> RunResult:
    stamps, poses, covs, odo, step_times, sizes, nis, dof = [], [], [], [], [], [], [], []
    points = []
    totals: dict[str, int] = {}
    prev_odo = None
    frontend = LaserOdometry(config.frontend) if config.frontend.enabled else None
    for i, frame in enumerate(dataset):
        if steps is not None and i >= steps:
            break
        if slam is None:
            slam = SplineSLAM(config, initial_pose=frame.odometry)
        t0 = time.perf_counter()
        if frontend is not None:
            # the front end's increment and covariance replace the odometry's; its cost is
            # part of the step's
            matched = frontend.step(frame)
            delta, delta_cov = matched.increment, matched.covariance
            if i and not matched.fallback:
                totals["frontend_matched"] = totals.get("frontend_matched", 0) + 1
            elif i:
                totals["frontend_fallbacks"] = totals.get("frontend_fallbacks", 0) + 1
        else:
            delta = None if prev_odo is None else between(prev_odo, frame.odometry)
            delta_cov = None
        prev_odo = frame.odometry
        report = slam.step(delta, frame.scan, frame.laser_offset, odometry_covariance=delta_cov)
        step_times.append(time.perf_counter() - t0)
        stamps.append(frame.stamp)
        poses.append(slam.pose)
        covs.append(slam.pose_covariance)
        odo.append(np.asarray(frame.odometry, dtype=float))
        sizes.append(report.state_size)
        nis.append(report.nis)
        dof.append(report.nis_dof)
        for key in ("observed_splines", "matched_splines", "new_splines", "extended_splines",
                    "pruned_splines", "beams_used"):
            totals[key] = totals.get(key, 0) + int(getattr(report, key))
        for reason, count in report.beams_dropped.items():
            totals[f"beams_dropped_{reason}"] = totals.get(f"beams_dropped_{reason}", 0) + count
        for reason, count in report.scan_counts.items():
            totals[f"scan_{reason}"] = totals.get(f"scan_{reason}", 0) + int(count)
        if point_stride:
            scan = frame.scan
            ok = np.isfinite(scan.ranges) & (scan.ranges < scan.max_range) & (scan.ranges > 0)
            sel = np.flatnonzero(ok)[::point_stride]
            points.append(beam_points(slam.pose, frame.laser_offset, scan.angles[sel], scan.ranges[sel]).points)
        progress(i + 1, total)
    if slam is None:
        slam = SplineSLAM(config)
    n = len(stamps)
    estimate = Trajectory(np.array(stamps), np.array(poses).reshape(n, 3), np.array(covs).reshape(n, 3, 3))
    odometry = Trajectory(np.array(stamps), np.array(odo).reshape(n, 3))
    return RunResult(
        name=getattr(dataset, "name", "dataset"), estimate=estimate, odometry=odometry,
        ground_truth=dataset.ground_truth, map=slam.map, wall_time_s=float(np.sum(step_times)),
        step_times_s=np.array(step_times), state_sizes=np.array(sizes, dtype=int), totals=totals,
        nis=np.array(nis), nis_dof=np.array(dof, dtype=int),
        points=np.vstack(points) if points else np.empty((0, 2)), skipped=dataset.skipped,
    )
