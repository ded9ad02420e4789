"""The relations metric of Kümmerle et al. 2009, "On measuring the accuracy of SLAM
algorithms": compare each estimated relative motion with a hand-verified one."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass

import numpy as np

from bsslam.errors import InputError
from bsslam.eval.association import nearest_stamps
from bsslam.se2 import between
from bsslam.io.relations_file import read_relations
from bsslam.trajectory import Trajectory

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RelationsError:
    """Statistics of the relation errors (std with ddof = 0; NaN when ``used`` is 0).

    Attributes:
        trans_mean_m, trans_std_m: translation error |δ_xy| (m).
        rot_mean_deg, rot_std_deg: rotation error |δ_φ| (deg).
        used: relations whose two stamps both matched an estimated pose.
        total: relations given.
    """

    trans_mean_m: float
    trans_std_m: float
    rot_mean_deg: float
    rot_std_deg: float
    used: int
    total: int


def relations_error(est: Trajectory, relations: str | os.PathLike | np.ndarray, offset: float = 0.0,
                    max_dt: float = 0.001) -> RelationsError:
    """Error of an estimate against relations: for each relation (t1, t2, r), with p1, p2
    the estimated poses at t1 and t2, δ = (p1⁻¹ p2) ⊖ r = r⁻¹ ∘ (p1⁻¹ p2).

    Args:
        est: the estimated trajectory.
        relations: a relations file, or an (M, 5) ``t1 t2 dx dy dyaw`` array, or an
            (M, 8) ``t1 t2 dx dy dz droll dpitch dyaw`` array (s, m, rad).
        offset: added to the estimate's stamps to reach the relations' clock (s); for the
            Intel logs shipped here 976052857.337.
        max_dt: largest accepted time difference when matching a relation stamp (s).

    Raises:
        InputError: an unreadable file or an array of the wrong shape.
    """
    if isinstance(relations, (str, os.PathLike)):
        table = read_relations(relations)
    else:
        table = np.asarray(relations, dtype=float)
        if table.ndim != 2 or table.shape[1] not in (5, 8):
            raise InputError(f"relations must be (M, 5) or (M, 8), got {table.shape}")
        if table.shape[1] == 8:
            table = table[:, [0, 1, 2, 3, 7]]
    queries = est.stamps + offset
    i1 = nearest_stamps(queries, table[:, 0], max_dt)
    i2 = nearest_stamps(queries, table[:, 1], max_dt)
    ok = (i1 >= 0) & (i2 >= 0)
    used = int(ok.sum())
    if used == 0:
        logger.warning("no relation matched the estimate (offset %s s, max_dt %s s)", offset, max_dt)
        nan = float("nan")
        return RelationsError(nan, nan, nan, nan, 0, len(table))
    estimated = between(est.poses[i1[ok]], est.poses[i2[ok]])
    delta = between(table[ok, 2:5], estimated)
    trans = np.hypot(delta[:, 0], delta[:, 1])
    rot = np.degrees(np.abs(delta[:, 2]))
    return RelationsError(float(trans.mean()), float(trans.std()), float(rot.mean()), float(rot.std()),
                          used, len(table))
