"""dumps_indented writes exactly the json module's indented text (the oracle), errors included."""

import json

import numpy as np
import pytest

from bsslam.io.indented_json import dumps_compact, dumps_indented

DOCUMENTS = [
    {"a": [1.0, 2.5e-300, -0.0, 1e22, 0.1], "b": {"c": [], "d": {}, "e": None, "f": True, "g": 'héllo\n"x',
                                                "h": [[1.0, 2.0], [3, 4]], "i": [1, 2.0], "j": [True, False],
                                                "k": (1.5,), "l": [None, "s", 1.0]},
     1: 2, 2.5: 3, None: 4, False: 5},
    [], {}, 1.5, -7, "x", None, [[[]]], [{}], [[], {}],
    np.random.default_rng(0).normal(size=(5, 3)).tolist(),
    {"subclass": [np.float64(1.25), 2.0], "ints": [np.int64(3).item(), 2]},
]


@pytest.mark.parametrize("indent", [0, 1, 2])
@pytest.mark.parametrize("document", DOCUMENTS)
def test_same_text_as_the_json_module(document, indent):
    assert dumps_indented(document, indent) == json.dumps(document, indent=indent, allow_nan=False)


def test_a_map_document_round_trips():
    rng = np.random.default_rng(1)
    doc = {"splines": [{"id": i, "knots": np.sort(rng.uniform(0, 5, 8)).tolist(),
                        "control_points": rng.normal(size=(4, 2)).tolist(),
                        "covariance": rng.normal(size=(8, 8)).tolist() if i else None} for i in range(3)]}
    text = dumps_indented(doc, 1)
    assert text == json.dumps(doc, indent=1, allow_nan=False)
    assert json.loads(text) == doc


@pytest.mark.parametrize("bad", [[float("nan")], {"x": [1.0, float("inf")]}, {"y": [[1.0], [-float("inf")]]},
                                 {float("nan"): 1}, {"z": float("nan")}])
def test_non_finite_numbers_are_refused_like_the_json_module(bad):
    with pytest.raises(ValueError) as ours:
        dumps_indented(bad, 1)
    with pytest.raises(ValueError) as theirs:
        json.dumps(bad, indent=1, allow_nan=False)
    assert str(ours.value) == str(theirs.value)


def test_values_json_cannot_hold_are_type_errors():
    with pytest.raises(TypeError):
        dumps_indented({"a": [object()]}, 1)
    with pytest.raises(TypeError):
        dumps_indented({(1, 2): 0}, 1)


ARRAYS = [np.random.default_rng(2).normal(size=(7, 4)), np.array([1.0, -0.0, 1e22, 2.5e-300, 0.1]),
          np.arange(6).reshape(2, 3), np.arange(5, dtype=np.uint8), np.zeros((0, 2)), np.zeros((2, 0)),
          np.zeros(0), np.array(3.5), np.array([[True, False]]), np.ones((2, 2, 2)),
          np.array([1.5, 2.25], dtype=np.float32), np.asfortranarray(np.arange(12.0).reshape(3, 4))[:, ::2]]


@pytest.mark.parametrize("array", ARRAYS + [np.array([1.0, np.nan, -np.inf])], ids=range(len(ARRAYS) + 1))
def test_compact_text_is_json_dumps_of_the_lists(array):
    document = {"a": array, "nested": [array, {"b": array, "c": (1, "é", None, 2.5)}], "d": {1: 2}}
    as_lists = {"a": array.tolist(), "nested": [array.tolist(), {"b": array.tolist(), "c": (1, "é", None, 2.5)}],
                "d": {1: 2}}
    assert dumps_compact(document) == json.dumps(as_lists)


@pytest.mark.parametrize("document", DOCUMENTS)
def test_compact_text_of_documents_without_arrays(document):
    assert dumps_compact(document) == json.dumps(document)
