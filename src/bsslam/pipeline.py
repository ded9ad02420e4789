"""Run a Dataset through the filter: the step loop, progress, and the collected results.

Two passes. The first is the online filter: each scan's pose is the filter's estimate at
that moment. A filter never revises a past pose, so the poses before a loop closure keep
the drift the closure removed from the map. The second pass (``SLAMConfig.relocalize``)
localises every scan again in the final map, held fixed, from the same front-end
increments: the trajectory then agrees with the map the whole run built.

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
from bsslam.frontend import LaserOdometry, UpdateSchedule
from bsslam.slam import MapSpline, SplineSLAM
from bsslam.slam.enlarge import beam_points
from bsslam.se2 import between, compose_with_covariance
from bsslam.trajectory import Trajectory

Progress = Callable[[int, int | None], None]


def _no_progress(done: int, total: int | None) -> None:
    return None


@dataclass
class RunResult:
    """Everything a run produced.

    Attributes:
        name: the dataset's name.
        estimate: the online filter's trajectory with per-step pose covariances (one pose
            per scan): each pose as the filter knew it then, its covariance the pose block
            of the joint covariance.
        relocalized: the same scans localised in the final map (second pass), with pose
            covariances relative to that map; None when ``relocalize`` is off.
        odometry: the dead-reckoning trajectory at the same stamps.
        frontend: the front end's own trajectory (its increments chained, no map), or None
            when the front end is off.
        ground_truth: the dataset's reference, if it has one.
        map: the final map splines with their covariance blocks.
        wall_time_s: time spent in the filter (s), both passes, excluding reading the input.
        relocalize_time_s: of which the second pass (s).
        step_times_s: (N,) time spent on each scan (s): front end and, where it ran, filter.
        state_sizes: (N,) state dimension after each step.
        totals: summed counters of the step reports (beams used/dropped, new/extended splines …).
        nis: (N,) NIS of each step's update and (N,) its degrees of freedom.
        points: (k, 2) world scan points at the final poses (subsampled) for pictures.
        skipped: the reader's skipped-input counter.
        scans: one (LaserScan, laser_offset (3,)) per frame, aligned with ``trajectory``.
    """

    name: str
    estimate: Trajectory
    relocalized: Trajectory | None
    odometry: Trajectory
    frontend: Trajectory | None
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
    scans: list = field(default_factory=list)

    relocalize_time_s: float = 0.0

    @property
    def steps(self) -> int:
        return len(self.estimate)

    @property
    def trajectory(self) -> Trajectory:
        """The best trajectory: relocalised in the final map when there is one, else online."""
        return self.relocalized if self.relocalized is not None else self.estimate


def run_dataset(dataset: Dataset, config: SLAMConfig, *, steps: int | None = None,
                progress: Progress = _no_progress, total: int | None = None,
                point_stride: int = 4, slam: SplineSLAM | None = None,
                relocalize_progress: Progress = _no_progress) -> RunResult:
    """Run the filter over (the first ``steps`` frames of) a dataset, then, when
    ``config.relocalize`` is on, localise every scan again in the final map.

    The map frame is the first frame's odometry pose, so estimate, odometry and a reference
    that starts at the same pose are directly comparable.

    Args:
        point_stride: keep every k-th valid beam of every scan for ``RunResult.points``.
        slam: an existing filter to continue (its state is not reset).
        relocalize_progress: progress of the second pass (done, total frames).
    """
    # The per-scan matrices are small (hundreds of rows): BLAS threads only add overhead,
    # and under load they make a 170×170 Cholesky 100× slower. One thread for the loop.
    with threadpool_limits(limits=1, user_api="blas"):
        return _run(dataset, config, steps, progress, total, point_stride, slam, relocalize_progress)


class _OdometryMotion:
    """Raw odometry increments under the filter's motion model; every scan is a filter step."""

    def __init__(self) -> None:
        self._prev: np.ndarray | None = None

    def next(self, frame, totals: dict[str, int]):
        """(run the filter?, increment or None, its covariance or None) for one frame."""
        delta = None if self._prev is None else between(self._prev, frame.odometry)
        self._prev = np.asarray(frame.odometry, dtype=float)
        return True, delta, None


