"""The whole SLAM pipeline as a streaming object: feed it one scan at a time.

:class:`Mapper` is what ``bsslam run`` does, scan by scan: the laser-odometry front end
(:class:`~bsslam.frontend.LaserOdometry`) turns the odometry into scan-matched increments,
the update schedule (:class:`~bsslam.frontend.UpdateSchedule`) picks the scans the filter
(:class:`~bsslam.slam.SplineSLAM`) processes, and :meth:`Mapper.finish` runs the second
pass (:func:`relocalize`) and returns a :class:`RunResult`.
:func:`bsslam.pipeline.run_dataset` is a loop over it.

Two passes. The first is the online filter: each scan's pose is the filter's estimate at
that moment. A filter never revises a past pose, so the poses before a loop closure keep
the drift the closure removed from the map. The second pass (``SLAMConfig.relocalize``)
localises every scan again in the final map, held fixed, from the same front-end
increments: the trajectory then agrees with the map the whole run built.

The mapper calls a viewer after every scan and at the end; the default one does nothing,
so the loop never branches on "visualise?".
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from bsslam.blas_threads import one_blas_thread
from bsslam.compiled import kernel_interrupts
from bsslam.chi2 import chi2_quantile
from bsslam.config import SLAMConfig
from bsslam.dataset import Frame, SkipCounter
from bsslam.deskewed_dataset import deskewed, odometry_velocity
from bsslam.errors import FilterError, InputError, MemoryBudgetError
from bsslam.frontend import FrontendStep, LaserOdometry, UpdateSchedule
from bsslam.input_limits import InputLimits, OdometryGate, angles_problem, invalid_ranges, offset_problem
from bsslam.scan import LaserScan
from bsslam.se2 import between, compose, compose_with_covariance, squared_mahalanobis
from bsslam.slam import MapSpline, SplineSLAM
from bsslam.spline import BSplineCurve
from bsslam.submaps.backend import SubmapSLAM
from bsslam.trajectory import Trajectory
from bsslam.viz.null_viewer import NullViewer

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
            covariances relative to that map; None when ``relocalize`` is off or the run
            was interrupted.
        odometry: the dead-reckoning trajectory at the same stamps.
        frontend: the front end's own trajectory (its increments chained, no map), or None
            when the front end is off.
        ground_truth: the dataset's reference, if it has one.
        map: the final map splines with their covariance blocks.
        wall_time_s: time spent in this process on the scans (s), both passes and the
            sweep between them, excluding reading the input.
        relocalize_time_s: of which the second pass (s).
        sweep_time_s: … and the submap backend's end-of-run loop-closure sweep (s;
            :meth:`~bsslam.submaps.SubmapSLAM.sweep_loops`).
        step_times_s: (N,) time spent on each scan (s): front end and, where it ran, filter;
            the front end not included on the scans it matched in a helper process
            (``totals["frontend_in_helper"]`` counts them).
        state_sizes: (N,) state dimension after each step.
        totals: summed counters of the step reports (beams used/dropped, new/extended splines …).
        nis: (N,) NIS of each step's update and (N,) its degrees of freedom.
        points: (k, 2) world scan points at the final poses (subsampled) for pictures.
        skipped: the reader's skipped-input counter.
        scans: one (LaserScan, laser_offset (3,)) per frame, aligned with ``trajectory``.
        interrupted: the run was ended early (KeyboardInterrupt, or SIGTERM turned into
            one, or the memory budget): the arrays hold the scans processed until then and
            the second pass did not run.
        stop_reason: why it ended early (None: it did not, or by an interrupt).
        submaps: the submap backend's global layer (None with ``backend: ekf``).
        step_submaps: (N,) the submap of each scan (zeros with ``backend: ekf``).
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
    sweep_time_s: float = 0.0
    interrupted: bool = False
    stop_reason: str | None = None
    submaps: SubmapSLAM | None = None
    step_submaps: np.ndarray | None = None

    @property
    def steps(self) -> int:
        return len(self.estimate)

    @property
    def trajectory(self) -> Trajectory:
        """The best trajectory: relocalised in the final map when there is one, else online."""
        return self.relocalized if self.relocalized is not None else self.estimate


@dataclass(frozen=True)
class PoseEstimate:
    """What :meth:`Mapper.add` returns for one scan.

    Attributes:
        stamp: the scan's time (s).
        pose: (3,) the robot's pose (x m, y m, φ rad) in the map frame.
        covariance: (3, 3) its covariance (m², m·rad, rad²).
        filter_step: True when the filter processed this scan; else the pose is the last
            filter step's composed with the front end's increments since.
    """

    stamp: float
    pose: np.ndarray
    covariance: np.ndarray
    filter_step: bool


class Viewer(Protocol):
    """What the mapper calls (:class:`~bsslam.viz.null_viewer.NullViewer` does nothing)."""

    def update(self, estimate: PoseEstimate, points: np.ndarray, mapper: "Mapper") -> None:
        """After each scan, with its valid beams' world points (k, 2) at ``estimate.pose``;
        ``mapper.curves`` is the current map (it changes on filter steps)."""

    def finish(self, result: RunResult) -> None:
        """Once, with the run's result (after the second pass)."""


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


