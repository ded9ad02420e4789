"""The spline map as JSON: every B-spline feature with its knots, control points and
covariance block, so that a map can be re-plotted, compared or reloaded without the run.

Layout::

    {"format": "bsslam-spline-map", "version": 1,
     "units": {"knots": "m", "control_points": "m", "covariance": "m^2"},
     "covariance_order": "x_0..x_{n-1}, y_0..y_{n-1}",
     "metadata": {...},                      # free-form, e.g. the run it came from
     "splines": [{"id": 3, "order": 4, "degree": 3, "knots": [...],
                  "control_points": [[x, y], ...], "covariance": [[...], ...] | null,
                  "submap": 0, "surface": 3}]}    # submap, surface: optional

Knots are in metres because the paper parameterises by chord length.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any, Iterable

import numpy as np

from bsslam.errors import InputError, SplineError
from bsslam.io.indented_json import dumps_indented
from bsslam.io.path_or_file import PathOrFile, describe, open_path_or_file

MAP_FORMAT = "bsslam-spline-map"
MAP_VERSION = 1


@dataclass(frozen=True)
class CurveRecord:
    """A B-spline curve as stored: degree p, knots (n + p + 1,) in m, control points (n, 2) in m."""

    degree: int
    knots: np.ndarray
    control_points: np.ndarray


@dataclass(frozen=True)
class SplineRecord:
    """One map feature as stored. ``covariance`` is (2n, 2n) ordered
    [x_0..x_{n-1}, y_0..y_{n-1}] (m²), or None when the run kept none. Has the same
    ``id``/``curve``/``covariance`` attributes that :func:`write_map_json` reads, so a
    loaded map can be written again."""

    id: int
    curve: CurveRecord
    covariance: np.ndarray | None = None


@dataclass(frozen=True)
class SplineMap:
    """A loaded map file: its features and the free-form metadata stored with them."""

    splines: list[SplineRecord]
    metadata: dict[str, Any] = field(default_factory=dict)


def _check_shapes(degree: int, knots: np.ndarray, points: np.ndarray,
                  covariance: np.ndarray | None) -> str | None:
    """The reason a spline's arrays are inconsistent, or None when they fit together."""
    if degree < 1:
        return f"degree must be ≥ 1, got {degree}"
    if points.ndim != 2 or points.shape[1] != 2:
        return f"control points must be (n, 2), got {points.shape}"
    n = points.shape[0]
    if knots.shape != (n + degree + 1,):
        return f"{n} control points of degree {degree} need {n + degree + 1} knots, got {knots.shape}"
    if np.any(np.diff(knots) < 0):
        return "knots must be non-decreasing"
    if covariance is not None and covariance.shape != (2 * n, 2 * n):
        return f"covariance must be ({2 * n}, {2 * n}), got {covariance.shape}"
    return None


def write_map_json(target: PathOrFile, splines: Iterable[Any],
                   metadata: dict[str, Any] | None = None) -> None:
    """Write map splines as JSON.

    Args:
        target: path or open text file.
        splines: objects with ``id: int``, ``curve`` (``.degree``, ``.knots`` (K,),
            ``.control_points`` (n, 2)) and ``covariance`` ((2n, 2n) or None).
        metadata: optional JSON-serialisable dict stored alongside (e.g. run settings).

    Raises:
        SplineError: a spline whose arrays do not fit together, or non-finite numbers.
    """
    records = []
    for spline in splines:
        curve = spline.curve
        degree = int(curve.degree)
        knots = np.asarray(curve.knots, dtype=float)
        points = np.asarray(curve.control_points, dtype=float)
        cov = None if spline.covariance is None else np.asarray(spline.covariance, dtype=float)
        problem = _check_shapes(degree, knots, points, cov)
        if problem is not None:
            raise SplineError(f"map spline {spline.id}: {problem}")
        records.append({
            "id": int(spline.id),
            "order": degree + 1,
            "degree": degree,
            "knots": knots.tolist(),
            "control_points": points.tolist(),
            "covariance": None if cov is None else cov.tolist(),
        })
        # the submap backend's: the submap a spline was mapped in (its covariance is
        # relative to that submap's base) and the surface it shares with other submaps
        for key in ("submap", "surface"):
            if getattr(spline, key, None) is not None:
                records[-1][key] = int(getattr(spline, key))
    document = {
        "format": MAP_FORMAT,
        "version": MAP_VERSION,
        "units": {"knots": "m", "control_points": "m", "covariance": "m^2"},
        "covariance_order": "x_0..x_{n-1}, y_0..y_{n-1}",
        "metadata": metadata or {},
        "splines": records,
    }
    try:
        # allow_nan=False: NaN/inf would make a file other JSON readers refuse
        text = dumps_indented(document, indent=1)
    except (TypeError, ValueError) as exc:
        raise SplineError(f"map cannot be written as JSON: {exc}") from None
    with open_path_or_file(target, "w") as f:
        f.write(text + "\n")


def _record_from_json(item: Any, name: str, index: int) -> SplineRecord:
    where = f"spline #{index}"
    try:
        degree = int(item["degree"])
        knots = np.asarray(item["knots"], dtype=float)
        points = np.asarray(item["control_points"], dtype=float)
        raw_cov = item.get("covariance")
        cov = None if raw_cov is None else np.asarray(raw_cov, dtype=float)
        spline_id = int(item["id"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{where}: missing or invalid field ({exc})", name) from None
    if "order" in item and item["order"] != degree + 1:
        raise InputError(f"{where}: order {item['order']} ≠ degree + 1 = {degree + 1}", name)
    problem = _check_shapes(degree, knots, points, cov)
    if problem is not None:
        raise InputError(f"{where} (id {spline_id}): {problem}", name)
    return SplineRecord(spline_id, CurveRecord(degree, knots, points), cov)


def read_map_json(source: PathOrFile) -> SplineMap:
    """Read a map written by :func:`write_map_json`.

    Raises:
        InputError: unreadable file, invalid JSON, another format or a newer version, or a
            spline whose arrays do not fit together (naming the file).
    """
    name = describe(source)
    with open_path_or_file(source) as f:
        try:
            document = json.load(f)
        except json.JSONDecodeError as exc:
            raise InputError(f"invalid JSON: {exc.msg}", name, exc.lineno) from None
    if not isinstance(document, dict) or document.get("format") != MAP_FORMAT:
        raise InputError(f"not a {MAP_FORMAT} file", name)
    version = document.get("version")
    if not isinstance(version, int) or not 1 <= version <= MAP_VERSION:
        raise InputError(f"unsupported map version {version!r} (this bsslam reads ≤ {MAP_VERSION})", name)
    items = document.get("splines")
    if not isinstance(items, list):
        raise InputError("'splines' must be a list", name)
    splines = [_record_from_json(item, name, i) for i, item in enumerate(items)]
    metadata = document.get("metadata") or {}
    return SplineMap(splines, metadata if isinstance(metadata, dict) else {})
