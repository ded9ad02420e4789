"""Open a log as a :class:`~bsslam.dataset.Dataset`, guessing the reader from the path.

``.clf``/``.log``/``.carmen`` → CARMEN; ``.bag`` → ROS 1; a folder holding
``metadata.yaml`` or one ``.db3``/``.mcap`` file, or such a file itself → ROS 2.
"""

from __future__ import annotations

import os
from pathlib import Path

from bsslam.dataset import Dataset
from bsslam.errors import ConfigError, InputError
from bsslam.io.reader_config import ReaderConfig
from bsslam.trajectory import Trajectory

FORMATS = ("carmen", "ros1", "ros2")
_CARMEN_SUFFIXES = (".clf", ".log", ".carmen")
_ROS2_STORAGE_SUFFIXES = (".db3", ".mcap")


def guess_format(path: str | os.PathLike) -> str:
    """The format of ``path``: "carmen", "ros1" or "ros2".

    Raises:
        InputError: the path does not exist or its kind cannot be told from its name.
    """
    p = Path(path)
    if not p.exists():
        raise InputError("no such file or folder", os.fspath(path))
    if p.is_dir():
        _ros2_target(p)  # raises when the folder is no ROS 2 bag
        return "ros2"
    suffix = p.suffix.lower()
    if suffix in _CARMEN_SUFFIXES:
        return "carmen"
    if suffix == ".bag":
        return "ros1"
    if suffix in _ROS2_STORAGE_SUFFIXES:
        return "ros2"
    raise InputError(f"cannot tell the log format from the name; pass format= one of {FORMATS}",
                     os.fspath(path))


def _ros2_target(path: Path) -> Path:
    """A ROS 2 folder without metadata.yaml is read through its single storage file."""
    if path.is_dir() and not (path / "metadata.yaml").exists():
        storage = [f for f in path.iterdir() if f.suffix in _ROS2_STORAGE_SUFFIXES]
        if len(storage) != 1:
            raise InputError("a ROS 2 bag folder needs metadata.yaml or exactly one .db3/.mcap file",
                             os.fspath(path))
        return storage[0]
    return path


def open_dataset(path: str | os.PathLike, format: str | None = None, *, strict: bool = False,
                 reader_config: ReaderConfig | None = None, scan_topic: str | None = None,
                 odom_topic: str | None = None, ground_truth: Trajectory | None = None) -> Dataset:
    """Open a log for streaming.

    Args:
        path: a CARMEN log, a ROS 1 bag, or a ROS 2 bag (folder or storage file).
        format: "carmen", "ros1" or "ros2" to override the guess from the path.
        strict: bad input raises :class:`InputError` instead of being counted in ``skipped``.
        reader_config: no-return rule, CARMEN laser stream, tf frame names.
        scan_topic, odom_topic: ROS topics; None finds them by type.
        ground_truth: a reference trajectory to attach as ``dataset.ground_truth``.

    Returns:
        a reader implementing the Dataset protocol.

    Raises:
        InputError: missing, unreadable or unrecognised input (naming the path).
        ConfigError: an unknown ``format``, or ROS topics given for a CARMEN log.
    """
    if format is None:
        format = guess_format(path)
    elif format not in FORMATS:
        raise ConfigError(f"format must be one of {FORMATS}, got {format!r}")
    if format == "carmen":
        if scan_topic is not None or odom_topic is not None:
            raise ConfigError("scan_topic/odom_topic apply to ROS bags, not to CARMEN logs")
        from bsslam.io.carmen import CarmenReader
        return CarmenReader(path, strict=strict, config=reader_config, ground_truth=ground_truth)
    # imported here: rosbags costs a noticeable start-up time that CARMEN users need not pay
    from bsslam.io.rosbag import RosbagReader
    target = Path(path)
    if format == "ros2":
        target = _ros2_target(target)
    elif target.suffix != ".bag":
        # rosbags tells ROS 1 from ROS 2 by this suffix
        raise InputError("a ROS 1 bag must be named *.bag", os.fspath(path))
    return RosbagReader(target, strict=strict, config=reader_config, scan_topic=scan_topic,
                        odom_topic=odom_topic, ground_truth=ground_truth)
