"""The fit-quality experiments (paper Figs. 2–3): their orderings, a least-squares oracle,
reproducibility, and the files they write."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from bsslam.errors import ConfigError
from bsslam.experiments.fit import (
    fit_example,
    fit_knots_experiment,
    fit_order_experiment,
    sensor_bearings,
    wall_range,
    write_fit_knots,
    write_fit_order,
)

SEEDS = (0, 1, 2)


@pytest.mark.parametrize("seed", SEEDS)
def test_error_falls_as_knot_spacing_falls(seed):
    # Over spacings where the wall's waves (6.3 m long) dominate the error. Below ~0.7 m
    # the fit starts following the noise and the error rises again (σ²·n_control/m).
    spacings = (1.0, 2.0, 2.92, 4.0, 6.0)
    mse = [m for _, m in fit_knots_experiment(spacings, runs=10, seed=seed)]
    assert np.all(np.diff(mse) > 0)


@pytest.mark.parametrize("seed", SEEDS)
def test_at_the_papers_spacing_cubic_beats_quadratic_beats_linear(seed):
    results = fit_order_experiment(degrees=(1, 2, 3), spacing_m=2.92, runs=10, seed=seed)
    assert [k for k, _ in results] == [2, 3, 4]
    linear, quadratic, cubic = (m for _, m in results)
    assert cubic <= quadratic <= linear


def test_fine_knots_leave_only_the_least_squares_noise():
    # Noise-free: a 0.25 m cubic reproduces the wall to micrometres along every beam.
    [(_, exact)] = fit_knots_experiment((0.25,), runs=1, sigma_m=0.0)
    assert exact < 1e-10
    # Noisy: the bias is negligible, and a least-squares projection onto n_control of m
    # points keeps σ²·n_control/m of the noise variance (trace of the hat matrix / m).
    sigma = 0.005
    [(_, mse)] = fit_knots_experiment((0.25,), runs=10, seed=4, sigma_m=sigma)
    example = fit_example([(3, 0.25)], seed=4, sigma_m=sigma)
    n_control = example.curves[0][1].n_control
    expected = sigma**2 * n_control / example.points.shape[0]
    assert mse == pytest.approx(expected, rel=0.2)


def test_results_are_reproducible_and_progress_is_reported():
    calls = []
    first = fit_knots_experiment((1.0, 3.0), runs=4, seed=7, progress=lambda done, total: calls.append((done, total)))
    again = fit_knots_experiment((1.0, 3.0), runs=4, seed=7)
    other = fit_knots_experiment((1.0, 3.0), runs=4, seed=8)
    assert first == again
    assert first != other
    assert calls == [(1, 4), (2, 4), (3, 4), (4, 4)]
    # The same seed gives the same scans to both experiments.
    [(_, knots_cubic)] = fit_knots_experiment((2.92,), runs=3, seed=5)
    [(_, order_cubic)] = fit_order_experiment((3,), runs=3, seed=5)
    assert knots_cubic == order_cubic


def test_scan_geometry_and_arguments():
    phi = sensor_bearings(1.0)
    assert phi.shape == (181,) and phi[0] == 0.0 and phi[-1] == pytest.approx(np.pi)
    assert sensor_bearings(0.5).shape == (361,)
    np.testing.assert_allclose(wall_range(np.array([0.0, np.pi / 10])), [5.0, 5.5])
    with pytest.raises(ConfigError):
        sensor_bearings(0.7)
    with pytest.raises(ConfigError):
        fit_knots_experiment((1.0,), runs=0)


def _read_csv(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], [[float(v) for v in row] for row in rows[1:]]


def test_writers_produce_csv_with_exact_headers_and_pngs(tmp_path):
    knots = [(0.5, 1.5e-5), (2.92, 3.8e-3), (6.0, 5.6e-2)]
    order = [(2, 1.9e-2), (3, 1.4e-2), (4, 3.8e-3)]
    knot_paths = write_fit_knots(knots, tmp_path)
    order_paths = write_fit_order(order, tmp_path)
    assert sorted(p.name for p in knot_paths + order_paths) == [
        "fit_knots.csv", "fit_knots.png", "fit_order.csv", "fit_order.png"]
    header, rows = _read_csv(tmp_path / "fit_knots.csv")
    assert header == ["knot_spacing_m", "mse_m2"]
    np.testing.assert_allclose(rows, knots, rtol=1e-8)
    header, rows = _read_csv(tmp_path / "fit_order.csv")
    assert header == ["order", "mse_m2"]
    np.testing.assert_allclose(rows, order, rtol=1e-8)
    for name in ("fit_knots.png", "fit_order.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
