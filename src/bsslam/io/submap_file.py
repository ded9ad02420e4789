"""A frozen submap as one ``.npz`` file: its splines with their covariance blocks (its own
frame), the points matching uses, and the robot's final pose in it.

Everything is stored as float64/int64 arrays, so a submap read back is the one written,
bit for bit (``tests/io/test_submap_file.py``). Layout (n splines)::

    index, filter_steps, end_pose (3,), end_covariance (3, 3)
    spline_id, spline_degree, spline_submap, spline_surface (n,)   # surface −1: none
    knot_start, point_start, cov_start (n + 1,)    # offsets into the three flat arrays
    knots, control_points (·, 2), covariances (flat, row-major (2m, 2m) blocks)
    shape_<field>                                   # the SubmapShape's fields
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from bsslam.errors import InputError
from bsslam.io.atomic_file import atomic_write
from bsslam.slam import MapSpline
from bsslam.spline import BSplineCurve
from bsslam.submaps.backend import FrozenSubmap
from bsslam.submaps.loop_closure import SubmapShape


def write_submap(path: str | os.PathLike, submap: FrozenSubmap) -> None:
    """Write ``submap`` to ``path`` (.npz) atomically."""
    splines = submap.splines
    knots = [s.curve.knots for s in splines]
    points = [s.curve.control_points for s in splines]
    covs = [s.covariance.reshape(-1) for s in splines]
    arrays = {
        "index": np.int64(submap.index), "filter_steps": np.int64(submap.filter_steps),
        "end_pose": submap.end_pose, "end_covariance": submap.end_covariance,
        "spline_id": np.array([s.id for s in splines], dtype=np.int64),
        "spline_degree": np.array([s.curve.degree for s in splines], dtype=np.int64),
        "spline_submap": np.array([s.submap for s in splines], dtype=np.int64),
        "spline_surface": np.array([-1 if s.surface is None else s.surface for s in splines], dtype=np.int64),
        "knot_start": _offsets(knots), "point_start": _offsets(points), "cov_start": _offsets(covs),
        "knots": np.concatenate(knots) if splines else np.empty(0),
        "control_points": np.concatenate(points) if splines else np.empty((0, 2)),
        "covariances": np.concatenate(covs) if splines else np.empty(0),
    }
    for f in dataclasses.fields(SubmapShape):
        arrays[f"shape_{f.name}"] = np.asarray(getattr(submap.shape, f.name))
    with atomic_write(Path(path), "wb") as out:
        np.savez(out, **arrays)


def read_submap(path: str | os.PathLike) -> FrozenSubmap:
    """The submap in ``path``, as :func:`write_submap` wrote it.

    Raises:
        InputError: the file is unreadable or not a submap file (naming it).
    """
    try:
        with np.load(Path(path), allow_pickle=False) as z:
            a = {k: z[k] for k in z.files}
        splines = []
        ks, ps, cs = a["knot_start"], a["point_start"], a["cov_start"]
        for i in range(a["spline_id"].shape[0]):
            points = a["control_points"][ps[i]:ps[i + 1]]
            m = 2 * points.shape[0]
            curve = BSplineCurve(points, a["knots"][ks[i]:ks[i + 1]], int(a["spline_degree"][i]))
            surface = int(a["spline_surface"][i])
            splines.append(MapSpline(int(a["spline_id"][i]), curve, a["covariances"][cs[i]:cs[i + 1]].reshape(m, m),
                                     submap=int(a["spline_submap"][i]), surface=None if surface < 0 else surface))
        # files written before the shape carried its walls' σ read as σ = 0 (not known)
        a.setdefault("shape_sigma", np.zeros(a["shape_points"].shape[0]))
        shape = SubmapShape(**{f.name: _scalar(a[f"shape_{f.name}"]) for f in dataclasses.fields(SubmapShape)})
        return FrozenSubmap(int(a["index"]), splines, shape, a["end_pose"], a["end_covariance"], int(a["filter_steps"]))
    except (OSError, KeyError, ValueError, IndexError) as exc:
        raise InputError(f"not a readable submap file ({exc})", str(path)) from None


def _offsets(parts: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([[0], np.cumsum([p.shape[0] for p in parts], dtype=np.int64)]).astype(np.int64)


def _scalar(value: np.ndarray):
    """0-d arrays back to Python numbers (the shape's floats), arrays as they are."""
    return value.item() if value.ndim == 0 else value
