"""Run a Dataset through the filter: a loop of :class:`bsslam.mapper.Mapper` over its
frames, with progress callbacks and an early end on KeyboardInterrupt.

The loop never branches on "show progress?" or "visualise?": it calls a progress callback
and the mapper calls a viewer, both no-ops by default (the CLI passes a rich progress bar
and, with ``--viewer``, a rerun viewer).
"""

from __future__ import annotations

from typing import Callable

from bsslam.config import SLAMConfig
from bsslam.dataset import Dataset
from bsslam.errors import MemoryBudgetError
from bsslam.mapper import Mapper, Progress, RunResult, Viewer, _no_progress, relocalize
from bsslam.slam import SplineSLAM

__all__ = ["Progress", "RunResult", "relocalize", "run_dataset"]


def run_dataset(dataset: Dataset, config: SLAMConfig, *, steps: int | None = None,
                progress: Progress = _no_progress, total: int | None = None,
                point_stride: int = 4, slam: SplineSLAM | None = None,
                relocalize_progress: Progress = _no_progress, viewer: Viewer | None = None,
                mapper: Mapper | None = None, start: int = 0,
                checkpoint: Callable[[int, Mapper], None] | None = None) -> RunResult:
    """Run the filter over (the first ``steps`` frames of) a dataset, then, when
    ``config.relocalize`` is on, localise every scan again in the final map.

    The map frame is the first frame's odometry pose, so estimate, odometry and a reference
    that starts at the same pose are directly comparable.

    A KeyboardInterrupt while reading or processing the frames (Ctrl-C; the CLI turns
    SIGTERM into one too) ends the run early: the result holds the frames processed so
    far, the second pass is skipped and ``RunResult.interrupted`` is True. A run that
    reaches the memory budget (``max_memory_mb``) ends the same way, the budget's message
    in ``RunResult.stop_reason``.

    Args:
        point_stride: keep every k-th valid beam of every scan for ``RunResult.points``.
        slam: an existing filter to continue (its state is not reset).
        relocalize_progress: progress of the second pass (done, total frames).
        viewer: shown every scan and the result (see :class:`bsslam.mapper.Viewer`).
        mapper: a restored mapper to continue (a resumed run, :mod:`bsslam.io.checkpoint`)
            instead of a new one; ``slam`` is then ignored, ``viewer`` replaces its viewer.
        start: the index of the first frame to process: the frames before it are read and
            skipped (they are in ``mapper`` already). The dataset must be the same one.
        checkpoint: called after every frame with the index of the next frame and the
            mapper (e.g. a :class:`bsslam.io.checkpoint.Checkpointer`, which saves it now
            and then); it must not change the mapper.
    """
    if mapper is None:
        mapper = Mapper(config, viewer=viewer, slam=slam)
    elif viewer is not None:
        mapper.viewer = viewer
    interrupted, reason = False, None
    try:
        for i, frame in enumerate(dataset):
            if steps is not None and i >= steps:
                break
            if i < start:
                continue
            mapper.add_frame(frame)   # a Dataset checked its frames against the input limits
            progress(i + 1, total)
            if checkpoint is not None:
                checkpoint(i + 1, mapper)
    except KeyboardInterrupt:
        interrupted = True
    except MemoryBudgetError as exc:   # the results so far are kept, with the reason
        interrupted, reason = True, str(exc)
    return mapper.finish(name=getattr(dataset, "name", "dataset"), ground_truth=dataset.ground_truth,
                         skipped=dataset.skipped, point_stride=point_stride, progress=relocalize_progress,
                         interrupted=interrupted, stop_reason=reason)