@dataclass(frozen=True)
class _Record:
    """Everything the mapper keeps of one scan. A scan is recorded in one append once it
    is fully processed, so an interruption never leaves the per-scan arrays unequal."""

    stamp: float
    pose: np.ndarray
    covariance: np.ndarray
    odometry: np.ndarray
    frontend_pose: np.ndarray | None
    step_time_s: float
    state_size: int
    nis: float
    nis_dof: int
    counts: dict[str, int]
    replay: _Replayed
    scan: LaserScan
    laser_offset: np.ndarray
    submap: int = 0        # the submap its pose is relative to (``backend: submaps``)


class _OdometryMotion:
    """Raw odometry increments under the filter's motion model; every scan is a filter step."""

    #: no front end, no fallbacks (see :attr:`_FrontendMotion.wide_covariance`)
    wide_covariance = None

    def __init__(self) -> None:
        self._prev: np.ndarray | None = None

    def next(self, frame: Frame, step: FrontendStep | None = None):
        """(run the filter?, increment or None, its covariance or None, counter or None)."""
        delta = None if self._prev is None else between(self._prev, frame.odometry)
        self._prev = np.asarray(frame.odometry, dtype=float)
        return True, delta, None, None

    def pose(self) -> np.ndarray | None:
        return None


class _FrontendMotion:
    """Scan-matched increments with their covariance; the filter runs on the scans the
    update schedule picks, the others only feed the front end."""

    def __init__(self, config) -> None:
        self.odometry = LaserOdometry(config)
        self.schedule = UpdateSchedule(config.update_distance_m, config.update_angle_rad)
        # scales a trusted match's translation σ for the filter (FrontendConfig.filter_translation_scale)
        root = math.sqrt(config.filter_translation_scale)
        self._trust = np.outer([root, root, 1.0], [root, root, 1.0])
        self._pose: np.ndarray | None = None
        # with ``fallback_learned``: the same increments compounded with each fallback's
        # model covariance instead of its learned one (the wheels decide both schedules,
        # so they take together)
        self._learned = config.fallback_learned
        self._wide = UpdateSchedule(config.update_distance_m, config.update_angle_rad)
        self._fallback_since_take = False
        #: (3, 3) the covariance of the increment just taken with its fallbacks' model
        #: covariance; None when it held no fallback, when that equals the learned one
        #: (before 20 matches) or when ``fallback_learned`` is off
        self.wide_covariance: np.ndarray | None = None
        # the fallbacks since the last trusted match (an episode): are there any, and did a
        # filter step that took some of them predict them with the model's covariance
        self._episode_open = False
        self._episode_wide = False

    def next(self, frame: Frame, step: FrontendStep | None = None):
        """As :meth:`_OdometryMotion.next`; ``step`` is the front end's step on ``frame``
        when it ran elsewhere (:mod:`bsslam.helper_process`), which leaves
        :attr:`odometry` behind until its state is handed over."""
        matched = self.odometry.step(frame) if step is None else step
        self._pose = matched.pose
        if matched.increment is None:  # the first frame
            return True, None, None, None
        key = "frontend_fallbacks" if matched.fallback else "frontend_matched"
        covariance = matched.covariance if matched.fallback else matched.covariance * self._trust
        wide = self.odometry.odometry_covariance(matched.odometry_increment) if matched.fallback else covariance
        if matched.carried is not None and self._episode_wide:
            # The match after fallbacks takes their error back. A filter step that took them
            # predicted them with the model's covariance, so its walls took that error out
            # already: the increment carries it, as wide (all of it, an upper bound where
            # some of them share this increment and cancel in it). Where every such step
            # kept the learned σ, the walls agreed with the wheels and the filter kept their
            # error for the match to take back; where all of them share this increment,
            # their errors cancel in it. Carrying the learned σ after every fallback too cost
            # the campus two runs of seventy (docs/real_logs.md, "The match after a fallback").
            covariance, wide = covariance + matched.carried, wide + matched.carried
        if not matched.fallback:
            self._episode_open = self._episode_wide = False
        self._episode_open |= bool(matched.fallback)
        self._fallback_since_take |= bool(matched.fallback)
        if self._learned:
            self._wide.add(matched.increment, wide, matched.odometry_increment)
        self.wide_covariance = None
        if not self.schedule.add(matched.increment, covariance, matched.odometry_increment):
            return False, None, None, key
        delta, cov = self.schedule.take()
        if self._learned:
            wide = self._wide.take()[1]
            # before 20 matches the learned covariance is the model's: nothing to check
            self.wide_covariance = wide if self._fallback_since_take and not np.array_equal(wide, cov) else None
        if self._fallback_since_take and self.wide_covariance is None:
            self._episode_wide |= self._episode_open   # the model's covariance, nothing to check
        self._fallback_since_take = False
        return True, delta, cov, key

    def checked(self, widened: bool) -> None:
        """The walls' check of the increment just taken (its :attr:`wide_covariance`)
        predicted it with the model's covariance (``widened``) or the learned one."""
        self._episode_wide |= widened and self._episode_open

    def since_update(self):
        """The increment (3,) and covariance (3, 3) compounded since the last filter step."""
        return self.schedule.increment.copy(), self.schedule.covariance.copy()

    def pose(self) -> np.ndarray:
        """The front end's own pose (3,) after the last frame."""
        return self._pose.copy()