class _FrontendMotion:
    """Scan-matched increments with their covariance; the filter runs on the scans the
    update schedule picks, the others only feed the front end."""

    def __init__(self, config) -> None:
        self.odometry = LaserOdometry(config)
        self.schedule = UpdateSchedule(config.update_distance_m, config.update_angle_rad)

    def next(self, frame, totals: dict[str, int]):
        matched = self.odometry.step(frame)
        if matched.increment is None:  # the first frame
            return True, None, None
        key = "frontend_fallbacks" if matched.fallback else "frontend_matched"
        totals[key] = totals.get(key, 0) + 1
        if not self.schedule.add(matched.increment, matched.covariance):
            return False, None, None
        delta, cov = self.schedule.take()
        return True, delta, cov

    def since_update(self):
        """The increment (3,) and covariance (3, 3) compounded since the last filter step."""
        return self.schedule.increment.copy(), self.schedule.covariance.copy()


@dataclass(frozen=True)
class _Replayed:
    """One frame as the second pass needs it: a filter step (scan set) with its increment
    (None on the first frame), or a skipped scan whose pose is the last step's composed
    with ``delta``."""

    delta: np.ndarray | None
    covariance: np.ndarray | None
    scan: object = None
    laser_offset: np.ndarray | None = None
    features: object = None      # the scan's splines from the first pass (not fitted twice)


def _scan_points(frame_scan, pose, laser_offset, stride: int) -> np.ndarray:
    ok = np.isfinite(frame_scan.ranges) & (frame_scan.ranges < frame_scan.max_range) & (frame_scan.ranges > 0)
    sel = np.flatnonzero(ok)[::stride]
    return beam_points(pose, laser_offset, frame_scan.angles[sel], frame_scan.ranges[sel]).points


def _run(dataset, config, steps, progress, total, point_stride, slam, relocalize_progress) -> RunResult:
    stamps, poses, covs, odo, fe, step_times, sizes, nis, dof = [], [], [], [], [], [], [], [], []
    points, replay, scans = [], [], []
    totals: dict[str, int] = {}
    motion = _FrontendMotion(config.frontend) if config.frontend.enabled else _OdometryMotion()
    first_pose = None
    for i, frame in enumerate(dataset):
        if steps is not None and i >= steps:
            break
        if slam is None:
            slam = SplineSLAM(config, initial_pose=frame.odometry)
        if first_pose is None:
            first_pose, first_cov = slam.pose, slam.pose_covariance
        t0 = time.perf_counter()
        run_filter, delta, delta_cov = motion.next(frame, totals)
        if run_filter:
            report = slam.step(delta, frame.scan, frame.laser_offset, odometry_covariance=delta_cov)
            pose, cov = slam.pose, slam.pose_covariance
            replay.append(_Replayed(delta, delta_cov, frame.scan, frame.laser_offset, report.features))
        else:
            report = None
            pose, cov = motion.schedule.pose_between_updates(slam.pose, slam.pose_covariance)
            replay.append(_Replayed(*motion.since_update()))
        step_times.append(time.perf_counter() - t0)
        stamps.append(frame.stamp)
        poses.append(pose)
        covs.append(cov)
        odo.append(np.asarray(frame.odometry, dtype=float))
        scans.append((frame.scan, np.asarray(frame.laser_offset, float)))
        if isinstance(motion, _FrontendMotion):
            fe.append(motion.odometry.pose.copy())
        sizes.append(slam.state_size)
        nis.append(report.nis if report else 0.0)
        dof.append(report.nis_dof if report else 0)
        if report is not None:
            _add_report(totals, report)
        if point_stride and not config.relocalize:   # else the second pass draws them at its poses
            points.append(_scan_points(frame.scan, pose, frame.laser_offset, point_stride))
        progress(i + 1, total)
    if slam is None:
        slam = SplineSLAM(config)
    n = len(stamps)
    stamps_arr = np.array(stamps)
    estimate = Trajectory(stamps_arr, np.array(poses).reshape(n, 3), np.array(covs).reshape(n, 3, 3))
    odometry = Trajectory(stamps_arr, np.array(odo).reshape(n, 3))
    frontend = Trajectory(stamps_arr, np.array(fe).reshape(n, 3)) if fe else None
    final_map = slam.map
    relocalized, relocalize_time = None, 0.0
    if config.relocalize and n:
        t0 = time.perf_counter()
        relocalized, reloc_points = relocalize(final_map, replay, stamps_arr, config, first_pose, first_cov,
                                               point_stride, relocalize_progress)
        relocalize_time = time.perf_counter() - t0
        points = reloc_points
    return RunResult(
        name=getattr(dataset, "name", "dataset"), estimate=estimate, relocalized=relocalized, odometry=odometry,
        frontend=frontend, ground_truth=dataset.ground_truth, map=final_map,
        wall_time_s=float(np.sum(step_times)) + relocalize_time, relocalize_time_s=relocalize_time,
        step_times_s=np.array(step_times), state_sizes=np.array(sizes, dtype=int), totals=totals,
        nis=np.array(nis), nis_dof=np.array(dof, dtype=int),
        points=np.vstack(points) if points else np.empty((0, 2)), skipped=dataset.skipped, scans=scans,
    )


