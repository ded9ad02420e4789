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
  streams; otherwise they are ignored (counted silently under ``other_messages``).

Laser offset (:attr:`Frame.laser_offset`, the laser's pose in the robot frame; the scan's
angles stay in the laser frame): for ROBOTLASER and for FLASER/RLASER whose two triples
differ, the laser pose seen from the robot pose; otherwise from PARAM
``robot_{front,rear}laser_{offset,side_offset,angular_offset}`` (m, m, rad; 0 when absent),
the rear laser turned by π as GMapping's CARMEN reader does. RAWLASER1 uses the front
laser's PARAM offset, RAWLASER2 the rear's, RAWLASER3/4 none.

Stamps are ipc timestamps (see :mod:`bsslam.io.carmen_messages`). Ranges at or above the
no-return threshold become +inf (see :class:`~bsslam.io.reader_config.ReaderConfig`).

Laser stream: ``ReaderConfig.laser_message``, else the preferred type among those holding
at least half as many *valid* scans as the richest one in the head of the log (so a few
malformed lines of one type cannot make the reader drop every scan of another).

Validation (once, here, with :mod:`bsslam.input_limits` and ``ReaderConfig.limits``):
beam count ≤ ``max_beams`` and the line no longer than such a scan can be; bearings
finite and strictly increasing within a turn (angle increment ≠ 0); NaN/inf and negative
ranges kept as invalid beams (counted); odometry poses finite, within
``max_coordinate_m`` and moving at a plausible speed (an implausible step is bridged with
the previous velocity, see :class:`~bsslam.input_limits.OdometryGate`); headings wrapped; laser
offsets (PARAM or the message's laser pose) finite and within ``max_laser_offset_m``.

Bad input — a malformed line, invalid beams, an empty scan, a duplicate or backwards
timestamp, a truncated last line, an implausible odometry step — is counted in ``skipped``
with its ``path:line`` by default, and raises :class:`~bsslam.errors.InputError` with
``strict=True``. Message types the reader does not use are counted silently in
``skipped.ignored["other_messages"]``; comments and blank lines are ignored. A log without
a single usable scan, a FIFO/device, and binary content (gzip, UTF-16, images) raise
:class:`~bsslam.errors.InputError` in both modes. A UTF-8 byte-order mark and CRLF line ends
are accepted.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import os
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterator

import numpy as np

from bsslam.dataset import Frame
from bsslam.errors import InputError
from bsslam.io.carmen_messages import LASER_PARSERS, LaserMessage, MalformedLine, parse_odom, parse_param
from bsslam.input_limits import angles_problem, invalid_ranges, offset_problem, pose_problem, wrap
from bsslam.io.input_issues import CheckedReader, InputIssues, require_regular_file
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
# Characters one range takes at most in a sane log ("12.345678 "), and the rest of a line.
_CHARS_PER_BEAM = 64
_LINE_OVERHEAD_CHARS = 4096
# Leading bytes of binary formats people hand over by mistake.
_MAGIC = ((b"\x1f\x8b", "gzip-compressed data; decompress it first"),
          (b"\xff\xfe", "UTF-16 text; convert it to UTF-8"),
          (b"\xfe\xff", "UTF-16 text; convert it to UTF-8"),
          (b"\x89PNG", "a PNG image, not a CARMEN log"),
          (b"BZh", "bzip2-compressed data; decompress it first"),
          (b"\xfd7zXZ", "xz-compressed data; decompress it first"),
          (b"PK\x03\x04", "a zip archive; extract it first"))

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


class CarmenReader(CheckedReader):
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
        expected_frames: the frames a pass will yield at most, for progress: the log's
            lines of that stream (bad ones are skipped); None when the head of the log
            holds no valid scan.
        no_return_code_m: the detected no-return code (m) or None.
        skipped: counts of what the last pass skipped, with the first locations.

    Raises:
        InputError: the file is missing or unreadable (at construction).
    """

    _logger = logger   # the pass's summary warning (CheckedReader)

    def __init__(self, path: str | os.PathLike, *, strict: bool = False,
                 config: ReaderConfig | None = None, ground_truth: Trajectory | None = None):
        self.path = os.fspath(path)
        self.name = Path(self.path).stem
        self.strict = strict
        self.config = config or ReaderConfig()
        self.ground_truth = ground_truth
        self._issues = InputIssues(self.path, strict)
        self._max_line_chars = _CHARS_PER_BEAM * self.config.limits.max_beams + _LINE_OVERHEAD_CHARS
        self._check_content()
        valid, maxima = self._survey_head()
        self.laser_message = self.config.laser_message or self._choose_stream(valid)
        self.no_return_code_m = None
        if self.config.detect_no_return_code and self.laser_message in maxima:
            self.no_return_code_m = detect_no_return_code(maxima[self.laser_message], self.config)

    # -- reading ----------------------------------------------------------------------
    def _check_content(self) -> None:
        """Refuse a FIFO/device (before opening it) and binary content, with a clear error."""
        require_regular_file(self.path)
        try:
            with open(self.path, "rb") as handle:
                head = handle.read(4096)
        except OSError as exc:
            raise InputError(f"cannot read CARMEN log: {exc.strerror or exc}", self.path) from None
        for magic, what in _MAGIC:
            if head.startswith(magic):
                raise InputError(f"{what} (expected a CARMEN text log)", self.path)
        if b"\x00" in head:
            raise InputError("binary data, not a CARMEN text log", self.path)

    def _lines(self) -> Iterator[tuple[int, str | None]]:
        """(1-based number, text) of every line, text None for a line longer than any sane
        scan (its rest is read and dropped); unreadable files become InputError."""
        try:
            # errors="replace": a corrupt byte makes one malformed line, not a crash;
            # utf-8-sig: a byte-order mark is dropped
            handle = open(self.path, encoding="utf-8-sig", errors="replace")
        except OSError as exc:
            raise InputError(f"cannot read CARMEN log: {exc.strerror or exc}", self.path) from None
        number, limit = 0, self._max_line_chars
        with handle:
            try:
                while line := handle.readline(limit):
                    number += 1
                    if len(line) >= limit and not line.endswith("\n"):
                        while (rest := handle.readline(limit)) and not rest.endswith("\n"):
                            pass
                        yield number, None
                    else:
                        yield number, line
            except OSError as exc:
                raise InputError(f"read error: {exc.strerror or exc}", self.path, number + 1) from None

    @functools.cached_property
    def expected_frames(self) -> int | None:
        """The frames a pass will yield at most (see the class's attributes); the log is read
        for it when it is first asked for, not when the reader opens it."""
        return None if self.laser_message is None else self._count_lines(self.laser_message)

    def _count_lines(self, message: str) -> int:
        """The lines of the log that start with ``message`` and a blank, counted in the raw
        bytes a megabyte at a time (a few milliseconds a megabyte)."""
        pattern = b"\n" + message.encode("ascii") + b" "
        count, tail, first = 0, b"\n", True    # the first line: as if a newline came before it
        try:
            with open(self.path, "rb") as handle:
                while chunk := handle.read(1 << 20):
                    if first:
                        chunk, first = chunk.removeprefix(b"\xef\xbb\xbf"), False   # a byte-order mark
                    block = tail + chunk
                    count += block.count(pattern)
                    tail = block[-(len(pattern) - 1):]   # shorter than a match: none counted twice
        except OSError as exc:
            raise InputError(f"cannot read CARMEN log: {exc.strerror or exc}", self.path) from None
        return count

    def _survey_head(self) -> tuple[Counter, dict[str, list[float]]]:
        """Valid scans per laser message type at the start of the log and, per type, the
        largest finite range of each of its first valid scans (for the no-return code)."""
        valid: Counter = Counter()
        maxima: dict[str, list[float]] = {}
        wanted = self.config.code_detection_scans
        with contextlib.closing(self._lines()) as lines:
            for number, line in lines:
                if number > _SURVEY_MAX_LINES:
                    break
                fields = line.split() if line is not None else None
                parser = LASER_PARSERS.get(fields[0]) if fields else None
                if parser is None:
                    continue
                try:
                    msg = _increasing(parser(fields))
                except MalformedLine:
                    continue  # reported by the real pass
                if angles_problem(msg.angles, self.config.limits) is not None:
                    continue
                valid[msg.kind] += 1
                seen = maxima.setdefault(msg.kind, [])
                finite = msg.ranges[np.isfinite(msg.ranges)]
                if finite.size:
                    seen.append(float(finite.max()))
                if valid[msg.kind] >= wanted:
                    break
        return valid, maxima

    @staticmethod
    def _choose_stream(valid: Counter) -> str | None:
        """The preferred laser type among those with at least half the valid scans of the
        richest one; None when the head of the log holds no valid scan."""
        if not valid:
            return None
        top = max(valid.values())
        return next(k for k in CARMEN_LASER_MESSAGES if 2 * valid.get(k, 0) >= top)

    def _numbered_frames(self) -> Iterator[tuple[int, Frame]]:
        """(line, frame) of every scan that passed the line-level checks, before the
        odometry check."""
        state = _StreamState()
        for number, line in self._lines():
            if line is None:
                self._issues.problem("line too long", number, f"more than {self._max_line_chars} characters")
                continue
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
                    self._issues.ignore()
            except MalformedLine as exc:
                # only the last line can lack its newline: the log was cut while writing
                reason = (f"malformed {kind[:20]} line ({exc.reason})" if line.endswith("\n")
                          else "truncated last line")
                self._issues.problem(reason, number, exc.detail)
        yield from self._release(state, final=True)

    def _on_laser(self, fields: list[str], number: int, state: _StreamState) -> Iterator[tuple[int, Frame]]:
        kind = fields[0]
        if self.laser_message is not None and kind != self.laser_message:
            self._issues.ignore()  # another laser stream (often the same laser twice)
            return
        msg = LASER_PARSERS[kind](fields)
        sweep = _sweep_time(msg.angles, self.config.carmen_sweep_time_s)
        msg = _increasing(msg)
        reason = angles_problem(msg.angles, self.config.limits)
        if reason is not None:
            self._issues.problem(reason, number, f"{kind} with {msg.angles.size} beams")
            return
        if self.laser_message is None:
            self.laser_message = kind  # the head of the log had no valid laser message
        if not self._issues.stamp_advances(msg.stamp, state.last_scan_stamp, "scan", number):
            return
        state.last_scan_stamp = msg.stamp
        ranges, nonfinite, negative = invalid_ranges(msg.ranges)
        if nonfinite:
            self._issues.problem("NaN/inf ranges (kept as invalid beams)", number)
        if negative:
            self._issues.problem("negative ranges (kept as invalid beams)", number)
        threshold = no_return_threshold(self.config, msg.max_range_m, self.no_return_code_m)
        scan = LaserScan(msg.stamp, msg.angles, mark_no_return(ranges, threshold), threshold, sweep)
        offset = self._laser_offset(msg, state, number)
        if msg.robot_pose is not None:
            yield number, Frame(msg.stamp, msg.robot_pose, scan, offset)
        else:
            state.sync.add_scan(msg.stamp, (number, scan, offset))
            yield from self._release(state)

    def _on_odom(self, fields: list[str], number: int, state: _StreamState) -> Iterator[tuple[int, Frame]]:
        if self.laser_message is not None and not self.laser_message.startswith("RAWLASER"):
            # the laser messages carry their own odometry pose; ODOM lines are not read
            # (intel-corrected.log has thousands of out-of-order ones)
            self._issues.ignore()
            return
        stamp, pose = parse_odom(fields)
        reason = pose_problem(pose, self.config.limits)
        if reason is not None:
            self._issues.problem(f"{reason} in ODOM", number)
            return
        if not self._issues.stamp_advances(stamp, state.last_odom_stamp, "ODOM", number):
            return
        state.last_odom_stamp = stamp
        pose[2] = wrap(float(pose[2]))
        state.sync.add_odometry(stamp, pose)
        yield from self._release(state)

    def _on_param(self, fields: list[str], number: int, state: _StreamState) -> None:
        name, value = parse_param(fields)
        target = _PARAM_OFFSETS.get(name)
        if target is None:
            return
        try:
            number_value = float(value)
        except ValueError:
            raise MalformedLine("non-numeric value", f"{name} = {value!r}") from None
        # an angular offset beyond a full turn is garbage, not a mounting
        limit = 2.0 * math.pi if target[1] == 2 else self.config.limits.max_laser_offset_m
        if not (math.isfinite(number_value) and abs(number_value) <= limit):
            self._issues.problem("invalid laser offset in PARAM (ignored)", number, f"{name} = {value!r}")
            return
        state.mounts[target[0]][target[1]] = wrap(number_value) if target[1] == 2 else number_value

    def _release(self, state: _StreamState, final: bool = False) -> Iterator[tuple[int, Frame]]:
        for (number, scan, offset), pose, reason in state.sync.ready(final):
            if pose is None:
                # expected at the edges of a log, so counted even in strict mode
                self._issues.skip(reason, number)
            else:
                yield number, Frame(scan.stamp, pose, scan, offset)

    # -- helpers ----------------------------------------------------------------------
    def _laser_offset(self, msg: LaserMessage, state: _StreamState, number: int) -> np.ndarray:
        if msg.laser_pose is None:
            return state.param_offset(msg.kind)
        limits = self.config.limits
        if pose_problem(msg.robot_pose, limits) is not None:
            return state.param_offset(msg.kind)  # the odometry check reports this line
        reason = pose_problem(msg.laser_pose, limits, "laser pose")
        relative = between(msg.robot_pose, msg.laser_pose) if reason is None else None
        if reason is None:
            reason = offset_problem(relative, limits)
        if reason is not None:
            self._issues.problem(f"{reason} (PARAM offset used)", number)
            return state.param_offset(msg.kind)
        if msg.kind.startswith("ROBOTLASER") or np.max(np.abs(relative)) > _SAME_POSE_TOLERANCE:
            return relative
        return state.param_offset(msg.kind)


def _sweep_time(angles: np.ndarray, sweep_s: float) -> float:
    """The sweep time of a CARMEN scan with bearings ``angles`` (rad, in the order the
    message lists them, which is the order they were measured in): ``sweep_s``, negative
    when the bearings decrease; 0 for a scan finer than one beam per degree, which a SICK
    LMS measures over several turns of its mirror, interlaced, not in the order of its
    bearings (the linear sweep of :func:`bsslam.scan.deskew` does not describe it)."""
    if angles.size < 2:
        return 0.0
    step = float(angles[1] - angles[0])
    if abs(step) < math.radians(1.0) * (1 - 1e-6):
        return 0.0
    return sweep_s if step > 0 else -sweep_s


def _increasing(msg: LaserMessage) -> LaserMessage:
    """``msg`` with its beams in increasing bearing order (a negative angular resolution
    — a laser mounted upside down — lists them backwards)."""
    if msg.angles.size > 1 and msg.angles[-1] < msg.angles[0]:
        return replace(msg, angles=msg.angles[::-1].copy(), ranges=msg.ranges[::-1].copy())
    return msg
