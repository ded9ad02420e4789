"""The spline map as metric vector files for other tools: SVG with exact Bézier paths and
GeoJSON line strings, both in the run's map frame in metres.

``map_metric.svg``: user units are metres; a group flips y (``scale(1,-1)``) so the
coordinates in the paths are the map's own (y up). Each spline is one ``<path>`` with
``id="spline-<id>"`` (an XML id cannot start with a digit; ``data-spline-id`` holds the
bare number) made of its polynomial pieces, one per non-empty knot span, each converted
exactly (up to rounding) to Bézier form: degree 1 → ``L``, 2 → ``Q``, 3 → ``C``. SVG has
no quartic primitive, and a quartic piece is not a cubic, so no choice of cubic Béziers
(elevated or split) reproduces it exactly: degree-4 splines are written as dense polylines
whose vertices lie on the curve (``degree4_step_m`` apart in parameter, i.e. about in arc
length, since knots are chord lengths).

``map.geojson``: a FeatureCollection with one ``LineString`` per spline, sampled densely
(every knot included; a ``MultiLineString`` for a spline that jumps at a knot), properties ``id``, ``degree``, ``knots`` and ``control_points``.
Coordinates are metres in the map frame, not the WGS 84 longitudes and latitudes of
RFC 7946: the foreign member ``"frame"`` says so, and GIS tools must be told to read them
as a local projected (engineering) system.
"""

from __future__ import annotations

import math
from typing import Iterable, Protocol
from xml.sax.saxutils import quoteattr

import numpy as np

from bsslam.io.indented_json import dumps_compact
from bsslam.io.path_or_file import PathOrFile, open_path_or_file
from bsslam.spline import BSplineCurve

_SVG_COMMAND = {1: "L", 2: "Q", 3: "C"}
# Consecutive Bézier pieces of a continuous spline meet to rounding (~1e-13 m); farther
# apart, the spline jumps there.
_JOIN_TOLERANCE_M = 1e-9


class MapFeature(Protocol):
    """What the writers need of a map spline (e.g. ``bsslam.slam.MapSpline`` or a loaded
    ``bsslam.io.map_file.SplineRecord``): an ``id`` and a ``curve`` with ``degree``,
    ``knots`` (m) and ``control_points`` (n, 2) (m)."""

    id: int
    curve: object


def _curve(feature: MapFeature) -> BSplineCurve:
    c = feature.curve
    return c if isinstance(c, BSplineCurve) else BSplineCurve(c.control_points, c.knots, c.degree)


def bezier_pieces(curve: BSplineCurve) -> np.ndarray:
    """The Bézier control points of each polynomial piece of a B-spline curve.

    Each piece ``Σ_k c_k (t − b_s)ᵏ`` (Taylor coefficients of
    :attr:`BSplineCurve.pieces`) becomes, with τ = (t − b_s)/w on [0, 1], the power form
    ``Σ_k a_k τᵏ``, a_k = c_k wᵏ, whose Bézier points are ``P_i = Σ_{k≤i} C(i,k)/C(p,k) a_k``.

    Returns:
        (S, p+1, 2) control points (m): piece s runs from ``[s, 0]`` to ``[s, p]`` as τ goes
        from 0 to 1, i.e. t from ``curve.pieces.breaks[s]`` to ``breaks[s+1]``.
    """
    pieces = curve.pieces
    p = pieces.degree
    powers = pieces.widths[:, None] ** np.arange(p + 1)[None, :]
    power_form = pieces.coeffs * powers[:, :, None]
    to_bezier = np.array([[math.comb(i, k) / math.comb(p, k) if k <= i else 0.0 for k in range(p + 1)]
                          for i in range(p + 1)])
    return np.einsum("ik,skd->sid", to_bezier, power_form)


def _num(v: float) -> str:
    """Shortest text that reads back to the same double."""
    return repr(float(v))


def _pair(point: np.ndarray) -> str:
    return f"{_num(point[0])} {_num(point[1])}"


def svg_path_data(curve: BSplineCurve, degree4_step_m: float = 0.01) -> str:
    """The ``d`` attribute of one spline (m): exact Bézier segments for degrees 1–3, a
    polyline through curve points about ``degree4_step_m`` apart for degree 4."""
    if curve.degree in _SVG_COMMAND:
        command = _SVG_COMMAND[curve.degree]
        segments = bezier_pieces(curve)
        parts = []
        for s, seg in enumerate(segments):
            # a piece starts where the last ended (up to rounding) unless a knot of
            # multiplicity p + 1 makes the spline jump there: then the pen moves
            if s == 0 or np.max(np.abs(seg[0] - segments[s - 1, -1])) > _JOIN_TOLERANCE_M:
                parts.append(f"M {_pair(seg[0])}")
            parts.append(f"{command} " + " ".join(_pair(q) for q in seg[1:]))
        return " ".join(parts)
    return " ".join(f"M {_pair(run[0])} " + " ".join(f"L {_pair(q)}" for q in run[1:])
                    for run in sampled_runs(curve, degree4_step_m))


