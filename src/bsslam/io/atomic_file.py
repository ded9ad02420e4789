"""Write a file so that its final name only ever holds a complete file.

Every result writer goes through :func:`atomic_write`: the bytes go to a hidden temporary
file in the target's own folder, are flushed and fsynced, and only then is the temporary
renamed onto the final name with :func:`os.replace` (atomic on POSIX and Windows within one
file system, which the shared folder guarantees). A crash, a signal, a full disk or an
exception in the writer leaves the previous file (or none) under the final name, never a
cut one; the temporary is removed.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from pathlib import Path
from typing import IO, Iterator

from bsslam.errors import InputError

TEMP_SUFFIX = ".tmp"


def _temp_name(path: Path) -> Path:
    # hidden, same folder (same file system, so os.replace is a rename), unique per writer
    return path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}{TEMP_SUFFIX}")


def _error(exc: OSError, path: Path) -> InputError:
    return InputError(f"cannot write file: {exc.strerror or exc}", os.fspath(path))


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "w", *, newline: str | None = None) -> Iterator[IO]:
    """Open a temporary beside ``path`` for writing; on a clean exit flush, fsync and rename
    it onto ``path``.

    Args:
        path: the final file name; its folder must exist.
        mode: ``"w"`` (UTF-8 text) or ``"wb"``.
        newline: as for :func:`open` in text mode (``""`` for the csv module).

    Raises:
        InputError: the file cannot be created, written, synced or renamed (permissions, a
            full disk, a folder in the way), naming ``path``; nothing is left under
            ``path`` that was not there before, and no temporary stays behind.
        Any exception of the body, after the temporary has been removed.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_write writes whole files: mode 'w' or 'wb', got {mode!r}")
    path = Path(path)
    tmp = _temp_name(path)
    try:
        # O_EXCL: never write through someone else's file or link; 0o666 lets the umask
        # decide the permissions, as for a plain open()
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    except OSError as exc:
        raise _error(exc, path) from None
    try:
        try:
            handle = os.fdopen(fd, mode, encoding=None if "b" in mode else "utf-8",
                               newline=None if "b" in mode else newline)
        except BaseException:
            os.close(fd)
            raise
        with handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        _remove(tmp)
        raise _error(exc, path) from None
    except BaseException:
        _remove(tmp)
        raise


def _remove(tmp: Path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(tmp)
