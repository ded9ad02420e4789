"""The filter's map-curve table, grown spline by spline as the map is built, updated in place
as splines are extended and shrunk as unconfirmed ones are pruned, is the table built from
scratch from its features (the one every search of the filter reads)."""

import dataclasses

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.experiments.consistency import simulation_config
from bsslam.pipeline import run_dataset
from bsslam.sim import SimConfig, get_world, simulate
from bsslam.slam import SplineSLAM
from bsslam.slam.map_curves import MapCurves


def test_grown_extended_and_pruned_table_equals_the_rebuilt_one(monkeypatch):
    grown = []
    with_added = MapCurves.with_added
    monkeypatch.setattr(MapCurves, "with_added", lambda self, f: grown.append(len(f)) or with_added(self, f))
    shrunk = []
    without = MapCurves.without
    monkeypatch.setattr(MapCurves, "without", lambda self, *a: shrunk.append(1) or without(self, *a))
    replaced = []
    with_replaced = MapCurves.with_replaced
    monkeypatch.setattr(MapCurves, "with_replaced", lambda self, *a: replaced.append(1) or with_replaced(self, *a))
    sim = SimConfig()
    data = simulate(get_world("mixed"), sim, seed=5, steps=100)
    config = simulation_config(SLAMConfig(), sim).replace(relocalize=False)
    slam = SplineSLAM(config)
    run_dataset(data, config, point_stride=0, slam=slam)
    kept = slam.spline_map.curves()
    assert len(grown) > 3, "the table never grew in place"
    assert len(shrunk) > 3, "no pruning shrank the table in place"
    assert len(replaced) > 3, "no extension replaced its spline's rows in place"
    fresh = MapCurves(list(slam.features.values()))
    for f in dataclasses.fields(fresh.table):
        np.testing.assert_array_equal(getattr(kept.table, f.name), getattr(fresh.table, f.name), err_msg=f.name)
    np.testing.assert_array_equal(kept.state_rows, fresh.state_rows)
    np.testing.assert_array_equal(kept.ids, fresh.ids)


def test_curve_state_indices_are_the_unique_rows_of_the_curves():
    """The compiled gather of the working rows against np.unique of the curves' state rows,
    with fixed control points (−1) and curves sharing none of their rows."""
    from bsslam.slam.kernels import curve_state_indices
    from bsslam.spline.batch import kept_rows

    rng = np.random.default_rng(3)
    for _ in range(50):
        counts = rng.integers(1, 8, size=rng.integers(1, 12))
        cp_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.intp)
        n = 3 + 2 * int(cp_start[-1]) + 5
        state_rows = rng.permutation(np.arange(3, n))[: 2 * cp_start[-1]].reshape(-1, 2).astype(np.intp)
        state_rows[rng.random(state_rows.shape[0]) < 0.2] = -1          # fixed control points
        curves = np.sort(rng.choice(counts.size, rng.integers(1, counts.size + 1), replace=False))
        rows = state_rows[kept_rows(cp_start, curves)[0]].ravel()
        expected = np.unique(rows[rows >= 0])
        got = curve_state_indices(state_rows, cp_start, curves, n)
        np.testing.assert_array_equal(got, expected)
        assert got.dtype == np.intp
