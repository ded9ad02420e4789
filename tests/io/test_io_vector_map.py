"""The metric vector exports: the SVG's Bézier segments are the splines themselves (parsed
back and evaluated), and the GeoJSON's line strings lie on them (read with shapely)."""

import json
import math
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import shapely.geometry

from bsslam.io.map_file import CurveRecord, SplineRecord
from bsslam.io.vector_map import bezier_pieces, map_geojson, write_map_geojson, write_map_svg
from bsslam.spline import BSplineCurve
from bsslam.spline.closest import closest_point
from bsslam.spline.knots import uniform_knots

SVG = "{http://www.w3.org/2000/svg}"


def _random_curve(rng, degree, clamped=True, repeated=False, offset=(120.0, -340.0)):
    n = int(rng.integers(degree + 1, degree + 7))
    if clamped:
        inner = np.sort(rng.uniform(0.0, 6.0, n - degree - 1))
        if repeated and len(inner) >= 2:
            inner[1] = inner[0]                       # a double interior knot: C^(p−2), a jump for p = 1
        knots = np.concatenate([np.zeros(degree + 1), inner, np.full(degree + 1, 6.0)])
    else:
        knots = uniform_knots(n, degree, spacing=0.7, start=-1.3)
    points = np.cumsum(rng.normal(0.0, 1.0, (n, 2)), axis=0) + np.asarray(offset)
    return BSplineCurve(points, knots, degree)


def _curves():
    rng = np.random.default_rng(11)
    curves = []
    for degree in (1, 2, 3, 4):
        curves += [_random_curve(rng, degree), _random_curve(rng, degree, clamped=False),
                   _random_curve(rng, degree, repeated=True)]
    return curves


def _records(curves):
    # the writers take what map.json holds (or the run's MapSpline): an id and a curve record
    return [SplineRecord(id=10 + k, curve=CurveRecord(c.degree, c.knots, c.control_points))
            for k, c in enumerate(curves)]


def _on_piece(curve, s, tau):
    """The curve on its piece s at τ ∈ [0, 1] (m, 2); τ = 1 is the left limit at the piece's
    end (a spline with a jump there takes the next piece's value)."""
    pieces = curve.pieces
    return curve.evaluate(pieces.breaks[s] + np.minimum(tau, 1 - 1e-13) * pieces.widths[s])


def _bernstein(control, tau):
    """Bézier curve (m, 2) with (p+1, 2) control points at τ (m,): the textbook sum."""
    p = len(control) - 1
    basis = np.array([math.comb(p, i) * (1 - tau) ** (p - i) * tau ** i for i in range(p + 1)])
    return basis.T @ control


def _parse_path(d):
    """SVG path data of M, L, Q, C commands (absolute, as written) → list of (command,
    (k+1, 2) points with the current point first)."""
    tokens = re.findall(r"[MLQC]|[-+0-9.eE]+", d)
    segments, current, i = [], None, 0
    per = {"L": 1, "Q": 2, "C": 3}
    while i < len(tokens):
        cmd = tokens[i]
        i += 1
        if cmd == "M":
            current = np.array([float(tokens[i]), float(tokens[i + 1])])
            i += 2
            continue
        k = per[cmd]
        pts = np.array([float(v) for v in tokens[i:i + 2 * k]]).reshape(k, 2)
        i += 2 * k
        segments.append((cmd, np.vstack([current, pts])))
        current = pts[-1]
    return segments


def test_bezier_pieces_are_the_spline_piece_by_piece():
    tau = np.linspace(0.0, 1.0, 33)
    for curve in _curves():
        for s, control in enumerate(bezier_pieces(curve)):
            np.testing.assert_allclose(_bernstein(control, tau), _on_piece(curve, s, tau), rtol=0, atol=1e-9)


