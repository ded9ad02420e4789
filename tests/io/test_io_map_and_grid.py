"""Round trips of the spline map JSON and the map_server occupancy grid."""

import io
import json
from dataclasses import dataclass

import numpy as np
import pytest
import yaml

from bsslam.errors import InputError, SplineError
from bsslam.io.grid import FREE, OCCUPIED, UNKNOWN, render_grid, write_grid
from bsslam.io.map_file import read_map_json, write_map_json


@dataclass
class _Curve:
    degree: int
    knots: np.ndarray
    control_points: np.ndarray


@dataclass
class _Spline:
    id: int
    curve: _Curve
    covariance: np.ndarray | None


def _splines():
    rng = np.random.default_rng(3)
    cubic = _Curve(3, np.array([0, 0, 0, 0, 0.9, 2.1, 2.1, 2.1, 2.1]), rng.normal(size=(5, 2)))
    a = rng.normal(size=(10, 10))
    linear = _Curve(1, np.array([0.0, 0.0, 1.5, 1.5]), np.array([[0.0, 0.0], [1.5, 0.0]]))
    return [_Spline(4, cubic, a @ a.T), _Spline(9, linear, None)]


def test_map_json_round_trip(tmp_path):
    path = tmp_path / "map.json"
    write_map_json(path, _splines(), metadata={"log": "intel"})
    loaded = read_map_json(path)
    assert loaded.metadata == {"log": "intel"}
    for original, back in zip(_splines(), loaded.splines, strict=True):
        assert back.id == original.id
        assert back.curve.degree == original.curve.degree
        np.testing.assert_array_equal(back.curve.knots, original.curve.knots)
        np.testing.assert_array_equal(back.curve.control_points, original.curve.control_points)
        if original.covariance is None:
            assert back.covariance is None
        else:
            np.testing.assert_array_equal(back.covariance, original.covariance)
    # a loaded map can be written again unchanged
    again = io.StringIO()
    write_map_json(again, loaded.splines, metadata=loaded.metadata)
    assert again.getvalue() == path.read_text()


def test_map_json_fields_and_metadata():
    out = io.StringIO()
    write_map_json(out, _splines()[:1])
    doc = json.loads(out.getvalue())
    assert doc["version"] == 1 and doc["units"]["control_points"] == "m"
    item = doc["splines"][0]
    assert (item["id"], item["order"], item["degree"]) == (4, 4, 3)
    assert np.shape(item["covariance"]) == (10, 10)


def test_inconsistent_spline_is_refused_when_writing():
    bad = _Spline(1, _Curve(3, np.zeros(5), np.zeros((5, 2))), None)
    with pytest.raises(SplineError, match="need 9 knots"):
        write_map_json(io.StringIO(), [bad])
    bad_cov = _Spline(2, _splines()[0].curve, np.eye(4))
    with pytest.raises(SplineError, match="covariance"):
        write_map_json(io.StringIO(), [bad_cov])


@pytest.mark.parametrize("mutate, words", [
    (lambda d: d.update(format="other"), "not a bsslam-spline-map"),
    (lambda d: d.update(version=99), "version"),
    (lambda d: d["splines"][0].update(order=7), "order"),
    (lambda d: d["splines"][0].update(knots=[0, 1]), "knots"),
    (lambda d: d["splines"][0].pop("control_points"), "missing"),
])
def test_bad_map_files_are_input_errors(tmp_path, mutate, words):
    out = io.StringIO()
    write_map_json(out, _splines())
    doc = json.loads(out.getvalue())
    mutate(doc)
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match=words) as info:
        read_map_json(path)
    assert info.value.path == str(path)


def test_invalid_json_names_the_line(tmp_path):
    path = tmp_path / "m.json"
    path.write_text('{\n"format": \n')
    with pytest.raises(InputError) as info:
        read_map_json(path)
    assert info.value.line is not None


def _read_pgm(data: bytes) -> np.ndarray:
    magic, width, height, maxval, pixels = data.split(maxsplit=4)
    assert magic == b"P5" and maxval == b"255"
    return np.frombuffer(pixels, dtype=np.uint8).reshape(int(height), int(width))


def _world_of_cell(row, col, origin, resolution, height):
    """Centre of a cell through the map_server convention (origin = lower-left corner)."""
    return (origin[0] + (col + 0.5) * resolution, origin[1] + (height - 1 - row + 0.5) * resolution)


