"""concat_tables gives, field for field and bit for bit, the table curve_table builds from all
the knot vectors at once (the filter grows its map table this way)."""

import dataclasses

import numpy as np
import pytest

from bsslam.errors import SplineError
from bsslam.spline import fit_curve
from bsslam.spline.batch import concat_tables, curve_table, take_curves


def _knots(rng, count, degree):
    out = []
    for i in range(count):
        pts = np.cumsum(rng.normal(size=(20 + 7 * i, 2)) * 0.2, axis=0)
        out.append(fit_curve(pts, degree, 0.8).curve.knots)
    return out


@pytest.mark.parametrize("degree", [1, 2, 3])
@pytest.mark.parametrize("split", [1, 3, 5])
def test_concatenation_equals_building_all_at_once(degree, split):
    knots = _knots(np.random.default_rng(degree * 10 + split), 6, degree)
    full = curve_table(knots, [degree] * 6)
    joined = concat_tables(curve_table(knots[:split], [degree] * split),
                           curve_table(knots[split:], [degree] * (6 - split)))
    for f in dataclasses.fields(full):
        np.testing.assert_array_equal(getattr(joined, f.name), getattr(full, f.name), err_msg=f.name)
    for name in ("piece_keys", "last_piece"):
        np.testing.assert_array_equal(getattr(joined, name), getattr(full, name), err_msg=name)
    # and the joined table answers queries as the full one does
    cp = np.random.default_rng(0).normal(size=(int(full.cp_start[-1]), 2))
    curve = np.repeat(np.arange(6), 5)
    t = full.lo[curve] + (full.hi[curve] - full.lo[curve]) * np.tile(np.linspace(0, 1, 5), 6)
    np.testing.assert_array_equal(joined.with_control_points(cp).evaluate(curve, t),
                                  full.with_control_points(cp).evaluate(curve, t))


def test_tables_of_different_degrees_are_refused():
    rng = np.random.default_rng(3)
    with pytest.raises(SplineError):
        concat_tables(curve_table(_knots(rng, 1, 2), [2]), curve_table(_knots(rng, 1, 3), [3]))


@pytest.mark.parametrize("degree", [1, 2, 3])
@pytest.mark.parametrize("keep", [[0], [1, 2, 5], [0, 2, 3, 4, 5], [5]])
def test_taking_curves_equals_building_them_alone(degree, keep):
    """take_curves (the filter's pruning) gives the table curve_table builds from the kept
    knot vectors, bit for bit, including padded windows."""
    knots = _knots(np.random.default_rng(degree * 7 + len(keep)), 6, degree)
    degrees = [degree] * 6
    if degree > 1:
        degrees[3] = degree - 1   # one lower-degree curve: padded windows
    full = curve_table(knots, degrees)
    taken = take_curves(full, np.array(keep))
    alone = curve_table([knots[c] for c in keep], [degrees[c] for c in keep])
    for f in dataclasses.fields(alone):
        np.testing.assert_array_equal(getattr(taken, f.name), getattr(alone, f.name), err_msg=f.name)
    for name in ("piece_keys", "last_piece"):
        np.testing.assert_array_equal(getattr(taken, name), getattr(alone, name), err_msg=name)


def test_taking_no_curve_or_losing_the_padded_degree_is_refused():
    rng = np.random.default_rng(4)
    table = curve_table(_knots(rng, 2, 3) + _knots(rng, 1, 2), [3, 3, 2])
    with pytest.raises(SplineError):
        take_curves(table, np.array([], dtype=int))
    with pytest.raises(SplineError):
        take_curves(table, np.array([2]))


def test_a_curve_without_a_non_empty_span_is_refused():
    """All knots equal, or too few knots for the degree: no piece, a clear error."""
    good = _knots(np.random.default_rng(6), 1, 3)[0]
    for bad in (np.zeros(8), np.array([0.0, 0.0, 1.0, 1.0])):
        with pytest.raises(SplineError, match="non-empty domain"):
            curve_table([good, bad], [3, 3])


def test_table_fields_equal_a_reference_built_curve_by_curve():
    """curve_table's compiled layout against the layout of each curve built alone and
    shifted: rows, pieces, breaks and padded windows (one lower-degree curve)."""
    knots = _knots(np.random.default_rng(8), 4, 3)
    knots[2] = _knots(np.random.default_rng(9), 1, 2)[0]
    degrees = [3, 3, 2, 3]
    full = curve_table(knots, degrees)
    for c, (k, d) in enumerate(zip(knots, degrees)):
        alone = curve_table([k], [d])
        pieces = slice(full.piece_start[c], full.piece_start[c + 1])
        np.testing.assert_array_equal(full.piece_lo[pieces], alone.piece_lo)
        np.testing.assert_array_equal(full.width[pieces], alone.width)
        np.testing.assert_array_equal(full.keys[full.break_start[c]:full.break_start[c + 1]].imag, alone.keys.imag)
        np.testing.assert_array_equal(full.window[pieces, : d + 1] - full.cp_start[c], alone.window)
        assert full.real[pieces, : d + 1].all() and not full.real[pieces, d + 1:].any()
        # padding repeats the last real row
        np.testing.assert_array_equal(full.window[pieces, d + 1:], full.window[pieces, d : d + 1].repeat(3 - d, axis=1))
        assert (full.lo[c], full.hi[c]) == (alone.lo[0], alone.hi[0])
