"""Result folders: every verb that writes results writes to ``DIR/<timestamp>/``; ``DIR/latest``
points at the newest run that *completed*.

The lifecycle of a run folder (:func:`run_folder`):

1. :func:`create_run_dir` checks ``DIR`` and ``DIR/latest`` and makes ``DIR/<timestamp>/``
   before any work, so a bad ``--out`` fails at once;
2. the verb writes its files (each atomically, :mod:`bsslam.io.atomic_file`) and, last,
   ``summary.json`` with ``"status": "complete"`` (:func:`write_summary`);
3. :func:`publish_run` then repoints ``DIR/latest`` — only at a folder whose
   ``summary.json`` says complete.

A run that fails or is interrupted gets a ``summary.json`` with ``"status": "failed"`` or
``"interrupted"`` and the ``"reason"``, and ``latest`` stays on the last good run.

A run resumed from its checkpoint (``bsslam run --resume``) goes on in its own folder
(:func:`resumed_run_folder`): same lifecycle from step 2, ``latest`` repointed at it once
it completes.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
import signal
import threading
from pathlib import Path
from typing import Any, Iterator

from bsslam.errors import InputError
from bsslam.io.atomic_file import atomic_write

SUMMARY_FILE = "summary.json"
LATEST = "latest"
STATUSES = ("complete", "interrupted", "failed")


def _out_error(exc: OSError, path: Path, what: str) -> InputError:
    return InputError(f"cannot {what}: {exc.strerror or exc}", os.fspath(path))


def create_run_dir(out: str | os.PathLike) -> Path:
    """Create ``out/<UTC timestamp>/`` (unique even within one second) and return it.
    ``out/latest`` is not touched (see :func:`publish_run`).

    Raises:
        InputError: ``out`` is a file or lies under one, cannot be created or written, or
            ``out/latest`` exists and is not a symbolic link (a real folder or file that
            publishing would have to destroy); the message names the path.
    """
    base = Path(out)
    if base.exists() and not base.is_dir():
        raise InputError("the results folder is a file, not a folder", os.fspath(base))
    try:
        base.mkdir(parents=True, exist_ok=True)
    except OSError as exc:   # a file on the way (ENOTDIR), permissions, a read-only disk
        raise _out_error(exc, base, "create the results folder") from None
    latest = base / LATEST
    if latest.exists() and not latest.is_symlink():
        raise InputError(f"'{LATEST}' there is a real {'folder' if latest.is_dir() else 'file'}, not a link "
                         "to the newest run; move it away", os.fspath(latest))
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%d-%H%M%S")
    run = base / stamp
    suffix = 1
    while True:
        try:
            run.mkdir()
            return run
        except FileExistsError:
            suffix += 1
            run = base / f"{stamp}-{suffix}"
        except OSError as exc:
            raise _out_error(exc, run, "create the run folder") from None


def write_summary(run_dir: str | os.PathLike, summary: dict[str, Any], status: str,
                  reason: str | None = None) -> dict[str, Any]:
    """Write ``run_dir/summary.json`` atomically: ``status`` (and ``reason``) first, then
    ``summary``. Returns what was written.

    Raises:
        ValueError: ``status`` is not one of :data:`STATUSES`.
        InputError: the file cannot be written.
    """
    if status not in STATUSES:
        raise ValueError(f"status must be one of {STATUSES}, got {status!r}")
    head: dict[str, Any] = {"status": status}
    if reason is not None:
        head["reason"] = reason
    document = {**head, **{k: v for k, v in summary.items() if k not in ("status", "reason")}}
    with atomic_write(Path(run_dir) / SUMMARY_FILE) as f:
        f.write(json.dumps(document, indent=2) + "\n")
    return document


def read_status(run_dir: str | os.PathLike) -> str | None:
    """The ``status`` in ``run_dir/summary.json``, or None without a readable one."""
    try:
        document = json.loads((Path(run_dir) / SUMMARY_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return document.get("status") if isinstance(document, dict) else None


def publish_run(run_dir: str | os.PathLike) -> bool:
    """Point ``run_dir/../latest`` at ``run_dir`` if its ``summary.json`` says complete;
    returns whether it did. The link is swapped atomically (readers never see it missing).

    Raises:
        InputError: the link cannot be made (e.g. ``latest`` became a real folder).
    """
    run = Path(run_dir)
    if read_status(run) != "complete":
        return False
    latest = run.parent / LATEST
    tmp = run.parent / f".{LATEST}-{os.getpid()}"
    try:
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        tmp.symlink_to(run.name, target_is_directory=True)
        os.replace(tmp, latest)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise _out_error(exc, latest, "point the link at the new run") from None
    return True


def mark_unfinished(run_dir: str | os.PathLike, status: str, reason: str) -> None:
    """Record a failed or interrupted run in its ``summary.json``, unless the run already
    wrote a summary with a status (a complete or partial result says more). Never raises
    for I/O: the original error is the one to report."""
    if read_status(run_dir) is not None:
        return
    with contextlib.suppress(OSError, InputError):
        write_summary(run_dir, {}, status, reason)


def interrupt_reason(exc: KeyboardInterrupt) -> str:
    """"interrupted by SIGTERM" when the signal handler named the signal, else by SIGINT."""
    return f"interrupted by {exc.args[0]}" if exc.args else "interrupted by SIGINT"


@contextlib.contextmanager
def run_folder(out: str | os.PathLike) -> Iterator[Path]:
    """The lifecycle of one run folder: create it, yield it, then publish it when the body
    wrote a complete summary; on a KeyboardInterrupt mark it interrupted, on any other
    exception failed (with the exception's message as reason), and re-raise.

    SIGINT and SIGTERM are held from before the folder is made until the marking is in
    place: a signal's KeyboardInterrupt between the two left a folder that said nothing
    (the CLI's signal test caught one in a few dozen runs); it is raised again, to the
    handlers that were there, once the folder would be marked."""
    held = _hold_signals()
    try:
        run = create_run_dir(out)
    except BaseException:
        _release_signals(held)
        raise
    with _published(run, lambda: _release_signals(held)) as run:
        yield run


_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _hold_signals() -> tuple[dict, list] | None:
    """Replace the SIGINT and SIGTERM handlers by one that only notes the signal: (the
    previous handlers, the signals noted), or None off the main thread, where handlers
    cannot be set. (Blocking them with ``pthread_sigmask`` is not enough: the kernel hands
    a process signal to another thread — a BLAS worker — and Python runs the handler in the
    main thread all the same.)"""
    if threading.current_thread() is not threading.main_thread():
        return None
    noted: list[int] = []
    previous = {sig: signal.signal(sig, lambda signum, frame: noted.append(signum)) for sig in _STOP_SIGNALS}
    return previous, noted


def _release_signals(held: tuple[dict, list] | None) -> None:
    """Undo :func:`_hold_signals`; a signal noted meanwhile is raised again, now to the
    previous handler."""
    if held is None:
        return
    previous, noted = held
    for sig, handler in previous.items():
        signal.signal(sig, handler)
    if noted:
        signal.raise_signal(noted[0])


@contextlib.contextmanager
def _published(run: Path, ready=None) -> Iterator[Path]:
    """Yield ``run``; publish it after the body, or mark it interrupted (KeyboardInterrupt)
    or failed (any other exception, its message the reason) and re-raise. ``ready()``, if
    given, is called first, inside that guard (the caller's held signals let in)."""
    try:
        if ready is not None:
            ready()
        yield run
    except KeyboardInterrupt as exc:
        mark_unfinished(run, "interrupted", interrupt_reason(exc))
        raise
    except BaseException as exc:
        mark_unfinished(run, "failed", str(exc) or type(exc).__name__)
        raise
    publish_run(run)


@contextlib.contextmanager
def resumed_run_folder(run_dir: str | os.PathLike) -> Iterator[Path]:
    """:func:`run_folder` for a run that goes on in its existing folder (a resume from its
    checkpoint): the old ``summary.json`` (an interrupted or failed status, or none after a
    SIGKILL) is removed first, so the folder says what *this* attempt did; the files are
    overwritten as the run writes them, and ``latest`` moves only once it completes.

    Raises:
        InputError: ``run_dir`` is no folder, or its summary cannot be removed.
    """
    run = Path(run_dir)
    if not run.is_dir():
        raise InputError("no such run folder", os.fspath(run))
    try:
        (run / SUMMARY_FILE).unlink(missing_ok=True)
    except OSError as exc:
        raise _out_error(exc, run / SUMMARY_FILE, "remove the old summary") from None
    with _published(run) as published:
        yield published
