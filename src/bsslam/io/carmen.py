"""Streaming reader of CARMEN laser logs (``.clf``, ``.log``, ``.carmen``).

One laser stream is turned into frames (see ``ReaderConfig.laser_message``), one line at a
time; the whole log is never held in memory.

Odometry of a frame:

* FLASER/RLASER carry two pose triples, ``x y theta`` (the laser's pose) and
  ``odom_x odom_y odom_theta`` (the robot's odometry pose); CARMEN derives the first from the
  second with the laser offset. :attr:`Frame.odometry` is the second triple, the robot's
  dead-reckoning pose. In the shipped logs both triples are equal (no laser offset) and
  equal the ODOM message at the same stamp; in ``intel-corrected.log`` both hold the
  GMapping-corrected poses (its ODOM lines are all zero), so "odometry" there is corrected.
* ROBOTLASER1/2: the robot pose of the message.
* RAWLASER1–4: ODOM messages interpolated at the scan stamp (scans before the first or
  after the last ODOM are skipped and counted). ODOM lines are read only for these
  streams; otherwise they are counted as unused.

Laser offset (:attr:`Frame.laser_offset`, the laser's pose in the robot frame; the scan's
angles stay in the laser frame): for ROBOTLASER and for FLASER/RLASER whose two triples
differ, the laser pose seen from the robot pose; otherwise from PARAM
``robot_{front,rear}laser_{offset,side_offset,angular_offset}`` (m, m, rad; 0 when absent),
the rear laser turned by π as GMapping's CARMEN reader does. RAWLASER1 uses the front
laser's PARAM offset, RAWLASER2 the rear's, RAWLASER3/4 none.

Stamps are ipc timestamps (see :mod:`bsslam.io.carmen_messages`). Ranges at or above the
no-return threshold become +inf (see :class:`~bsslam.io.reader_config.ReaderConfig`).

Bad input — a malformed line, NaN/inf ranges (the beams are kept as NaN/inf, the scan is
used), an empty scan, a duplicate or backwards timestamp, a truncated last line — is
counted in ``skipped`` with its ``path:line`` by default, and raises
:class:`~bsslam.errors.InputError` with ``strict=True``. Message types not used are
counted by type; comments and blank lines are ignored.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from bsslam.dataset import Frame, SkipCounter
from bsslam.errors import InputError
from bsslam.io.carmen_messages import LASER_PARSERS, LaserMessage, MalformedLine, parse_odom, parse_param
from bsslam.io.input_issues import InputIssues
from bsslam.io.no_return import detect_no_return_code, mark_no_return, no_return_threshold
from bsslam.io.odometry_sync import OdometrySync
from bsslam.io.reader_config import CARMEN_LASER_MESSAGES, ReaderConfig
from bsslam.scan.laser_scan import LaserScan
from bsslam.se2 import between
from bsslam.trajectory import Trajectory, wrap_angle

logger = logging.getLogger(__name__)

# Two pose triples closer than this (m, rad) are "equal": the logs print 6 decimals.
_SAME_POSE_TOLERANCE = 1e-4
# The head survey stops after this many lines even if few laser messages were seen.
_SURVEY_MAX_LINES = 50_000

_PARAM_OFFSETS = {
    "robot_frontlaser_offset": ("front", 0), "robot_frontlaser_side_offset": ("front", 1),
    "robot_frontlaser_angular_offset": ("front", 2),
    "robot_rearlaser_offset": ("rear", 0), "robot_rearlaser_side_offset": ("rear", 1),
    "robot_rearlaser_angular_offset": ("rear", 2),
}
_MOUNT_OF = {"FLASER": "front", "ROBOTLASER1": "front", "RAWLASER1": "front",
             "RLASER": "rear", "ROBOTLASER2": "rear", "RAWLASER2": "rear"}


@dataclass
class _StreamState:
    """What one pass over the log remembers between lines."""

    sync: OdometrySync = field(default_factory=OdometrySync)
    last_scan_stamp: float | None = None
    last_odom_stamp: float | None = None
    mounts: dict[str, np.ndarray] = field(
        default_factory=lambda: {"front": np.zeros(3), "rear": np.zeros(3)})

    def param_offset(self, kind: str) -> np.ndarray:
        mount = _MOUNT_OF.get(kind)
        if mount is None:
            return np.zeros(3)
        offset = self.mounts[mount].copy()
        if mount == "rear":
            offset[2] = float(wrap_angle(offset[2] + math.pi))
        return offset


class CarmenReader:
    """A :class:`~bsslam.dataset.Dataset` over one CARMEN log.

    Args:
        path: the log file.
        strict: raise :class:`InputError` on bad input instead of counting a skip.
        config: reader settings (no-return rule, laser stream); defaults if None.
        ground_truth: an optional reference trajectory to carry along.

    Attributes:
        name: the file's stem.
        laser_message: the laser stream read (None until one is seen if the start of
            the log has none).
        no_return_code_m: the detected no-return code (m) or None.
        skipped: counts of what the last pass skipped, with the first locations.

    Raises:
        InputError: the file is missing or unreadable (at construction).
    """

    def __init__(self, path: str | os.PathLike, *, strict: bool = False,
                 config: ReaderConfig | None = None, ground_truth: Trajectory | None = None):
        self.path = os.fspath(path)
        self.name = Path(self.path).stem
        self.strict = strict
        self.config = config or ReaderConfig()
        self.ground_truth = ground_truth
        self._issues = InputIssues(self.path, strict)
        kinds, maxima = self._survey_head()
        self.laser_message = self.config.laser_message or next(
            (k for k in CARMEN_LASER_MESSAGES if k in kinds), None)
        self.no_return_code_m = None
        if self.config.detect_no_return_code and self.laser_message in maxima:
            self.no_return_code_m = detect_no_return_code(maxima[self.laser_message], self.config)

    # -- reading ----------------------------------------------------------------------
    def _lines(self) -> Iterator[tuple[int, str]]:
        """(1-based number, text) of every line; unreadable files become InputError."""
        try:
            # errors="replace": a corrupt byte makes one malformed line, not a crash
            handle = open(self.path, encoding="utf-8", errors="replace")
        except OSError as exc:
            raise InputError(f"cannot read CARMEN log: {exc.strerror or exc}", self.path) from None
        number = 0
        with handle:
            try:
                for number, line in enumerate(handle, start=1):
                    yield number, line
            except OSError as exc:
                raise InputError(f"read error: {exc.strerror or exc}", self.path, number + 1) from None

    def _survey_head(self) -> tuple[set[str], dict[str, list[float]]]:
        """Laser message types present at the start of the log and, per type, the largest
        finite range of each of its first scans (for the no-return code)."""
        maxima: dict[str, list[float]] = {}
        wanted = self.config.code_detection_scans
        with contextlib.closing(self._lines()) as lines:
            for number, line in lines:
                if number > _SURVEY_MAX_LINES:
                    break
                fields = line.split()
                parser = LASER_PARSERS.get(fields[0]) if fields else None
                if parser is None:
                    continue
                seen = maxima.setdefault(fields[0], [])
                try:
                    ranges = parser(fields).ranges
                except MalformedLine:
                    continue  # reported by the real pass
                finite = ranges[np.isfinite(ranges)]
                if finite.size:
                    seen.append(float(finite.max()))
                if len(seen) >= wanted:
                    break
        return set(maxima), maxima

    @property
    def skipped(self) -> SkipCounter:
        """What the last pass skipped (counts and first locations)."""
        return self._issues.skipped

    def __iter__(self) -> Iterator[Frame]:
        self._issues = InputIssues(self.path, self.strict)
        state = _StreamState()
        for number, line in self._lines():
            fields = line.split()
            if not fields or fields[0].startswith("#"):
                continue
            kind = fields[0]
            try:
                if kind in LASER_PARSERS:
                    yield from self._on_laser(fields, number, state)
                elif kind == "ODOM":
                    yield from self._on_odom(fields, number, state)
                elif kind == "PARAM":
                    self._on_param(fields, number, state)
                else:
                    self._issues.skip(f"unused message type {kind}")
            except MalformedLine as exc:
                # only the last line can lack its newline: the log was cut while writing
                reason = (f"malformed {kind} line ({exc.reason})" if line.endswith("\n")
                          else "truncated last line")
                self._issues.problem(reason, number, exc.detail)
        yield from self._release(state, final=True)
        self._issues.log_summary(logger)

    def _on_laser(self, fields: list[str], number: int, state: _StreamState) -> Iterator[Frame]:
        kind = fields[0]
        if self.laser_message is None:
            self.laser_message = kind  # the head of the log had no laser message
        if kind != self.laser_message:
            self._issues.skip(f"unused laser stream {kind}")
            return
        msg = LASER_PARSERS[kind](fields)
        if msg.ranges.size == 0:
            self._issues.problem("empty scan", number)
            return
        if not self._issues.stamp_advances(msg.stamp, state.last_scan_stamp, "scan", number):
            return
        state.last_scan_stamp = msg.stamp
        if not np.all(np.isfinite(msg.ranges)):
            self._issues.problem("NaN/inf ranges (kept as invalid beams)", number)
        threshold = no_return_threshold(self.config, msg.max_range_m, self.no_return_code_m)
        try:
            scan = LaserScan(msg.stamp, msg.angles, mark_no_return(msg.ranges, threshold), threshold)
        except InputError as exc:
            self._issues.problem(f"malformed {kind} line (invalid beam geometry)", number, str(exc))
            return
        offset = self._laser_offset(msg, state)
        if msg.robot_pose is not None:
            yield Frame(msg.stamp, msg.robot_pose, scan, offset)
        else:
            state.sync.add_scan(msg.stamp, (number, scan, offset))
            yield from self._release(state)

    def _on_odom(self, fields: list[str], number: int, state: _StreamState) -> Iterator[Frame]:
        if self.laser_message is not None and not self.laser_message.startswith("RAWLASER"):
            # the laser messages carry their own odometry pose; ODOM lines are not read
            # (intel-corrected.log has thousands of out-of-order ones)
            self._issues.skip("unused message type ODOM")
            return
        stamp, pose = parse_odom(fields)
        if not self._issues.stamp_advances(stamp, state.last_odom_stamp, "ODOM", number):
            return
        state.last_odom_stamp = stamp
        state.sync.add_odometry(stamp, pose)
        yield from self._release(state)

    def _on_param(self, fields: list[str], number: int, state: _StreamState) -> None:
        name, value = parse_param(fields)
        target = _PARAM_OFFSETS.get(name)
        if target is None:
            return
        try:
            state.mounts[target[0]][target[1]] = float(value)
        except ValueError:
            raise MalformedLine("non-numeric value", f"{name} = {value!r}") from None

    def _release(self, state: _StreamState, final: bool = False) -> Iterator[Frame]:
        for (number, scan, offset), pose, reason in state.sync.ready(final):
            if pose is None:
                # expected at the edges of a log, so counted even in strict mode
                self._issues.skip(reason, number)
            else:
                yield Frame(scan.stamp, pose, scan, offset)

    # -- helpers ----------------------------------------------------------------------
    def _laser_offset(self, msg: LaserMessage, state: _StreamState) -> np.ndarray:
        if msg.laser_pose is None:
            return state.param_offset(msg.kind)
        relative = between(msg.robot_pose, msg.laser_pose)
        if msg.kind.startswith("ROBOTLASER") or np.max(np.abs(relative)) > _SAME_POSE_TOLERANCE:
            return relative
        return state.param_offset(msg.kind)
