"""A second process for the parts of a run that need not wait for the filter: the two
halves of a run on two cores.

**The reader and the front end, ahead of the filter** (:meth:`HelperProcess.prefetch`).
The front end (:class:`~bsslam.frontend.LaserOdometry`) never looks at the filter: it
matches each scan against its own keyframes. So the second process reads the log and
matches its scans while the filter works on the frames before, and hands each frame over
with its front-end step. The numbers are the same as in one process (the same code on the
same input, BLAS on one thread in both); only the time changes. The frames go through a
pipe, whose buffer bounds how far the reader runs ahead, so memory stays bounded on any
log. The front end's state stays in the second process;
:meth:`HelperProcess.want_frontend` asks for it after the next frame (a checkpoint needs
it), and it comes with the last frame.

**A call** (:meth:`HelperProcess.call`), e.g. drawing the map picture while this process
writes the other files.

An error in the second process (a bad line under ``--strict``, an unreadable file) is
raised in the first as it was raised there, with the remote traceback as its cause. The
second process ignores SIGINT (a Ctrl-C reaches the whole process group; the first decides
what to do) and ends when the first closes it or goes away.
"""

from __future__ import annotations

import copy
import dataclasses
import multiprocessing as mp
import pickle
import signal
import traceback
from dataclasses import dataclass
from typing import Any, Callable, Iterator

from bsslam.blas_threads import one_blas_thread
from bsslam.dataset import Dataset, Frame, SkipCounter
from bsslam.errors import BsslamError
from bsslam.frontend import FrontendStep, LaserOdometry

__all__ = ["HelperProcess", "Prefetched", "can_prefetch"]


@dataclass(frozen=True)
class Prefetched:
    """One frame as the second process hands it over.

    Attributes:
        index: the frame's index in the dataset (0 = first).
        frame: the frame.
        step: the front end's step on it, without its match; None before ``start`` and
            with no front end.
        skipped: the reader's skip counter after this frame.
        frontend: the pickled front end after this frame, when asked for (or the last).
    """

    index: int
    frame: Frame
    step: FrontendStep | None
    skipped: SkipCounter
    frontend: bytes | None = None

    def frontend_state(self) -> LaserOdometry | None:
        """The front end this frame carries, unpickled (None if it carries none)."""
        return None if self.frontend is None else pickle.loads(self.frontend)


class RemoteTraceback(Exception):
    """The second process's traceback, as the cause of an error raised there."""

    def __str__(self) -> str:
        return "\n" + self.args[0]


def can_prefetch(dataset: Dataset) -> bool:
    """Whether ``dataset`` can be sent to a second process (it pickles): the log readers,
    the simulator and :class:`~bsslam.perturbed_dataset.PerturbedDataset` do (and each
    pass over them gives the same frames, which a prefetch needs too); a generator or an
    open stream does not."""
    try:
        pickle.dumps(dataset)
    except Exception:      # pickling raises TypeError, PicklingError, AttributeError, ...
        return False
    return True


