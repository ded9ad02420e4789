"""The readers' one policy for bad input: a counted skip by default, an error when strict."""

from __future__ import annotations

import logging

from bsslam.dataset import SkipCounter
from bsslam.errors import InputError


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

    def stamp_advances(self, stamp: float, previous: float | None, what: str, line: int) -> bool:
        """True when ``stamp`` is later than ``previous``; else a "duplicate"/"backwards
        <what> timestamp" problem and False."""
        if previous is None or stamp > previous:
            return True
        kind = "duplicate" if stamp == previous else "backwards"
        self.problem(f"{kind} {what} timestamp", line, f"{stamp!r} after {previous!r}")
        return False

    def log_summary(self, logger: logging.Logger) -> None:
        """One warning listing the problems (not the unused message types), if any."""
        problems = {k: v for k, v in self.skipped.counts.items() if not k.startswith("unused")}
        if problems:
            logger.warning("%s: %s; first: %s", self.path,
                           ", ".join(f"{v}× {k}" for k, v in problems.items()),
                           "; ".join(self.skipped.examples[:3]))