def sampled_runs(curve: BSplineCurve, step_m: float) -> list[np.ndarray]:
    """Points on the curve about ``step_m`` apart in parameter (≈ arc length, knots being
    chord lengths), every knot among them, as (k, 2) polylines (m): one, unless the curve
    jumps at a knot of multiplicity p + 1, where a new one starts.

    Each piece is evaluated up to its own end (its polynomial), so both sides of a jump are
    exact.
    """
    pieces = curve.pieces
    counts = np.maximum(np.ceil(pieces.widths / step_m), 1).astype(np.intp)
    piece = np.repeat(np.arange(len(counts)), counts + 1)
    first = np.cumsum(counts + 1) - (counts + 1)
    fraction = (np.arange(len(piece)) - first[piece]) / counts[piece]
    points = pieces.evaluate_local(piece, fraction * pieces.widths[piece])[0]
    runs = np.split(points, first[1:])
    out = [runs[0]]
    for run in runs[1:]:
        if np.max(np.abs(run[0] - out[-1][-1])) > _JOIN_TOLERANCE_M:
            out.append(run)
        else:
            out[-1] = np.vstack([out[-1], run[1:]])
    return out


def write_map_svg(target: PathOrFile, splines: Iterable[MapFeature], *, degree4_step_m: float = 0.01,
                  margin_m: float = 1.0) -> None:
    """Write the map as an SVG whose user unit is the metre (see the module docstring).

    The drawing is framed by the control polygons (which contain the curves) plus
    ``margin_m``, printed at 1:100 (1 m = 10 mm); strokes are about 1/500 of the map's size.
    """
    features = [(f.id, _curve(f)) for f in splines]
    if features:
        pts = np.vstack([c.control_points for _, c in features])
        low, high = pts.min(axis=0) - margin_m, pts.max(axis=0) + margin_m
    else:
        low, high = np.full(2, -margin_m), np.full(2, margin_m)
    size = high - low
    stroke = float(np.clip(0.002 * size.max(), 0.01, 0.5))
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" version="1.1" width="{_num(10 * size[0])}mm" '
        f'height="{_num(10 * size[1])}mm" viewBox="{_num(low[0])} {_num(-high[1])} {_num(size[0])} {_num(size[1])}">',
        "  <desc>bsslam spline map: user units are metres in the map frame, y up through the "
        "group transform; 1:100. Degrees 1-3 are exact Bézier segments, degree 4 dense polylines.</desc>",
        f'  <g id="map" transform="scale(1,-1)" fill="none" stroke="black" stroke-width="{_num(stroke)}" '
        'stroke-linecap="round" stroke-linejoin="round">',
    ]
    for spline_id, curve in features:
        lines.append(f'    <path id={quoteattr(f"spline-{spline_id}")} data-spline-id="{int(spline_id)}" '
                     f'data-degree="{curve.degree}" d="{svg_path_data(curve, degree4_step_m)}"/>')
    lines += ["  </g>", "</svg>", ""]
    with open_path_or_file(target, "w") as f:
        f.write("\n".join(lines))


def map_geojson(splines: Iterable[MapFeature], step_m: float = 0.02) -> dict:
    """The map as a GeoJSON FeatureCollection (a dict): one LineString per spline through
    curve points about ``step_m`` apart, every knot among them (m, map frame); see
    :func:`sampled_runs`."""
    return _geojson(splines, step_m, np.ndarray.tolist)


def _geojson(splines: Iterable[MapFeature], step_m: float, numbers) -> dict:
    """:func:`map_geojson` with each array of numbers given as ``numbers(array)`` (its list,
    or the array itself for :func:`~bsslam.io.indented_json.dumps_compact`)."""
    features = []
    for f in splines:
        curve = _curve(f)
        runs = sampled_runs(curve, step_m)
        geometry = ({"type": "LineString", "coordinates": numbers(runs[0])} if len(runs) == 1 else
                    {"type": "MultiLineString", "coordinates": [numbers(run) for run in runs]})
        features.append({
            "type": "Feature",
            "id": int(f.id),
            "geometry": geometry,
            "properties": {"id": int(f.id), "degree": int(curve.degree), "knots": numbers(curve.knots),
                           "control_points": numbers(curve.control_points)},
        })
    return {"type": "FeatureCollection",
            "frame": {"units": "m", "axes": "x, y of the run's map frame (the first pose), not WGS 84"},
            "features": features}


def _same(array: np.ndarray) -> np.ndarray:
    return array


def write_map_geojson(target: PathOrFile, splines: Iterable[MapFeature], step_m: float = 0.02) -> None:
    """Write :func:`map_geojson` to a path or text file."""
    # json.dumps' text, the arrays formatted whole: building the nested lists for the C
    # encoder took as long as the encoding (json.dump, the pure-Python encoder, 10x more)
    text = dumps_compact(_geojson(splines, step_m, _same))
    with open_path_or_file(target, "w") as f:
        f.write(text + "\n")
