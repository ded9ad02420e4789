"""The viewer a :class:`bsslam.Mapper` calls when it is given none: it does nothing, so
the mapping loop never branches on "visualise?" (the KISS-ICP convention)."""

from __future__ import annotations


class NullViewer:
    """A viewer that shows nothing; see :class:`bsslam.mapper.Viewer` for the calls."""

    def update(self, estimate, points, mapper) -> None:
        return None

    def finish(self, result) -> None:
        return None
