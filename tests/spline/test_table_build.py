"""curve_table's one compiled call (kernels.curve_table_arrays) against the numpy form it
replaced (table_oracle.py): every field, dtype, shape and bit, on random knot vectors of
one degree and of mixed degrees (padding), with repeated knots, negative and −0.0 breaks."""

import dataclasses

import numpy as np
import pytest

from bsslam.errors import SplineError
from bsslam.spline.batch import curve_table
from table_oracle import curve_table_fields


def _random_knots(rng, degree):
    """A clamped knot vector with random (sometimes repeated) interior knots, shifted so
    that breaks may be negative or exactly −0.0."""
    n_interior = int(rng.integers(0, 7))
    inner = np.sort(rng.uniform(0.0, 3.0, n_interior))
    if n_interior > 1 and rng.random() < 0.5:
        inner[1] = inner[0]                       # a repeated knot: an empty span
    start, end = 0.0, 3.0 + rng.random()
    knots = np.concatenate([[start] * (degree + 1), inner, [end] * (degree + 1)])
    shift = rng.choice([0.0, -1.5, -end, 1e3 * rng.random()])
    knots = knots + shift
    if shift == 0.0:
        knots[: degree + 1] = -0.0                # the domain starts at −0.0
    if shift == -end:
        knots[-degree - 1:] = -0.0                # the domain ends at −0.0
    return knots


def _assert_bitwise(a, b, name):
    a, b = np.asarray(a), np.asarray(b)
    assert a.dtype == b.dtype and a.shape == b.shape, name
    assert a.tobytes() == b.tobytes(), name


@pytest.mark.parametrize("seed", range(40))
def test_compiled_table_is_the_numpy_table_bit_for_bit(seed):
    rng = np.random.default_rng(seed)
    C = int(rng.integers(1, 6))
    top = int(rng.integers(0, 5))
    degrees = [top] * C if seed % 2 else [int(d) for d in rng.integers(0, top + 1, C)]
    knots = [_random_knots(rng, d) for d in degrees]
    expected = curve_table_fields(knots, degrees)
    if expected is None:
        with pytest.raises(SplineError, match="non-empty domain"):
            curve_table(knots, degrees)
        return
    table = curve_table(knots, degrees)
    for f in dataclasses.fields(table):
        _assert_bitwise(getattr(table, f.name), expected[f.name], f.name)
    for name in ("piece_keys", "last_piece"):
        _assert_bitwise(getattr(table, name), expected[name], name)
