"""Which logs a command line names: files, folders of logs and glob patterns."""

from __future__ import annotations

import glob
import os
from pathlib import Path
from typing import Iterable

from bsslam.errors import InputError
from bsslam.io.open_dataset import guess_format

#: What a folder search takes for a log. ``.log`` is left out on purpose: too many other
#: files end in it (and ``intel-corrected.log`` beside the shared Intel logs is a
#: GMapping output, not a run to repeat); name such logs explicitly or by a pattern.
FOLDER_LOG_SUFFIXES = (".clf", ".carmen", ".bag")


def is_ros2_bag(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a ROS 2 bag folder (as :func:`~bsslam.io.open_dataset` reads one)."""
    path = Path(path)
    if not path.is_dir():
        return False
    try:
        return guess_format(path) == "ros2"
    except InputError:  # a folder that is no bag
        return False


def logs_in_folder(folder: str | os.PathLike) -> list[Path]:
    """The logs below ``folder``, sorted: files ending in :data:`FOLDER_LOG_SUFFIXES` and
    ROS 2 bag folders (whose own files are not searched further)."""
    folder = Path(folder)
    bags = sorted(p for p in folder.rglob("*") if p.is_dir() and is_ros2_bag(p))
    files = [p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() in FOLDER_LOG_SUFFIXES
             and not any(bag in p.parents for bag in bags)]
    return sorted(files + bags)


def find_logs(names: Iterable[str | os.PathLike]) -> list[Path]:
    """The logs named by ``names``, in their order, each once.

    Each name is a file (taken as it is), a ROS 2 bag folder (taken as it is), another
    folder (:func:`logs_in_folder`), or a glob pattern such as ``data/*/*.clf`` or
    ``data/**/*.log`` (each match taken as above).

    Raises:
        InputError: a name that matches nothing, or a folder without logs (naming it).
    """
    found: list[Path] = []
    for name in names:
        path = Path(name)
        if path.exists():
            matches = [path]
        else:
            matches = [Path(m) for m in sorted(glob.glob(os.fspath(name), recursive=True))]
            if not matches:
                raise InputError("no such file or folder, and no file matches it as a pattern", os.fspath(name))
        for match in matches:
            if match.is_dir() and not is_ros2_bag(match):
                inside = logs_in_folder(match)
                if not inside:
                    raise InputError(f"no logs ({', '.join('*' + s for s in FOLDER_LOG_SUFFIXES)} "
                                     "or ROS 2 bags) in this folder", os.fspath(match))
                found.extend(inside)
            else:
                found.append(match)
    return list(dict.fromkeys(found))