class Mapper:
    """BS-SLAM as ``bsslam run`` does it, fed one scan at a time.

    >>> mapper = Mapper(SLAMConfig())
    >>> for scan, odometry_pose in my_sensor():                     # doctest: +SKIP
    ...     estimate = mapper.add(scan, odometry_pose, scan.stamp)   # .pose (3,), .covariance (3, 3)
    >>> result = mapper.finish()       # the second pass; result.trajectory, result.map  # doctest: +SKIP

    Args:
        config: the configuration (front end, update schedule, filter, second pass).
        initial_pose: (3,) the map-frame pose of the first scan (x m, y m, φ rad); by
            default the first scan's odometry pose, so map and odometry frames coincide.
        viewer: called after every scan and at the end (e.g.
            :class:`bsslam.viz.rerun_viewer.RerunViewer`); a no-op by default.
        slam: an existing filter to continue instead of a new one (its state is not reset;
            ``initial_pose`` is then ignored).
        limits: the physical limits :meth:`add` checks scans and odometry against; by
            default ``config.input`` (:class:`~bsslam.input_limits.InputLimits`).
        strict: an implausible odometry step raises InputError instead of being bridged
            and counted in :attr:`skipped`.
    """

    def __init__(self, config: SLAMConfig | None = None, initial_pose=None, viewer: Viewer | None = None,
                 *, slam: SplineSLAM | SubmapSLAM | None = None, limits: InputLimits | None = None,
                 strict: bool = False) -> None:
        self.config = config or SLAMConfig()
        self.viewer = viewer if viewer is not None else NullViewer()
        self._initial_pose = None if initial_pose is None else _pose(initial_pose, "initial_pose")
        self._slam = slam
        self._motion = _FrontendMotion(self.config.frontend) if self.config.frontend.enabled else _OdometryMotion()
        self._records: list[_Record] = []
        self._first: tuple[np.ndarray, np.ndarray] | None = None   # the first pose and covariance
        self._odometry: np.ndarray | None = None    # the last odometry pose
        self.limits = limits if limits is not None else self.config.input
        self.strict = strict
        self.skipped = SkipCounter()   # what add() bridged, by reason
        self._gate = OdometryGate(self.limits)
        self._last_stamp: float | None = None

    # -- pickling (a run's checkpoint, :mod:`bsslam.io.checkpoint`) ----------------------
    def __getstate__(self) -> dict:
        """Everything but the viewer (a window or a stream, not state): an unpickled
        mapper has the null viewer until :attr:`viewer` is set again."""
        state = self.__dict__.copy()
        state["viewer"] = None
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self.viewer = NullViewer()

    # -- views --------------------------------------------------------------------------
    @property
    def slam(self) -> SplineSLAM | SubmapSLAM | None:
        """The online filter (None before the first scan): the paper's global EKF
        (``backend: ekf``) or the submap backend."""
        return self._slam

    @property
    def map(self) -> list[MapSpline]:
        """The current map splines with their covariance blocks. Reading it folds the
        filter's pending covariance update, which changes the last bits of the later
        scans' numbers; :attr:`curves` does not."""
        return self._slam.map if self._slam is not None else []

    @property
    def curves(self) -> list[BSplineCurve]:
        """The current map splines' curves (world frame, m), without covariances; reading
        them leaves the filter untouched."""
        return [] if self._slam is None else self._slam.curves

    @property
    def frontend(self) -> LaserOdometry | None:
        """The laser-odometry front end (None when ``config.frontend.enabled`` is off). Set
        it to hand over the state of a front end that ran in another process."""
        return self._motion.odometry if isinstance(self._motion, _FrontendMotion) else None

    @frontend.setter
    def frontend(self, odometry: LaserOdometry) -> None:
        if not isinstance(self._motion, _FrontendMotion):
            raise ValueError("this mapper runs without a front end (config.frontend.enabled is off)")
        self._motion.odometry = odometry

    @property
    def scans(self) -> int:
        """The number of scans added."""
        return len(self._records)

    # -- the run ------------------------------------------------------------------------
    def add(self, scan: LaserScan, odometry=None, stamp: float | None = None, laser_offset=None, *,
            odometry_increment=None) -> PoseEstimate:
        """Process one scan; returns the robot's pose and covariance at it.

        Args:
            scan: the laser scan, bearings in the laser frame; a scan with a sweep time
                (``LaserScan.sweep_time_s``) is first corrected for the robot's motion
                during it (:func:`bsslam.scan.deskew`, the velocity from the odometry since
                the previous scan).
            odometry: (3,) the robot's odometry *pose* (x m, y m, φ rad) at the scan, in the
                odometry's own frame (only increments between scans are used).
            stamp: the scan's time (s); ``scan.stamp`` by default.
            laser_offset: (3,) the laser's pose in the robot frame; zeros by default.
            odometry_increment: instead of ``odometry``: (3,) the robot-frame motion
                (Δx m, Δy m, Δφ rad) since the previous scan. The increments are chained
                into odometry poses starting at ``initial_pose`` (the origin by default);
                on the first scan pass None (or zeros). The pipeline takes the increment
                between consecutive poses again, equal to the given one up to rounding.
        """
        odometry = self._odometry_pose(odometry, odometry_increment)
        stamp = float(scan.stamp if stamp is None else stamp)
        offset = np.zeros(3) if laser_offset is None else _pose(laser_offset, "laser_offset")
        previous_stamp, previous_odometry = self._last_stamp, self._odometry
        frame = self._checked(Frame(stamp, odometry, scan, offset))
        velocity = odometry_velocity(previous_odometry, previous_stamp, frame.odometry, frame.stamp, self.limits)
        return self.add_frame(deskewed(frame, velocity))

    def _checked(self, frame: Frame) -> Frame:
        """The public API's boundary: the same physical limits as the log readers
        (:mod:`bsslam.input_limits`). A bad scan or laser offset is an InputError; an
        implausible odometry step is bridged (see :class:`~bsslam.input_limits.OdometryGate`)
        and counted in :attr:`skipped`, or an InputError when ``strict``."""
        limits = self.limits
        scan = frame.scan
        problem = angles_problem(scan.angles, limits) or offset_problem(frame.laser_offset, limits)
        if problem is not None:
            raise InputError(f"Mapper.add: scan at {frame.stamp}: {problem}")
        if self._last_stamp is not None and not frame.stamp > self._last_stamp:
            raise InputError(f"Mapper.add: stamp {frame.stamp} is not after the previous scan's {self._last_stamp}")
        odometry, problem = self._gate.accept(frame.stamp, frame.odometry)
        if problem is not None:
            if self.strict or odometry is None:
                raise InputError(f"Mapper.add: scan at {frame.stamp}: {problem}")
            self.skipped.add(problem, f"scan at {frame.stamp}")
        self._last_stamp = frame.stamp
        ranges, _, _ = invalid_ranges(scan.ranges)   # negative → NaN (a failed beam)
        return Frame(frame.stamp, odometry, dataclasses.replace(scan, ranges=ranges), frame.laser_offset)

    def add_frame(self, frame: Frame, frontend_step: FrontendStep | None = None) -> PoseEstimate:
        """:meth:`add` for a frame a reader has already checked against the input limits
        (every :class:`~bsslam.dataset.Dataset` of :mod:`bsslam.io` and the simulator):
        the checks run once, at the boundary where the data entered.

        Args:
            frontend_step: the front end's step on this frame, when it ran in another
                process (:meth:`~bsslam.helper_process.HelperProcess.prefetch`); the mapper's
                own :attr:`frontend` is then not advanced (hand the other process's state
                over by setting it). Ignored when the front end is off.
        """
        scan, odometry, offset = frame.scan, frame.odometry, frame.laser_offset
        with one_blas_thread():
            record = self._step(frame, frontend_step)
        self._records.append(record)      # the scan is recorded whole, or not at all
        self._odometry = odometry
        estimate = PoseEstimate(record.stamp, record.pose.copy(), record.covariance.copy(), record.replay.scan is not None)
        self.viewer.update(estimate, _scan_points(scan, record.pose, offset, 1), self)
        return estimate

    def _odometry_pose(self, odometry, increment) -> np.ndarray:
        if odometry is not None and increment is not None:
            raise InputError("Mapper.add: give the odometry pose or odometry_increment, not both")
        if odometry is not None:
            return _pose(odometry, "odometry")
        if increment is None and self._odometry is not None:
            raise InputError("Mapper.add: give the odometry pose or odometry_increment (None only on the first scan)")
        start = self._odometry if self._odometry is not None else (
            self._initial_pose if self._initial_pose is not None else np.zeros(3))
        return start if increment is None else compose(start, _pose(increment, "odometry_increment"))

    def _checked_by_walls(self, slam, frame: Frame, delta, covariance):
        """The covariance (3, 3) to predict the increment ``delta`` (3,) with, whether it was
        widened, and the scan's splines if a trial step fitted them (else None), for the
        real step to reuse.

        An increment holding a fallback (``frontend.fallback_learned``) carries the wheels'
        learned σ, and no scan checked it; the filter's walls are its first check. A trial
        step on a copy of the local filter, predicting with the front end's wide model
        covariance, lets the walls place the pose freely: where they put it beyond the 99 %
        region of the prediction with the learned σ, the wheels erred more than their σ
        says, and the step predicts with the wide covariance so that the walls can turn it
        back. Held to the learned σ there, the campus's filter kept a heading 6° off, bent
        its submap and let wrong loop closures in (docs/real_logs.md, "A fallback as wide
        as the wheels err"). The innovations' χ² is no such test: the gates drop the beams a
        wrong heading moved. Costs a copy of the local filter and a second step, on
        fallbacks only (the copy's memory briefly on top of the budget)."""
        wide = self._motion.wide_covariance
        if wide is None or delta is None:
            return covariance, False, None
        local = slam.local if isinstance(slam, SubmapSLAM) else slam
        mean, predicted = compose_with_covariance(local.pose, local.pose_covariance, delta, covariance)
        trial = copy.deepcopy(local)
        try:
            report = trial.step(delta, frame.scan, frame.laser_offset, odometry_covariance=wide)
        except (FilterError, MemoryBudgetError):   # the trial must not end a run the real step may finish
            return covariance, False, None
        if squared_mahalanobis(trial.pose, mean, predicted) > chi2_quantile(0.99, 3):
            return wide, True, report.features
        return covariance, False, report.features

    def _step(self, frame: Frame, frontend_step: FrontendStep | None = None) -> _Record:
        """The front end, the update schedule and (on the scans it picks) the filter."""
        if self._slam is None:
            start = frame.odometry if self._initial_pose is None else self._initial_pose
            submaps = self.config.backend == "submaps" and self.config.mode == "slam"
            self._slam = (SubmapSLAM if submaps else SplineSLAM)(self.config, initial_pose=start)
        slam = self._slam
        if self._first is None:
            self._first = slam.pose, slam.pose_covariance
        t0 = time.perf_counter()
        run_filter, delta, delta_cov, counter = self._motion.next(frame, frontend_step)
        widened = False
        if run_filter:
            delta_cov, widened, features = self._checked_by_walls(slam, frame, delta, delta_cov)
            if self._motion.wide_covariance is not None:
                self._motion.checked(widened)
            report = slam.step(delta, frame.scan, frame.laser_offset, odometry_covariance=delta_cov,
                               features=features)
            pose, cov = slam.pose, slam.pose_covariance
            replay = _Replayed(delta, delta_cov, frame.scan, frame.laser_offset, report.features)
        else:
            report = None
            pose, cov = self._motion.schedule.pose_between_updates(slam.pose, slam.pose_covariance)
            replay = _Replayed(*self._motion.since_update())
        step_time = time.perf_counter() - t0
        counts = {} if counter is None else {counter: 1}
        if frontend_step is not None and counter is not None:   # its match's time is the helper's
            counts["frontend_in_helper"] = 1
        if report is not None:
            _add_report(counts, report)
            if widened:
                counts["fallbacks_widened"] = 1
        submap = 0
        if isinstance(slam, SubmapSLAM):   # a step's scan may have ended its submap: it belongs to that one
            submap = slam.step_submap if run_filter else slam.submap_index
        return _Record(frame.stamp, pose, cov, frame.odometry, self._motion.pose(), step_time, slam.state_size,
                       report.nis if report else 0.0, report.nis_dof if report else 0, counts, replay,
                       frame.scan, frame.laser_offset, submap)

    def finish(self, *, name: str = "mapper", ground_truth: Trajectory | None = None,
               skipped: SkipCounter | None = None, point_stride: int = 4, progress: Progress = _no_progress,
               interrupted: bool = False, stop_reason: str | None = None) -> RunResult:
        """The run so far as a :class:`RunResult`, after the second pass when
        ``config.relocalize`` is on. Call it once, at the end.

        Args:
            name, ground_truth, skipped: the data source's, copied into the result (skipped: by default what :meth:`add` bridged).
            point_stride: keep every k-th valid beam of every scan for ``RunResult.points``
                (0: none).
            progress: progress of the second pass (done, total scans).
            interrupted: the run was cut short: skip the second pass and mark the result.
                A KeyboardInterrupt during the second pass does the same.
            stop_reason: why it was cut short, for the result (e.g. the memory budget).
        """
        records = self._records
        n = len(records)
        stamps = np.array([r.stamp for r in records])
        estimate = Trajectory(stamps, np.array([r.pose for r in records]).reshape(n, 3),
                              np.array([r.covariance for r in records]).reshape(n, 3, 3))
        odometry = Trajectory(stamps, np.array([r.odometry for r in records]).reshape(n, 3))
        frontend = None
        if isinstance(self._motion, _FrontendMotion):
            frontend = Trajectory(stamps, np.array([r.frontend_pose for r in records]).reshape(n, 3)) if n else None
        totals: dict[str, int] = {}
        for r in records:
            for key, count in r.counts.items():
                totals[key] = totals.get(key, 0) + count
        submaps = self._slam if isinstance(self._slam, SubmapSLAM) else None
        sweep_time = 0.0
        if submaps is not None and not interrupted:
            t0 = time.perf_counter()
            with one_blas_thread():
                submaps.finish()     # the last submap frozen, its loop closures found
            if records:      # counted as the last scan's time: it is part of the first pass
                records[-1] = dataclasses.replace(records[-1], step_time_s=records[-1].step_time_s
                                                  + time.perf_counter() - t0)
            t0 = time.perf_counter()
            try:
                with one_blas_thread(), kernel_interrupts():
                    submaps.sweep_loops()    # end-of-run work, like the second pass: not a scan's
            except KeyboardInterrupt:
                interrupted = True
            sweep_time = time.perf_counter() - t0
        if submaps is not None:
            _add_submap_stats(totals, submaps)
        final_map = self.map
        relocalized, relocalize_time, points = None, 0.0, None
        if self.config.relocalize and n and not interrupted:
            t0 = time.perf_counter()
            try:
                with one_blas_thread(), kernel_interrupts():
                    if submaps is not None:
                        relocalized, points = relocalize_submaps(submaps, records, self.config, point_stride,
                                                                 progress)
                    else:
                        relocalized, points = relocalize(final_map, [r.replay for r in records], stamps,
                                                         self.config, *self._first, point_stride, progress)
                relocalize_time = time.perf_counter() - t0
            except KeyboardInterrupt:
                interrupted = True
        if points is None:   # no second pass: the scans at the online poses
            points = [_scan_points(r.scan, r.pose, r.laser_offset, point_stride) for r in records] if point_stride else []
        step_times = np.array([r.step_time_s for r in records])
        result = RunResult(
            name=name, estimate=estimate, relocalized=relocalized, odometry=odometry, frontend=frontend,
            ground_truth=ground_truth, map=final_map,
            wall_time_s=float(np.sum(step_times)) + sweep_time + relocalize_time, relocalize_time_s=relocalize_time,
            sweep_time_s=sweep_time,
            step_times_s=step_times, state_sizes=np.array([r.state_size for r in records], dtype=int),
            totals=totals, nis=np.array([r.nis for r in records]),
            nis_dof=np.array([r.nis_dof for r in records], dtype=int),
            points=np.vstack(points) if points else np.empty((0, 2)),
            skipped=skipped if skipped is not None else self.skipped,
            scans=[(r.scan, r.laser_offset) for r in records], interrupted=interrupted,
            stop_reason=stop_reason, submaps=submaps,
            step_submaps=np.array([r.submap for r in records], dtype=int),
        )
        self.viewer.finish(result)
        return result


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