def test_the_svg_paths_are_the_splines_in_metres(tmp_path):
    curves = _curves()
    write_map_svg(tmp_path / "map_metric.svg", _records(curves))
    root = ET.parse(tmp_path / "map_metric.svg").getroot()
    group = root.find(f"{SVG}g")
    assert group.get("transform") == "scale(1,-1)"          # y up: path coordinates are the map's
    x, y_flipped, w, h = (float(v) for v in root.get("viewBox").split())
    cps = np.vstack([c.control_points for c in curves])
    # the view holds every control point (metres, y flipped by the group)
    assert x <= cps[:, 0].min() and cps[:, 0].max() <= x + w
    assert y_flipped <= -cps[:, 1].max() and -cps[:, 1].min() <= y_flipped + h
    assert root.get("width") == f"{10 * w!r}mm"               # 1:100
    paths = group.findall(f"{SVG}path")
    assert [p.get("id") for p in paths] == [f"spline-{10 + k}" for k in range(len(curves))]
    tau = np.linspace(0.0, 1.0, 17)
    for path, curve in zip(paths, curves):
        assert int(path.get("data-degree")) == curve.degree
        segments = _parse_path(path.get("d"))
        pieces = curve.pieces
        if curve.degree == 4:
            # no SVG primitive: a polyline whose vertices lie on the curve, ≤ 1 cm apart in parameter
            assert {cmd for cmd, _ in segments} == {"L"}
            vertices = np.vstack([segments[0][1][:1]] + [seg[1][1:] for seg in segments])
            _, _, dist = closest_point(curve, vertices)
            assert np.max(dist) < 1e-9
            np.testing.assert_allclose(vertices[[0, -1]], curve.evaluate(list(curve.domain)), atol=1e-9)
            assert len(segments) >= (curve.domain[1] - curve.domain[0]) / 0.01
            continue
        assert [cmd for cmd, _ in segments] == [{1: "L", 2: "Q", 3: "C"}[curve.degree]] * len(pieces.widths)
        for s, (_, control) in enumerate(segments):
            np.testing.assert_allclose(_bernstein(control, tau), _on_piece(curve, s, tau), rtol=0, atol=1e-9)


def test_the_geojson_line_strings_lie_on_the_splines(tmp_path):
    curves = _curves()
    write_map_geojson(tmp_path / "map.geojson", _records(curves))
    doc = json.loads((tmp_path / "map.geojson").read_text())
    assert doc["type"] == "FeatureCollection" and doc["frame"]["units"] == "m"
    assert len(doc["features"]) == len(curves)
    for k, (feature, curve) in enumerate(zip(doc["features"], curves)):
        line = shapely.geometry.shape(feature["geometry"])
        jumps = curve.degree == 1 and len(np.unique(curve.knots)) < len(curve.knots) - 2 * curve.degree
        assert line.geom_type == ("MultiLineString" if jumps else "LineString")
        assert line.is_valid and not line.is_empty
        props = feature["properties"]
        assert props["id"] == 10 + k and props["degree"] == curve.degree
        np.testing.assert_array_equal(props["knots"], curve.knots)
        np.testing.assert_array_equal(props["control_points"], curve.control_points)
        runs = [np.asarray(g.coords) for g in getattr(line, "geoms", [line])]
        coords = np.vstack(runs)
        _, _, dist = closest_point(curve, coords)
        assert np.max(dist) < 1e-9                                  # every vertex on the curve
        np.testing.assert_allclose([runs[0][0], runs[-1][-1]], curve.evaluate(list(curve.domain)), atol=1e-9)
        speed = np.max(np.linalg.norm(curve.evaluate(np.linspace(*curve.domain, 2000), 1), axis=1))
        assert max(np.max(np.hypot(*np.diff(r, axis=0).T)) for r in runs) <= 0.02 * speed * (1 + 1e-9)
        # densely sampled: its length is the curve's (chords fall short by ~(κh)²/24)
        assert line.length == pytest.approx(curve.length(), rel=1e-3)


def test_an_empty_map_still_writes_valid_files(tmp_path):
    write_map_svg(tmp_path / "m.svg", [])
    root = ET.parse(tmp_path / "m.svg").getroot()
    assert root.find(f"{SVG}g").findall(f"{SVG}path") == []
    assert map_geojson([]) == {"type": "FeatureCollection", "frame": map_geojson([])["frame"], "features": []}