def relocalize(splines: list[MapSpline], replay: list[_Replayed], stamps: np.ndarray, config: SLAMConfig,
               initial_pose: np.ndarray, initial_covariance: np.ndarray, point_stride: int = 0,
               progress: Progress = _no_progress) -> tuple[Trajectory, list[np.ndarray]]:
    """The second pass: every recorded frame localised in the fixed map ``splines``.

    Filter steps rerun with the first pass's increments (the front end is not run again);
    scans between them take the last step's pose composed with the increments since.
    Returns the trajectory (covariances relative to the map) and, with ``point_stride``,
    the filter steps' scan points at the new poses.
    """
    slam = SplineSLAM.in_fixed_map(splines, config, initial_pose, initial_covariance)
    poses, covs, points = [], [], []
    for i, frame in enumerate(replay):
        if frame.scan is not None:
            slam.step(frame.delta, frame.scan, frame.laser_offset, odometry_covariance=frame.covariance,
                      features=frame.features)
            pose, cov = slam.pose, slam.pose_covariance
            if point_stride:
                points.append(_scan_points(frame.scan, pose, frame.laser_offset, point_stride))
        else:
            pose, cov = compose_with_covariance(slam.pose, slam.pose_covariance, frame.delta, frame.covariance)
        poses.append(pose)
        covs.append(cov)
        progress(i + 1, len(replay))
    n = len(poses)
    return Trajectory(stamps, np.array(poses).reshape(n, 3), np.array(covs).reshape(n, 3, 3)), points


def _add_report(totals: dict[str, int], report) -> None:
    """Add one step report's counters to the run totals."""
    totals["filter_steps"] = totals.get("filter_steps", 0) + 1
    for key in ("observed_splines", "matched_splines", "new_splines", "extended_splines",
                "pruned_splines", "beams_used"):
        totals[key] = totals.get(key, 0) + int(getattr(report, key))
    for reason, count in report.beams_dropped.items():
        totals[f"beams_dropped_{reason}"] = totals.get(f"beams_dropped_{reason}", 0) + count
    for reason, count in report.scan_counts.items():
        totals[f"scan_{reason}"] = totals.get(f"scan_{reason}", 0) + int(count)
