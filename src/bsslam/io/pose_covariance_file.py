"""Pose covariances as CSV: one row per pose, the 3×3 matrix over (x m, y m, φ rad) row-major.

Header ``stamp,c_xx,c_xy,c_xphi,c_yx,c_yy,c_yphi,c_phix,c_phiy,c_phiphi``; units m², m·rad,
rad². Written next to the TUM trajectory so that NEES can be computed later.
"""

from __future__ import annotations

import numpy as np

from bsslam.errors import InputError
from bsslam.io.numeric_table import parse_numeric_table
from bsslam.io.path_or_file import PathOrFile, describe, open_path_or_file
from bsslam.trajectory import Trajectory

COVARIANCE_HEADER = "stamp,c_xx,c_xy,c_xphi,c_yx,c_yy,c_yphi,c_phix,c_phiy,c_phiphi"


def write_pose_covariance_csv(target: PathOrFile, trajectory: Trajectory) -> None:
    """Write the (N, 3, 3) covariances of ``trajectory`` with their stamps.

    Raises:
        InputError: the trajectory carries no covariances.
    """
    if trajectory.covariances is None:
        raise InputError("the trajectory has no covariances to write", describe(target))
    table = np.column_stack([trajectory.stamps, trajectory.covariances.reshape(-1, 9)])
    with open_path_or_file(target, "w") as f:
        f.write(COVARIANCE_HEADER + "\n")
        for row in table.tolist():
            # repr(): shortest exact round trip of each double
            f.write(",".join(map(repr, row)) + "\n")


def read_pose_covariance_csv(source: PathOrFile) -> tuple[np.ndarray, np.ndarray]:
    """Read a pose covariance CSV.

    Returns:
        stamps (N,) in s and covariances (N, 3, 3).

    Raises:
        InputError: unreadable file, wrong header, or a bad row (with file and line).
    """
    name = describe(source)
    with open_path_or_file(source) as f:
        header = f.readline().strip()
        if header.replace(" ", "") != COVARIANCE_HEADER:
            raise InputError(f"expected the header {COVARIANCE_HEADER!r}, got {header!r}", name, 1)
        table = parse_numeric_table(f, name, (10,), sep=",", first_line=2)
    return table[:, 0], table[:, 1:].reshape(-1, 3, 3)
