"""The one exception hierarchy of bsslam.

Library code raises these (never prints or exits); the CLI turns them into messages.
"""

from __future__ import annotations


class BsslamError(Exception):
    """Base class of every error bsslam raises on purpose."""


class SplineError(BsslamError, ValueError):
    """Invalid B-spline data: knots, orders, control points or parameters."""


class FitError(SplineError):
    """A least-squares fit is impossible (too few points, Schoenberg–Whitney fails)."""


class ConfigError(BsslamError, ValueError):
    """An invalid configuration value or file."""


class InputError(BsslamError):
    """Bad input data, located by file and line where known.

    Attributes:
        path: the file, or None for in-memory data.
        line: 1-based line number (or message index for binary formats), or None.
    """

    def __init__(self, message: str, path: str | None = None, line: int | None = None):
        self.path = path
        self.line = line
        where = ""
        if path is not None:
            where = f"{path}:{line}: " if line is not None else f"{path}: "
        super().__init__(where + message)


class FilterError(BsslamError, RuntimeError):
    """The filter reached an invalid numerical state (e.g. a covariance not positive definite)."""


class MissingDependencyError(BsslamError, ImportError):
    """An optional dependency is not installed; the message names the extra to install."""


class MemoryBudgetError(BsslamError, MemoryError):
    """The estimator's live arrays would exceed the memory budget (``max_memory_mb``).

    Attributes:
        nbytes: the bytes they need(ed).
    """

    def __init__(self, message: str, nbytes: int = 0):
        self.nbytes = int(nbytes)
        super().__init__(message)
