"""Run a Dataset through the filter: a loop of :class:`bsslam.mapper.Mapper` over its
frames, with progress callbacks and an early end on KeyboardInterrupt.

The loop never branches on "show progress?" or "visualise?": it calls a progress callback
and the mapper calls a viewer, both no-ops by default (the CLI passes a rich progress bar
and, with ``--viewer``, a rerun viewer).
"""

from __future__ import annotations

import contextlib
from typing import Callable, Iterator

from bsslam.compiled import kernel_interrupts
from bsslam.config import SLAMConfig
from bsslam.dataset import Dataset
from bsslam.deskewed_dataset import DeskewedDataset
from bsslam.errors import MemoryBudgetError
from bsslam.helper_process import HelperProcess, Prefetched, can_prefetch
from bsslam.mapper import Mapper, Progress, RunResult, Viewer, _no_progress, relocalize
from bsslam.slam import SplineSLAM

__all__ = ["Progress", "RunResult", "relocalize", "run_dataset"]


def run_dataset(dataset: Dataset, config: SLAMConfig, *, steps: int | None = None,
                progress: Progress = _no_progress, total: int | None = None,
                point_stride: int = 4, slam: SplineSLAM | None = None,
                relocalize_progress: Progress = _no_progress, viewer: Viewer | None = None,
                mapper: Mapper | None = None, start: int = 0,
                checkpoint: Callable[[int, Mapper], None] | None = None,
                prefetch: bool | HelperProcess = False) -> RunResult:
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
        prefetch: read the dataset and run the front end in a second process, ahead of
            the filter (:meth:`bsslam.helper_process.HelperProcess.prefetch`; True starts
            a helper process and closes it at the end, or pass one started earlier): the
            same result in less time on two cores. The frames are processed here until
            the helper is ready (its interpreter takes about a second to start), then it
            reads the dataset again from the start and takes over at the next frame. The
            dataset must give the same frames on every pass; one that does not pickle
            (:func:`~bsslam.helper_process.can_prefetch`) is read here, without the helper;
            ``checkpoint`` is then called on the frames that bring the front end's state,
            asked for when its ``due(next_frame)`` (every frame without one) says so.
    """
    dataset = DeskewedDataset(dataset, config.input)    # scans taken over a sweep, as if at one instant
    if mapper is None:
        mapper = Mapper(config, viewer=viewer, slam=slam)
    elif viewer is not None:
        mapper.viewer = viewer
    interrupted, reason = False, None
    if prefetch is not False and not can_prefetch(dataset):   # it cannot reach a second process
        prefetch = False
    helper = (HelperProcess() if prefetch is True else prefetch) or None
    handover = None
    try:
        with kernel_interrupts():
            handover = _run_here(dataset, mapper, start, steps, progress, total, checkpoint,
                                 None if helper is None else helper.ready)
            if handover is not None:
                with contextlib.closing(helper.prefetch(dataset, mapper.frontend, start=handover,
                                                        steps=steps)) as frames:
                    _run_prefetched(frames, helper, mapper, handover, progress, total, checkpoint)
    except KeyboardInterrupt:
        interrupted = True
    except MemoryBudgetError as exc:   # the results so far are kept, with the reason
        interrupted, reason = True, str(exc)
    finally:
        if prefetch is True:
            helper.close()
    return mapper.finish(name=getattr(dataset, "name", "dataset"), ground_truth=dataset.ground_truth,
                         skipped=dataset.skipped if handover is None else helper.skipped, point_stride=point_stride,
                         progress=relocalize_progress, interrupted=interrupted, stop_reason=reason)


def _run_here(dataset: Dataset, mapper: Mapper, start: int, steps: int | None, progress: Progress,
              total: int | None, checkpoint: Callable[[int, Mapper], None] | None,
              hand_over: Callable[[], bool] | None) -> int | None:
    """The loop of :func:`run_dataset` in this process. With ``hand_over``, it stops at
    the first frame (from ``start`` on) at which ``hand_over()`` is true and returns that
    frame's index, for the helper process to go on from; None when it ran to the end."""
    frames = iter(dataset)
    try:
        for i, frame in enumerate(frames):
            if steps is not None and i >= steps:
                break
            if i < start:
                continue
            if hand_over is not None and hand_over():
                return i
            mapper.add_frame(frame)   # a Dataset checked its frames against the input limits
            progress(i + 1, total)
            if checkpoint is not None:
                checkpoint(i + 1, mapper)
    finally:
        close = getattr(frames, "close", None)
        if close is not None:   # a generator left early: end its pass now
            close()
    return None


def _run_prefetched(frames: Iterator[Prefetched], helper: HelperProcess, mapper: Mapper, start: int,
                    progress: Progress, total: int | None, checkpoint: Callable[[int, Mapper], None] | None) -> None:
    """The loop of :func:`run_dataset` over frames the second process read and matched.
    The mapper's front end is behind until a frame brings its state; only then may a
    checkpoint save the mapper."""
    due = getattr(checkpoint, "due", lambda next_frame: True)
    asked = False
    for item in frames:
        if item.index < start:
            continue
        if item.frontend is not None:
            mapper.frontend = item.frontend_state()
        mapper.add_frame(item.frame, frontend_step=item.step)
        progress(item.index + 1, total)
        if checkpoint is None or mapper.frontend is None:
            if checkpoint is not None:
                checkpoint(item.index + 1, mapper)
        elif item.frontend is not None:
            checkpoint(item.index + 1, mapper)
            asked = False
        elif not asked and due(item.index + 1):
            helper.want_frontend()
            asked = True
