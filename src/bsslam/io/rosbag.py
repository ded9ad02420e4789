"""Streaming reader of ROS 1 bags and ROS 2 bags (sqlite3 or mcap) through ``rosbags``.

Frames come from one ``sensor_msgs/LaserScan`` topic; the odometry pose of each frame is
interpolated at the scan's header stamp from ``nav_msgs/Odometry`` (preferred) or from the
``odom → base`` transform in ``/tf``. Topics are found by type when not named: exactly one
LaserScan topic, and one Odometry topic or else ``/tf``; several candidates raise
:class:`~bsslam.errors.InputError` listing them.

Scans: bearings ``angle_min + i·angle_increment`` in the laser frame (reversed into
increasing order for a negative increment), ranges as float64. Following REP 117, +inf
is "no return" and NaN a failed measurement; ranges below ``range_min`` become NaN, ranges
≥ the no-return threshold (``range_max`` or ``ReaderConfig.no_return_m``) become +inf.

Laser offset: the laser frame's pose in the robot (odometry child) frame, composed from
``/tf_static`` when it links them; zero otherwise. Stamps are header stamps (the bag's
receive time when a header stamp is zero).

Validation (once, here, with :mod:`bsslam.input_limits` and ``ReaderConfig.limits``): a
scan's header must give finite angles, a non-zero ``angle_increment`` consistent with
``angle_max`` and at most ``max_beams`` beams; negative ranges become NaN; odometry poses
must be finite, within ``max_coordinate_m`` and move at a plausible speed (an implausible
step is bridged, see :class:`~bsslam.input_limits.OdometryGate`).

Scans before the first or after the last odometry are skipped and counted. Bad input (an
undecodable message, an invalid scan header, a duplicate or backwards stamp, an invalid
odometry pose, a bag that cannot be read to its end) is counted in ``skipped`` by default
and raises ``InputError`` with ``strict=True``; the "line" of an error is the message's
index in the stream (the scan and odometry topics together). A bag without one usable
scan raises ``InputError`` in both modes.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from bsslam.errors import MissingDependencyError

try:  # the optional extra bsslam[ros]; open_dataset imports this module only for bags
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.rosbag1 import ReaderError as Rosbag1Error
    from rosbags.rosbag2 import ReaderError as Rosbag2Error
    from rosbags.typesys import Stores, get_typestore
except ImportError as exc:
    raise MissingDependencyError(f"reading ROS bags needs the rosbags package ({exc}): "
                                 "pip install 'bsslam[ros]'") from None

from bsslam.dataset import Frame
from bsslam.errors import InputError
from bsslam.input_limits import beam_geometry_problem, invalid_ranges, pose_problem
from bsslam.io.input_issues import CheckedReader, InputIssues, require_regular_file
from bsslam.io.no_return import mark_no_return, no_return_threshold
from bsslam.io.odometry_sync import OdometrySync
from bsslam.io.quaternion import yaw_from_quaternion
from bsslam.io.reader_config import ReaderConfig
from bsslam.scan.laser_scan import LaserScan
from bsslam.se2 import compose
from bsslam.trajectory import Trajectory

logger = logging.getLogger(__name__)

LASER_SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOMETRY_TYPE = "nav_msgs/msg/Odometry"
TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
_BAG_ERRORS = (AnyReaderError, Rosbag1Error, Rosbag2Error, OSError, KeyError, ValueError)
# Longest chain of /tf_static links followed from the laser frame to the robot frame.
_MAX_TF_HOPS = 16


def _stamp(header: Any, bag_time_ns: int) -> float:
    """Header stamp (s), or the bag's receive time when the header stamp is unset."""
    stamp = header.stamp.sec + header.stamp.nanosec * 1e-9
    return stamp if stamp > 0 else bag_time_ns * 1e-9


def _frame_id(name: str) -> str:
    return name.lstrip("/")  # ROS 1 tf_prefix style "/odom" is the same frame as "odom"


