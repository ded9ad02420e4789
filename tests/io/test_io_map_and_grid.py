"""Round trips of the spline map JSON (the occupancy grid: test_io_occupancy_grid.py)."""

import io
import json
from dataclasses import dataclass

import numpy as np
import pytest

from bsslam.errors import InputError, SplineError
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