def relocalize_submaps(slam: SubmapSLAM, records: list[_Record], config: SLAMConfig, point_stride: int = 0,
                       progress: Progress = _no_progress) -> tuple[Trajectory, list[np.ndarray]]:
    """The second pass of the submap backend: each submap's scans localised again in its
    own final map (:func:`relocalize`, in its frame, from its base at the origin), then
    put in the map frame by the optimised base pose, with the base's marginal covariance
    composed in. Submap k > 0 starts at the scan that ended submap k − 1.

    Returns the trajectory (one pose per record) and, with ``point_stride``, the filter
    steps' scan points (map frame).
    """
    n = len(records)
    poses, covs = np.empty((n, 3)), np.empty((n, 3, 3))
    points: list[np.ndarray] = []
    submap_of = np.array([r.submap for r in records])
    seed: _Record | None = None   # the last filter step of the previous submap
    done = 0
    for k in np.unique(submap_of):
        idx = np.flatnonzero(submap_of == k)
        replay = [records[i].replay for i in idx]
        stamps = np.array([records[i].stamp for i in idx])
        if seed is not None:
            replay.insert(0, dataclasses.replace(seed.replay, delta=None, covariance=None))
            stamps = np.r_[seed.stamp, stamps]
        skip = 0 if seed is None else 1
        # Progress per frame, not per submap: a submap is hundreds of frames, and an
        # interrupt raised from the callback must come as soon as it is asked for.
        local, local_points = relocalize(slam.local_map(int(k)), replay, stamps, config, np.zeros(3),
                                         np.zeros((3, 3)), point_stride,
                                         progress=lambda i, _: progress(done + max(i - skip, 0), n))
        if point_stride:
            local_points = local_points[skip:]
        base, base_cov = slam.base_of(int(k))
        for j, i in enumerate(idx):
            poses[i], covs[i] = compose_with_covariance(base, base_cov, local.poses[skip + j],
                                                        local.covariances[skip + j])
        points += [_transform_points(base, p) for p in local_points]
        steps = [i for i in idx if records[i].replay.scan is not None]
        seed = records[steps[-1]] if steps else seed
        done += idx.size
    stamps = np.array([r.stamp for r in records])
    return Trajectory(stamps, poses, covs), points


