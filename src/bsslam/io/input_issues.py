"""The readers' one policy for bad input: a counted skip by default, an error when strict,
and the pass over a reader's frames that applies it (:class:`CheckedReader`)."""

from __future__ import annotations

import logging
import os
import stat
from typing import TYPE_CHECKING, Iterable, Iterator

from bsslam.dataset import Frame, SkipCounter
from bsslam.errors import InputError
from bsslam.input_limits import InputLimits, OdometryGate

if TYPE_CHECKING:
    from bsslam.io.reader_config import ReaderConfig


class InputIssues:
    """Collects what one pass of a reader skipped.

    Args:
        path: the input, for ``path:line`` locations.
        strict: :meth:`problem` raises instead of counting.

    Attributes:
        skipped: the counts and the first locations (``path:line: reason``).
    """

    def __init__(self, path: str, strict: bool):
        self.path = path
        self.strict = strict
        self.skipped = SkipCounter()

    def problem(self, reason: str, line: int, detail: str = "") -> None:
        """Bad input at ``line`` (a 1-based line or message index): count it, or raise
        :class:`InputError` when strict. ``reason`` is the category counted."""
        if self.strict:
            raise InputError(f"{reason}: {detail}" if detail else reason, self.path, line)
        self.skipped.add(reason, f"{self.path}:{line}")

    def skip(self, reason: str, line: int | None = None) -> None:
        """An expected skip (an unused message, a scan outside the odometry): always
        counted, never an error; located only when ``line`` is given."""
        self.skipped.add(reason, None if line is None else f"{self.path}:{line}")

    def ignore(self, key: str = "other_messages") -> None:
        """Input not meant for this reader: counted silently, never reported as a skip."""
        self.skipped.ignore(key)

    def stamp_advances(self, stamp: float, previous: float | None, what: str, line: int) -> bool:
        """True when ``stamp`` is later than ``previous``; else a "duplicate"/"backwards
        <what> timestamp" problem and False."""
        if previous is None or stamp > previous:
            return True
        kind = "duplicate" if stamp == previous else "backwards"
        self.problem(f"{kind} {what} timestamp", line, f"{stamp!r} after {previous!r}")
        return False

    def log_summary(self, logger: logging.Logger) -> None:
        """One warning listing the problems (not the ignored messages), if any."""
        problems = self.skipped.counts
        if problems:
            logger.warning("%s: %s; first: %s", self.path,
                           ", ".join(f"{v}× {k}" for k, v in problems.items()),
                           "; ".join(self.skipped.examples[:3]))


def require_regular_file(path: str) -> None:
    """Refuse what is not a regular file before opening it: a FIFO or a device would block
    or stream forever, a folder cannot be read as a log.

    Raises:
        InputError: missing, not a regular file, or not accessible.
    """
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", path) from None
    if stat.S_ISDIR(mode):
        raise InputError("is a folder, not a log file", path)
    if not stat.S_ISREG(mode):
        raise InputError("not a regular file (a FIFO, socket or device); bsslam reads files only", path)


def checked_frames(items: Iterable[tuple[int, Frame]], limits: InputLimits, issues: InputIssues) -> Iterator[Frame]:
    """The reader's frames after the odometry check: each ``(line, frame)`` passes
    :class:`~bsslam.input_limits.OdometryGate`; an implausible or invalid pose is a problem
    at ``line`` and the step is bridged (a bad first pose skips its scan).

    Raises:
        InputError: no frame at all came through (in both modes), naming the file and what
            was skipped; or, when strict, the first bad pose.
    """
    gate = OdometryGate(limits)
    count = 0
    for line, frame in items:
        pose, reason = gate.accept(frame.stamp, frame.odometry)
        if reason is not None:
            if pose is None:
                issues.problem(f"{reason} (scan skipped)", line)
                continue
            issues.problem(f"{reason} (bridged)", line)
        count += 1
        yield Frame(frame.stamp, pose, frame.scan, frame.laser_offset)
    if count == 0:
        counts = issues.skipped.counts
        why = ("; skipped: " + ", ".join(f"{v}× {k}" for k, v in counts.items())) if counts else ""
        raise InputError(f"no laser scans{why}", issues.path)


class CheckedReader:
    """The pass over a reader's frames that the readers share: each pass counts its own
    skips in a fresh :class:`InputIssues`, sends the frames through
    :func:`checked_frames` and ends with one summary warning.

    Subclasses provide ``path`` (str), ``strict`` (bool), ``config.limits``
    (:class:`~bsslam.input_limits.InputLimits`), :meth:`_numbered_frames`, and ``_logger``
    (a class attribute: the logger the summary goes to, the reader module's own).

    Attributes:
        skipped: counts of what the last pass skipped, with the first locations.
    """

    path: str
    strict: bool
    config: ReaderConfig
    _logger: logging.Logger
    _issues: InputIssues

    @property
    def skipped(self) -> SkipCounter:
        """What the last pass skipped (counts and first locations)."""
        return self._issues.skipped

    def __iter__(self) -> Iterator[Frame]:
        self._issues = InputIssues(self.path, self.strict)
        yield from checked_frames(self._numbered_frames(), self.config.limits, self._issues)
        self._issues.log_summary(self._logger)

    def _numbered_frames(self) -> Iterator[tuple[int, Frame]]:
        """(line or message index, frame) of every scan that passed the reader's own
        checks, before the odometry check; problems go to ``self._issues``."""
        raise NotImplementedError