class HelperProcess:
    """A second process for a run's work that need not wait for the filter. Start it
    early (its interpreter and imports take about a second, while this process does its
    own), then give it one :meth:`prefetch` and any number of :meth:`call`, one at a time.
    Use it as a context manager (or call :meth:`close`) so the process ends with the run.

    Args:
        preload: modules to import once the prefetched frames are done (for the calls to
            come, while the filter finishes).
        context: the multiprocessing start method; "spawn" starts a fresh interpreter (no
            state of this process, its threads or locks, is copied). A script that
            starts one must guard its main code with ``if __name__ == "__main__":``.
        ahead_bytes: how far ahead of the filter the reader may run, in bytes of pickled
            frames (about 4 kB a frame of 181 beams): the pipe's size, where the system
            lets it be set (Linux, up to ``/proc/sys/fs/pipe-max-size``); None leaves
            the system's (64 KiB on Linux). A checkpoint waits for the front end's state
            at most that far.
    """

    def __init__(self, preload: tuple[str, ...] = (), context: str = "spawn", ahead_bytes: int | None = 1 << 20) -> None:
        ctx = mp.get_context(context)
        self._receiver, sender = ctx.Pipe(duplex=False)
        if ahead_bytes is not None:
            _widen(sender, ahead_bytes)
        job_receiver, self._jobs = ctx.Pipe(duplex=False)
        self._wanted = ctx.Event()
        self._process = ctx.Process(target=_serve, name="bsslam-helper", daemon=True,
                                    args=(job_receiver, sender, self._wanted, tuple(preload)))
        self._process.start()
        # the second process holds the only other ends: its exit ends the pipes
        sender.close()
        job_receiver.close()
        self.skipped = SkipCounter()
        self._ready = False    # its imports are done: it said so
        self._busy = False     # a job's answers are still coming
        self._broken = False   # stopped in the middle of a job: no more jobs

    def ready(self) -> bool:
        """Whether the process has started and can take a job at once (never waits)."""
        return self.wait_ready(0)

    def wait_ready(self, timeout: float | None = None) -> bool:
        """Wait until the process can take a job (at most ``timeout`` s; None: as long as it
        takes); whether it can. A run that waits for it hands every frame to it."""
        if not self._ready and not self._broken:
            try:
                if self._receiver.poll(timeout):
                    self._ready = self._receiver.recv()[0] == "ready"
            except (EOFError, OSError):    # it died while starting: it never will be
                self._broken = True
        return self._ready

    # -- prefetch -------------------------------------------------------------------------
    def prefetch(self, dataset: Dataset, frontend: LaserOdometry | None, *, start: int = 0,
                 steps: int | None = None) -> Iterator[Prefetched]:
        """Read ``dataset`` and run the front end on its frames in the second process;
        yields :class:`Prefetched` frames in order. Leaving the loop early (a break, an
        exception) stops the process: no more jobs after that.

        Args:
            dataset: a picklable dataset (:func:`can_prefetch`).
            frontend: the front end to continue (a fresh one, or a checkpoint's), or None
                to only read the frames.
            start: frames before it are read (the reader counts its skips) but not
                matched: a resumed run has them already.
            steps: read the first ``steps`` frames only (None: all).
        """
        self._send(("prefetch", dataset, frontend, start, steps))
        self.skipped = dataset.skipped
        try:
            while True:
                kind, payload = self._get()
                if kind == "frame":
                    self.skipped = payload.skipped
                    yield payload
                    continue
                self._busy = False
                if kind == "error":
                    _raise(payload)
                return
        finally:
            if self._busy:     # left early: the process is still reading
                self._stop()

    def want_frontend(self) -> None:
        """Ask for the front end's state with the next frame the process matches."""
        self._wanted.set()

    # -- calls ----------------------------------------------------------------------------
    def call(self, fn: Callable[..., Any], *args, **kwargs) -> Callable[[], Any]:
        """Start ``fn(*args, **kwargs)`` in the second process (``fn`` and the arguments
        should pickle); returns a function that waits for its result (or raises its
        error). When the process cannot take it (stopped, ended) or the call does not
        pickle, ``fn`` runs here, now."""
        if not self._broken and self._process.is_alive():
            try:
                self._send(("call", fn, args, kwargs))
                return self._answer
            except (pickle.PicklingError, AttributeError, TypeError):   # it does not pickle: nothing was sent
                pass
            except OSError:    # the pipe is gone with the process
                self._broken = True
        try:
            value = fn(*args, **kwargs)
        except BaseException as exc:
            def fail(error: BaseException = exc):    # bound now: the name is gone after the except
                raise error
            return fail
        return lambda: value

    def _answer(self) -> Any:
        kind, payload = self._get()
        self._busy = False
        if kind == "error":
            _raise(payload)
        return payload

    # -- plumbing -------------------------------------------------------------------------
    def _send(self, job: tuple) -> None:
        if self._busy or self._broken:
            raise RuntimeError("the helper process is busy with a job, or was stopped in one")
        self._jobs.send(job)
        self._busy = True

    def _get(self):
        try:
            message = self._receiver.recv()
            if message[0] == "ready":    # a job sent before ready() saw it
                self._ready = True
                message = self._receiver.recv()
            return message
        except EOFError:     # the second process ended without a last word (killed, crashed)
            self._busy, self._broken = False, True
            self._process.join()
            raise BsslamError(f"the helper process ended unexpectedly (exit code "
                              f"{self._process.exitcode})") from None

    def _stop(self) -> None:
        self._broken, self._busy = True, False
        if self._process.is_alive():
            self._process.terminate()

    def close(self) -> None:
        """End the second process (at once, if it is still working) and close the pipes."""
        self._stop()
        self._process.join()
        self._receiver.close()
        self._jobs.close()

    def __enter__(self) -> "HelperProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _widen(connection, size: int) -> None:
    """Let the pipe hold ``size`` bytes where the system allows it (Linux; 64 KiB by
    default). A few hundred frames: either side's slow stretches (a keyframe rebuild in
    the front end, a loop closure in the filter) then no longer stall the other."""
    try:
        import fcntl
        fcntl.fcntl(connection.fileno(), getattr(fcntl, "F_SETPIPE_SZ", 1031), size)
    except (ImportError, OSError, ValueError):   # another system, or a smaller limit: the default
        pass