def _cell_of(x, y, origin, resolution, height):
    return (height - 1 - int(np.floor((y - origin[1]) / resolution)),
            int(np.floor((x - origin[0]) / resolution)))


def test_grid_files_follow_map_server_and_cells_map_back_to_the_world(tmp_path):
    # the corner is off the cell boundaries so the expected cell is unambiguous
    wall = np.array([[0.0, 0.0], [4.04, 0.0], [4.04, 3.04]])
    resolution = 0.1
    grid, origin = render_grid([wall], resolution_m=resolution, margin_m=0.5)
    assert origin == pytest.approx((-0.5, -0.5, 0.0))
    write_grid(tmp_path / "map.pgm", tmp_path / "map.yaml", grid, origin, resolution)

    meta = yaml.safe_load((tmp_path / "map.yaml").read_text())
    assert meta == {"image": "map.pgm", "resolution": 0.1, "origin": list(origin), "negate": 0,
                    "occupied_thresh": 0.65, "free_thresh": 0.196, "mode": "trinary"}
    image = _read_pgm((tmp_path / "map.pgm").read_bytes())
    np.testing.assert_array_equal(image, grid)
    assert set(np.unique(image)) == {OCCUPIED, UNKNOWN}
    height = image.shape[0]
    assert image.shape == (41, 51)  # (3.04 + 1) / 0.1 rows, (4.04 + 1) / 0.1 columns, rounded up

    # the top-right occupied cell is the corner's, and maps back to its centre
    rows, cols = np.nonzero(image == OCCUPIED)
    top = rows.min()
    corner_cell = (top, cols[rows == top].max())
    assert corner_cell == _cell_of(4.04, 3.04, origin, resolution, height)
    assert corner_cell[0] == 41 - 1 - 35  # row 0 is the top: y = 3.04 is 35 cells above y = -0.5
    assert _world_of_cell(*corner_cell, origin, resolution, height) == pytest.approx((4.05, 3.05))
    # every occupied cell lies on the wall, and the wall leaves no gap along x
    world = np.array([_world_of_cell(r, c, origin, resolution, height) for r, c in zip(rows, cols)])
    on_bottom = np.abs(world[:, 1]) <= resolution * 0.75
    on_right = np.abs(world[:, 0] - 4.04) <= resolution * 0.75
    assert np.all(on_bottom | on_right)
    bottom_cols = np.unique(cols[on_bottom])
    assert np.array_equal(bottom_cols, np.arange(bottom_cols.min(), bottom_cols.max() + 1))
    assert len(bottom_cols) >= 40


def test_free_rays_clear_traversed_cells_but_not_the_hit():
    wall = np.array([[2.04, -1.04], [2.04, 1.04]])
    origin_xy = np.array([0.03, 0.04])
    hits = np.array([[2.04, 0.04], [2.04, 0.64]])
    grid, origin = render_grid([wall], resolution_m=0.1, margin_m=0.2, free_rays=[(origin_xy, hits)])
    height = grid.shape[0]

    def value(x, y):
        return grid[_cell_of(x, y, origin, 0.1, height)]

    assert value(*origin_xy) == FREE
    assert value(1.0, 0.04) == FREE
    assert value(*(0.5 * (origin_xy + hits[1]))) == FREE
    assert value(*hits[0]) == OCCUPIED and value(*hits[1]) == OCCUPIED
    assert value(1.0, -0.5) == UNKNOWN  # no ray went there
    assert value(2.2, 0.04) == UNKNOWN  # behind the wall


def test_empty_map_gives_an_unknown_grid_around_the_origin():
    grid, origin = render_grid([], resolution_m=0.1, margin_m=1.0)
    assert grid.shape == (20, 20) and np.all(grid == UNKNOWN)
    assert origin == pytest.approx((-1.0, -1.0, 0.0))


def test_grid_refuses_bad_arguments(tmp_path):
    with pytest.raises(InputError, match="resolution"):
        render_grid([np.zeros((2, 2))], resolution_m=0.0)
    with pytest.raises(InputError, match="uint8"):
        write_grid(tmp_path / "a.pgm", tmp_path / "a.yaml", np.zeros((2, 2)), (0, 0, 0), 0.1)
