"""Trajectory text files: TUM (``stamp x y z qx qy qz qw``) and plain ``stamp x y θ``.

Both are read by :func:`read_trajectory` and written by :func:`write_trajectory`
(``bsslam convert`` turns one into the other).

TUM is what evo and most SLAM benchmarks read; a planar pose becomes z = 0 and a rotation
about z, ``q = (0, 0, sin φ/2, cos φ/2)``. The reader also takes the four-column
``stamp x y θ`` files (the ``*.gt.txt`` references), deciding by the column count of the
first data line. Lines starting with ``#`` and blank lines are skipped.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from bsslam.errors import ConfigError
from bsslam.io.numeric_table import parse_numeric_table
from bsslam.io.path_or_file import PathOrFile, describe, open_path_or_file
from bsslam.io.quaternion import quaternion_from_yaw, yaw_from_quaternion
from bsslam.trajectory import Trajectory, wrap_angle

TUM_HEADER = "# stamp x y z qx qy qz qw"
XYTHETA_HEADER = "# stamp x y theta"
#: "tum": ``stamp x y z qx qy qz qw``; "xytheta": ``stamp x y θ`` (s, m, rad)
TRAJECTORY_FORMATS = ("tum", "xytheta")


def _format_row(values: np.ndarray) -> str:
    # repr() of a Python float is the shortest string that reads back to the same double,
    # so files round-trip exactly without 17-digit noise.
    return " ".join(map(repr, values.tolist()))


def write_tum(target: PathOrFile, trajectory: Trajectory) -> None:
    """Write ``trajectory`` as TUM lines ``stamp x y z qx qy qz qw`` (s, m, unit quaternion),
    with z = 0 and the heading as a rotation about z. Covariances are not written (see
    :mod:`bsslam.io.pose_covariance_file`)."""
    poses = trajectory.poses
    table = np.column_stack([trajectory.stamps, poses[:, 0], poses[:, 1], np.zeros(len(trajectory)),
                             quaternion_from_yaw(poses[:, 2])])
    with open_path_or_file(target, "w") as f:
        f.write(TUM_HEADER + "\n")
        for row in table:
            f.write(_format_row(row) + "\n")


def write_xytheta(target: PathOrFile, trajectory: Trajectory) -> None:
    """Write ``trajectory`` as lines ``stamp x y θ`` (s, m, rad in (−π, π]), the format of
    the ``*.gt.txt`` references. Covariances are not written."""
    table = np.column_stack([trajectory.stamps, trajectory.poses])
    with open_path_or_file(target, "w") as f:
        f.write(XYTHETA_HEADER + "\n")
        for row in table:
            f.write(_format_row(row) + "\n")


def format_from_name(path: str | os.PathLike) -> str:
    """The trajectory format a file name asks for: "tum" for ``*.tum``, else "xytheta"
    (``.txt`` is used for both, so only ``.tum`` is taken as a sign)."""
    return "tum" if Path(path).suffix.lower() == ".tum" else "xytheta"


def write_trajectory(target: PathOrFile, trajectory: Trajectory, format: str) -> None:
    """Write ``trajectory`` in one of :data:`TRAJECTORY_FORMATS`.

    Raises:
        ConfigError: an unknown format.
        InputError: the file cannot be written.
    """
    if format not in TRAJECTORY_FORMATS:
        raise ConfigError(f"trajectory format must be one of {TRAJECTORY_FORMATS}, got {format!r}")
    (write_tum if format == "tum" else write_xytheta)(target, trajectory)


def read_trajectory(source: PathOrFile) -> Trajectory:
    """Read a TUM (8 columns) or ``stamp x y θ`` (4 columns) trajectory file.

    Returns:
        Trajectory with stamps (N,) in s and poses (N, 3) (x m, y m, φ rad wrapped to (−π, π]).

    Raises:
        InputError: unreadable file, or a line with the wrong column count or a
            non-numeric value (naming the file and the 1-based line).
    """
    with open_path_or_file(source) as f:
        table = parse_numeric_table(f, describe(source), (8, 4))
    if table.shape[1] == 8:
        heading = yaw_from_quaternion(*table[:, 4:8].T)
    else:
        heading = wrap_angle(table[:, 3])
    return Trajectory(table[:, 0], np.column_stack([table[:, 1], table[:, 2], heading]))