def _transform_points(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(k, 2) points of the frame at ``pose`` (3,) in the parent frame."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return pose[:2] + points @ np.array([[c, s], [-s, c]])


def _add_submap_stats(totals: dict[str, int], slam: SubmapSLAM) -> None:
    """The global layer's counters: submaps, loop-closure candidates, accepted and
    loop closures the graph down-weighted below ½ or set aside, rejections by reason, and
    with ``submaps.loop_slides`` the loop closures kept as slides."""
    stats = slam.stats
    totals["submaps"] = len(slam.frozen) + (1 if slam.local.steps > slam._seed_steps else 0)
    totals["loop_candidates"] = stats.loop_candidates
    totals["loop_closures"] = stats.loop_closures
    totals["loop_sweep_candidates"] = stats.sweep_candidates
    totals["loop_sweep_closures"] = stats.sweep_closures
    totals["online_match_candidates"] = stats.online_candidates
    totals["online_matches"] = stats.online_matches
    totals["loop_closures_downweighted"] = int(np.count_nonzero(slam.loop_weights() < 0.5))
    if slam.config.submaps.loop_slides:
        totals["loop_slides"] = sum(1 for loop in slam.loops if loop.slide)
    for reason, count in stats.loop_rejections.items():
        totals[f"loop_rejected_{reason}"] = count


def _pose(value, name: str) -> np.ndarray:
    """(3,) finite floats, or an InputError naming ``name``."""
    try:
        pose = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be 3 finite numbers (x, y, φ), got {value!r}") from None
    if pose.shape != (3,) or not np.all(np.isfinite(pose)):
        raise InputError(f"{name} must be 3 finite numbers (x, y, φ), got {value!r}")
    return pose


def _scan_points(scan: LaserScan, pose: np.ndarray, laser_offset: np.ndarray, stride: int) -> np.ndarray:
    """(k, 2) world points (m) of every ``stride``-th valid beam of ``scan`` taken at the
    robot ``pose`` (3,) with the laser at ``laser_offset`` (3,) in the robot frame."""
    ok = np.isfinite(scan.ranges) & (scan.ranges < scan.max_range) & (scan.ranges > 0)
    sel = np.flatnonzero(ok)[::stride]
    laser = compose(pose, laser_offset)
    bearing = laser[2] + scan.angles[sel]
    return laser[:2] + scan.ranges[sel, None] * np.column_stack([np.cos(bearing), np.sin(bearing)])


def _add_report(totals: dict[str, int], report) -> None:
    """Add one step report's counters to ``totals``."""
    totals["filter_steps"] = totals.get("filter_steps", 0) + 1
    for key in ("observed_splines", "matched_splines", "new_splines", "extended_splines",
                "pruned_splines", "beams_used"):
        totals[key] = totals.get(key, 0) + int(getattr(report, key))
    for reason, count in report.beams_dropped.items():
        totals[f"beams_dropped_{reason}"] = totals.get(f"beams_dropped_{reason}", 0) + count
    for reason, count in report.scan_counts.items():
        totals[f"scan_{reason}"] = totals.get(f"scan_{reason}", 0) + int(count)
