"""Let every reader and writer accept either a path or an already open file."""

from __future__ import annotations

import contextlib
import os
from typing import IO, Iterator, Union

from bsslam.errors import InputError
from bsslam.io.atomic_file import atomic_write

PathOrFile = Union[str, os.PathLike, IO]


def describe(target: PathOrFile) -> str:
    """A name for ``target`` in error messages: the path, the open file's name, or
    ``<stream>``."""
    if isinstance(target, (str, os.PathLike)):
        return os.fspath(target)
    name = getattr(target, "name", None)
    return name if isinstance(name, str) else "<stream>"


@contextlib.contextmanager
def open_path_or_file(target: PathOrFile, mode: str = "r") -> Iterator[IO]:
    """Open ``target`` if it is a path (closing it afterwards), or yield it unchanged if
    it is already an open file (the caller who opened it closes it).

    Text modes use UTF-8. A path opened for writing (``"w"``, ``"wb"``) is written
    atomically (:func:`bsslam.io.atomic_file.atomic_write`): its name holds the old file or
    the complete new one, never a cut one. Failing to read or write a path raises
    :class:`InputError` naming the path, so callers never see a bare ``OSError``.
    """
    if not isinstance(target, (str, os.PathLike)):
        yield target
        return
    path = os.fspath(target)
    if mode in ("w", "wb"):
        with atomic_write(path, mode) as handle:
            yield handle
        return
    encoding = None if "b" in mode else "utf-8"
    try:
        handle = open(path, mode, encoding=encoding)
    except OSError as exc:
        verb = "read" if "r" in mode else "write"
        raise InputError(f"cannot {verb} file: {exc.strerror or exc}", path) from None
    with handle:
        yield handle