def _pose_2d(translation: Any, rotation: Any) -> np.ndarray:
    """(3,) planar pose (x m, y m, φ rad) of a 3-D translation and quaternion."""
    yaw = yaw_from_quaternion(rotation.x, rotation.y, rotation.z, rotation.w)
    return np.array([translation.x, translation.y, yaw], dtype=float)


def _pick(kind: str, candidates: list[str], option: str) -> str:
    if len(candidates) == 1:
        return candidates[0]
    raise InputError(f"{len(candidates)} {kind} topics ({', '.join(candidates)}); choose one with {option}")


class RosbagReader(CheckedReader):
    """A :class:`~bsslam.dataset.Dataset` over a ROS 1 ``.bag``, a ROS 2 bag folder, or a
    single ``.db3``/``.mcap`` file.

    Args:
        path: the bag.
        strict: raise :class:`InputError` on bad input instead of counting a skip.
        config: no-return threshold and ``/tf`` frame names; defaults if None.
        scan_topic: the LaserScan topic; None finds the only one.
        odom_topic: an Odometry topic or a tf topic; None prefers the only Odometry topic,
            then ``/tf``.
        ground_truth: an optional reference trajectory to carry along.

    Raises:
        InputError: unreadable bag, missing or ambiguous topics (at construction).
    """

    _logger = logger   # the pass's summary warning (CheckedReader)

    def __init__(self, path: str | os.PathLike, *, strict: bool = False, config: ReaderConfig | None = None,
                 scan_topic: str | None = None, odom_topic: str | None = None,
                 ground_truth: Trajectory | None = None):
        self.path = os.fspath(path)
        self.name = Path(self.path).stem or Path(self.path).name
        self.strict = strict
        self.config = config or ReaderConfig()
        self.ground_truth = ground_truth
        self._issues = InputIssues(self.path, strict)
        self._is_ros1 = Path(self.path).suffix == ".bag"
        if Path(self.path).exists() and not Path(self.path).is_dir():
            require_regular_file(self.path)   # a FIFO would block the bag reader
        with self._open() as reader:
            topics = {c.topic: c.msgtype for c in reader.connections}
            counts = [(c.topic, c.msgcount) for c in reader.connections]
        self.scan_topic, self.odom_topic, self.odometry_from_tf = self._choose_topics(topics, scan_topic, odom_topic)
        #: the frames a pass will yield at most, for progress: the scan topic's messages
        self.expected_frames = sum(n for topic, n in counts if topic == self.scan_topic)
        self._static_topics = [t for t, ty in topics.items() if ty in TF_TYPES and t.strip("/") == "tf_static"]

    # -- opening ------------------------------------------------------------------------
    @contextlib.contextmanager
    def _open(self) -> Iterator[AnyReader]:
        """An open AnyReader, closed afterwards; rosbags failures to open become InputError."""
        # bags without embedded message definitions (e.g. a bare .db3) need a default store
        store = get_typestore(Stores.ROS1_NOETIC if self._is_ros1 else Stores.ROS2_HUMBLE)
        try:
            reader = AnyReader([Path(self.path)], default_typestore=store)
            reader.open()
        except _BAG_ERRORS as exc:
            raise InputError(f"cannot read bag: {exc}", self.path) from None
        try:
            yield reader
        finally:
            reader.close()

    def _choose_topics(self, topics: dict[str, str], scan_topic: str | None,
                       odom_topic: str | None) -> tuple[str, str, bool]:
        listing = ", ".join(f"{t} [{ty}]" for t, ty in sorted(topics.items())) or "none"
        try:
            if scan_topic is None:
                scans = sorted(t for t, ty in topics.items() if ty == LASER_SCAN_TYPE)
                if not scans:
                    raise InputError(f"no {LASER_SCAN_TYPE} topic; topics: {listing}")
                scan_topic = _pick("LaserScan", scans, "scan_topic")
            elif topics.get(scan_topic) != LASER_SCAN_TYPE:
                raise InputError(f"scan topic {scan_topic!r} is not a {LASER_SCAN_TYPE} topic; topics: {listing}")
            if odom_topic is None:
                odometry = sorted(t for t, ty in topics.items() if ty == ODOMETRY_TYPE)
                tf = sorted(t for t, ty in topics.items() if ty in TF_TYPES and t.strip("/") == "tf")
                if odometry:
                    odom_topic = _pick("Odometry", odometry, "odom_topic")
                elif tf:
                    odom_topic = tf[0]
                else:
                    raise InputError(f"no odometry: no {ODOMETRY_TYPE} topic and no /tf; topics: {listing}")
            elif topics.get(odom_topic) not in (ODOMETRY_TYPE, *TF_TYPES):
                raise InputError(f"odometry topic {odom_topic!r} is neither Odometry nor tf; topics: {listing}")
        except InputError as exc:
            raise InputError(str(exc), self.path) from None
        return scan_topic, odom_topic, topics[odom_topic] in TF_TYPES

    # -- reading ------------------------------------------------------------------------
    def _numbered_frames(self) -> Iterator[tuple[int, Frame]]:
        """(message index, frame) of every scan that passed the message-level checks."""
        sync = OdometrySync()
        last_scan = last_odometry = None
        base_frame = self.config.tf_base_frame
        offsets: dict[str, np.ndarray] = {}
        with self._open() as reader:
            statics = self._static_transforms(reader)
            wanted = [c for c in reader.connections if c.topic in (self.scan_topic, self.odom_topic)]
            index = 0
            messages = reader.messages(connections=wanted)
            while True:
                try:
                    connection, bag_ns, raw = next(messages)
                except StopIteration:
                    break
                except _BAG_ERRORS as exc:
                    self._issues.problem("unreadable rest of the bag", index + 1, str(exc))
                    break
                index += 1
                try:
                    msg = reader.deserialize(raw, connection.msgtype)
                except _BAG_ERRORS as exc:
                    self._issues.problem(f"undecodable {connection.topic} message", index, str(exc))
                    continue
                if connection.topic == self.scan_topic:
                    scan = self._scan(msg, bag_ns, index)
                    if scan is not None and self._issues.stamp_advances(scan.stamp, last_scan, "scan", index):
                        last_scan = scan.stamp
                        sync.add_scan(scan.stamp, (index, scan, _frame_id(msg.header.frame_id)))
                else:
                    for stamp, pose, child in self._odometry(msg, bag_ns, base_frame):
                        base_frame = base_frame or child
                        reason = pose_problem(pose, self.config.limits)
                        if reason is not None:
                            self._issues.problem(f"{reason} in {connection.topic}", index)
                            continue
                        if self._issues.stamp_advances(stamp, last_odometry, "odometry", index):
                            last_odometry = stamp
                            sync.add_odometry(stamp, pose)
                yield from self._release(sync, False, statics, base_frame, offsets)
            yield from self._release(sync, True, statics, base_frame, offsets)

    def _scan(self, msg: Any, bag_ns: int, index: int) -> LaserScan | None:
        ranges = np.asarray(msg.ranges, dtype=float)
        reason = beam_geometry_problem(ranges.size, float(msg.angle_min), float(msg.angle_increment),
                                       self.config.limits, end_rad=float(msg.angle_max))
        if reason is not None:
            self._issues.problem(reason, index, f"{self.scan_topic}: {ranges.size} beams, angle_min "
                                 f"{msg.angle_min}, angle_increment {msg.angle_increment}, angle_max {msg.angle_max}")
            return None
        ranges, _, _ = invalid_ranges(ranges)   # negative → NaN; NaN is a failed beam (REP 117)
        angles = float(msg.angle_min) + float(msg.angle_increment) * np.arange(ranges.size)
        # the time from the first beam to the last, in the message's order (0: not given)
        sweep = float(msg.time_increment) * (ranges.size - 1)
        if not (math.isfinite(sweep) and abs(sweep) <= 1.0):
            self._issues.problem("implausible time_increment (scan taken as instantaneous)", index,
                                 f"{self.scan_topic}: time_increment {msg.time_increment}")
            sweep = 0.0
        if msg.angle_increment < 0:  # a laser mounted upside down: keep bearings increasing
            angles, ranges, sweep = angles[::-1], ranges[::-1], -sweep
        if msg.range_min > 0:
            with np.errstate(invalid="ignore"):
                ranges = np.where(ranges < msg.range_min, np.nan, ranges)
        threshold = no_return_threshold(self.config, float(msg.range_max))
        try:
            return LaserScan(_stamp(msg.header, bag_ns), angles, mark_no_return(ranges, threshold), threshold, sweep)
        except InputError as exc:
            self._issues.problem("invalid scan geometry", index, str(exc))
            return None

    def _odometry(self, msg: Any, bag_ns: int, base_frame: str | None) -> Iterator[tuple[float, np.ndarray, str]]:
        """(stamp, pose (3,), robot frame) of each odometry sample in ``msg``."""
        if not self.odometry_from_tf:
            yield (_stamp(msg.header, bag_ns), _pose_2d(msg.pose.pose.position, msg.pose.pose.orientation),
                   _frame_id(msg.child_frame_id))
            return
        for tf in msg.transforms:
            child = _frame_id(tf.child_frame_id)
            if _frame_id(tf.header.frame_id) == self.config.tf_odom_frame and base_frame in (None, child):
                yield _stamp(tf.header, bag_ns), _pose_2d(tf.transform.translation, tf.transform.rotation), child
                base_frame = child

    def _static_transforms(self, reader: AnyReader) -> dict[str, tuple[str, np.ndarray]]:
        """child frame → (parent frame, planar pose in the parent) from /tf_static."""
        links: dict[str, tuple[str, np.ndarray]] = {}
        connections = [c for c in reader.connections if c.topic in self._static_topics]
        if not connections:
            return links
        try:
            for connection, _, raw in reader.messages(connections=connections):
                for tf in reader.deserialize(raw, connection.msgtype).transforms:
                    links[_frame_id(tf.child_frame_id)] = (
                        _frame_id(tf.header.frame_id), _pose_2d(tf.transform.translation, tf.transform.rotation))
        except _BAG_ERRORS as exc:
            logger.warning("%s: /tf_static unreadable, laser offsets set to zero: %s", self.path, exc)
        return links

    def _laser_offset(self, laser_frame: str, base_frame: str | None,
                      statics: dict[str, tuple[str, np.ndarray]]) -> np.ndarray:
        """Pose (3,) of ``laser_frame`` in ``base_frame`` by chaining /tf_static links."""
        offset, frame = np.zeros(3), laser_frame
        for _ in range(_MAX_TF_HOPS):
            if frame == base_frame or frame not in statics:
                break
            parent, pose = statics[frame]
            offset, frame = compose(pose, offset), parent
        if frame != base_frame and laser_frame:
            logger.warning("%s: no /tf_static path from %r to %r; laser offset set to zero",
                           self.path, laser_frame, base_frame)
            return np.zeros(3)
        return offset

    def _release(self, sync: OdometrySync, final: bool, statics, base_frame, offsets) -> Iterator[tuple[int, Frame]]:
        for (index, scan, laser_frame), pose, reason in sync.ready(final):
            if pose is None:
                # expected at the edges of a recording, so counted even in strict mode
                self._issues.skip(reason, index)
                continue
            if laser_frame not in offsets:
                offsets[laser_frame] = self._laser_offset(laser_frame, base_frame, statics)
            yield index, Frame(scan.stamp, pose, scan, offsets[laser_frame].copy())