def _raise(payload: bytes):
    error, text = pickle.loads(payload)
    raise error from RemoteTraceback(text)


def _serve(jobs, out, wanted, preload: tuple[str, ...]) -> None:
    """The second process: its imports at once, then the jobs as they come, until the
    first process closes the pipe."""
    import importlib

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for module in ("bsslam.io", "bsslam.frontend"):   # the readers (a prefetch job unpickles one), the matcher
        importlib.import_module(module)

    try:
        out.send(("ready", None))
    except (BrokenPipeError, ConnectionResetError):
        return
    while True:
        try:
            job = jobs.recv()
        except (EOFError, OSError):
            return
        try:
            if job[0] == "prefetch":
                _produce(*job[1:], out, wanted)
                for name in preload:
                    importlib.import_module(name)
            else:
                _, fn, args, kwargs = job
                try:
                    answer = pickle.dumps(("result", fn(*args, **kwargs)))
                except Exception as exc:   # the call's error, or a result that does not pickle
                    answer = pickle.dumps(("error", _pickled_error(exc)))
                out.send_bytes(answer)
        except (BrokenPipeError, ConnectionResetError):   # the first process has gone
            return


def _produce(dataset: Dataset, frontend: LaserOdometry | None, start: int, steps: int | None,
             out, wanted) -> None:
    """The second process: the run's reading loop (as :func:`bsslam.pipeline.run_dataset`
    reads, so the reader counts the same skips) with the front end's step on each frame.

    It sends on the pipe from this thread: a queue's feeder thread would take the GIL from
    the front end a few thousand times a run, which made it half as fast again. A full
    pipe blocks the send, so this process is never more than the pipe's buffer ahead;
    a first process gone breaks the pipe (BrokenPipeError) and ends this one."""
    try:
        with one_blas_thread():   # as in the filter's process
            last = None
            for i, frame in enumerate(dataset):
                if steps is not None and i >= steps:
                    break
                if last is not None:
                    out.send(("frame", last))
                step = frontend.step(frame) if frontend is not None and i >= start else None
                if step is not None:   # the filter needs the increment, not the match's grids
                    step = dataclasses.replace(step, match=None)
                state = None
                if frontend is not None and i >= start and wanted.is_set():
                    wanted.clear()
                    state = pickle.dumps(frontend, protocol=pickle.HIGHEST_PROTOCOL)
                last = Prefetched(i, frame, step, copy.deepcopy(dataset.skipped), state)
            if last is not None:   # the last frame carries the front end as it ends
                if frontend is not None and last.frontend is None and last.index >= start:
                    last = dataclasses.replace(last, frontend=pickle.dumps(frontend, protocol=pickle.HIGHEST_PROTOCOL))
                out.send(("frame", last))
        out.send(("end", None))
    except (BrokenPipeError, ConnectionResetError):   # the first process has gone: nobody to tell
        raise
    except Exception as exc:   # every other error goes to the first process, which raises it
        out.send(("error", _pickled_error(exc)))


def _pickled_error(exc: BaseException) -> bytes:
    text = "".join(traceback.format_exception(exc))
    try:
        return pickle.dumps((exc, text))
    except Exception:    # an exception whose arguments do not pickle: its type and message
        return pickle.dumps((BsslamError(f"{type(exc).__name__}: {exc}"), text))
