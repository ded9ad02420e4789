"""The paper's fit-quality experiments (Figs. 2–3, spec §10).

A static sensor at the origin faces the curved wall ``z(φ) = 5 + 0.5 sin(5φ)`` (polar, m)
over φ ∈ [0, π] (a 180° field of view), one beam every ``resolution_deg``, ranges with
N(0, σ²) noise and an 8 m maximum range. Each Monte Carlo run fits one spline to the whole
scan (one segment), then measures, beam by beam, the range from the sensor to the fitted
spline along that beam (:func:`bsslam.spline.intersect_rays`) against the true range
z(φ); the run's error is the mean of the squared differences (MSE, m²), and the
experiments report the mean of that MSE over runs:

- :func:`fit_knots_experiment`: MSE against the knot spacing ρ of a cubic (Fig. 2);
- :func:`fit_order_experiment`: MSE against the order κ = degree + 1 at ρ = 2.92 m (Fig. 3).

Randomness: run ``r`` draws its noise from ``default_rng(SeedSequence(seed).spawn(runs)[r])``,
so results depend only on ``seed`` and ``runs``, and every knot spacing or order sees the
same noisy scans (common random numbers make the comparison sharper than the noise).

Beams whose ray misses the fitted spline are left out of that run's MSE: this happens
only at the two ends of the field of view, where a least-squares spline, not
interpolating its end points, may stop just short of the first or last beam (about one
beam per fit; six at ρ = 6 m, whose end spans are pulled in by the wave).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from bsslam.errors import ConfigError, FitError
from bsslam.io.atomic_file import atomic_write
from bsslam.spline import BSplineCurve, FitResult, fit_curve, intersect_rays

#: The curved wall of the paper's eq. (12): z(φ) = base + amplitude·sin(frequency·φ) (m).
WALL_BASE_M = 5.0
WALL_AMPLITUDE_M = 0.5
WALL_FREQUENCY = 5.0

#: Knot spacings (m) of the default knot experiment, 0.25–6 m, about √2 apart, with the
#: paper's 2.92 m.
DEFAULT_SPACINGS_M = (0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.92, 4.0, 6.0)
#: The knot spacing of the paper's order experiment (m).
PAPER_ORDER_SPACING_M = 2.92

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class FitExample:
    """One noisy scan of the wall and the splines fitted to it, for drawing.

    Attributes:
        bearings: (n,) beam angles φ (rad).
        true_points: (n, 2) exact wall points along the beams (m).
        points: (k, 2) the noisy scan points used in the fit (beams below max range) (m).
        curves: (label, fitted curve) pairs.
    """

    bearings: np.ndarray
    true_points: np.ndarray
    points: np.ndarray
    curves: list[tuple[str, BSplineCurve]]


def wall_range(phi: np.ndarray) -> np.ndarray:
    """True range (m) from the origin to the wall along bearings φ (rad), any shape."""
    return WALL_BASE_M + WALL_AMPLITUDE_M * np.sin(WALL_FREQUENCY * np.asarray(phi, dtype=float))


def sensor_bearings(resolution_deg: float = 1.0) -> np.ndarray:
    """(n,) beam bearings from 0 to π inclusive, ``resolution_deg`` apart (rad)."""
    if not (0 < resolution_deg <= 90):
        raise ConfigError(f"resolution_deg must be in (0, 90], got {resolution_deg}")
    n = int(round(180.0 / resolution_deg))
    if not math.isclose(n * resolution_deg, 180.0, rel_tol=1e-9):
        raise ConfigError(f"resolution_deg must divide 180°, got {resolution_deg}")
    return np.linspace(0.0, math.pi, n + 1)


def fit_knots_experiment(spacings_m: Sequence[float] = DEFAULT_SPACINGS_M, runs: int = 50, seed: int = 0,
                         resolution_deg: float = 1.0, sigma_m: float = 0.005, max_range_m: float = 8.0,
                         progress: Progress | None = None) -> list[tuple[float, float]]:
    """Mean range MSE of a cubic fit against the knot spacing (paper Fig. 2).

    Args:
        spacings_m: knot spacings ρ to try (m).
        runs: Monte Carlo runs (scans) per spacing; every spacing sees the same scans.
        seed: seed of the noise streams.
        resolution_deg: angle between beams (deg); must divide 180.
        sigma_m: σ of the Gaussian range noise (m).
        max_range_m: noisy ranges at or beyond this are dropped (m).
        progress: optional ``progress(done_runs, runs)``, called after each run.

    Returns:
        ``[(knot_spacing_m, mse_m2), …]`` in the order of ``spacings_m``.
    """
    spacings = [float(s) for s in spacings_m]
    mse = _monte_carlo([(3, s) for s in spacings], runs, seed, resolution_deg, sigma_m, max_range_m, progress)
    return list(zip(spacings, mse))


def fit_order_experiment(degrees: Sequence[int] = (1, 2, 3), spacing_m: float = PAPER_ORDER_SPACING_M,
                         runs: int = 50, seed: int = 0, resolution_deg: float = 1.0, sigma_m: float = 0.005,
                         max_range_m: float = 8.0, progress: Progress | None = None) -> list[tuple[int, float]]:
    """Mean range MSE against the spline order κ = degree + 1 at one knot spacing (paper Fig. 3).

    Args:
        degrees: polynomial degrees to try (1 linear, 2 quadratic, 3 cubic).
        spacing_m: the knot spacing ρ (m); the paper's 2.92 m by default.
        Others as :func:`fit_knots_experiment`.

    Returns:
        ``[(order, mse_m2), …]`` in the order of ``degrees``, order = degree + 1.
    """
    degrees = [int(d) for d in degrees]
    mse = _monte_carlo([(d, float(spacing_m)) for d in degrees], runs, seed, resolution_deg, sigma_m,
                       max_range_m, progress)
    return [(d + 1, m) for d, m in zip(degrees, mse)]


def fit_example(fits: Sequence[tuple[int, float]], seed: int = 0, resolution_deg: float = 1.0,
                sigma_m: float = 0.005, max_range_m: float = 8.0) -> FitExample:
    """The first scan of the experiments with ``seed`` and the splines of the given
    ``(degree, knot_spacing_m)`` fitted to it."""
    bearings = sensor_bearings(resolution_deg)
    true_ranges = wall_range(bearings)
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
    _, points = _noisy_points(rng, bearings, true_ranges, sigma_m, max_range_m)
    curves = [(f"degree {d}, ρ = {s:g} m", fit_curve(points, d, s).curve) for d, s in fits]
    return FitExample(bearings=bearings, true_points=_polar_points(bearings, true_ranges), points=points,
                      curves=curves)


def write_fit_knots(results: Sequence[tuple[float, float]], run_dir: str | Path, *, seed: int = 0,
                    resolution_deg: float = 1.0, sigma_m: float = 0.005) -> list[Path]:
    """Write ``fit_knots.csv`` (``knot_spacing_m,mse_m2``) and ``fit_knots.png`` (MSE against
    spacing on log axes, and the first scan of ``seed`` with cubic fits at the smallest,
    the paper's and the largest spacing) into ``run_dir``. Returns the paths written."""
    spacings = sorted({float(s) for s, _ in results})
    shown = sorted({spacings[0], PAPER_ORDER_SPACING_M, spacings[-1]}) if spacings else [PAPER_ORDER_SPACING_M]
    example = fit_example([(3, s) for s in shown], seed=seed, resolution_deg=resolution_deg, sigma_m=sigma_m)
    return _write(results, ("knot_spacing_m", "mse_m2"), Path(run_dir) / "fit_knots", example, "spacing")


def write_fit_order(results: Sequence[tuple[int, float]], run_dir: str | Path, *,
                    spacing_m: float = PAPER_ORDER_SPACING_M, seed: int = 0, resolution_deg: float = 1.0,
                    sigma_m: float = 0.005) -> list[Path]:
    """Write ``fit_order.csv`` (``order,mse_m2``) and ``fit_order.png`` (MSE against order,
    and the first scan of ``seed`` with a fit of each order at ``spacing_m``) into
    ``run_dir``. Returns the paths written."""
    example = fit_example([(int(k) - 1, spacing_m) for k, _ in results], seed=seed,
                          resolution_deg=resolution_deg, sigma_m=sigma_m)
    return _write(results, ("order", "mse_m2"), Path(run_dir) / "fit_order", example, "order")


def _monte_carlo(fits: list[tuple[int, float]], runs: int, seed: int, resolution_deg: float, sigma_m: float,
                 max_range_m: float, progress: Progress | None) -> list[float]:
    """Mean over ``runs`` scans of the range MSE (m²) of each ``(degree, spacing_m)`` fit."""
    if runs < 1:
        raise ConfigError(f"runs must be ≥ 1, got {runs}")
    if not sigma_m >= 0:
        raise ConfigError(f"sigma_m must be ≥ 0, got {sigma_m}")
    bearings = sensor_bearings(resolution_deg)
    true_ranges = wall_range(bearings)
    total = np.zeros(len(fits))
    for done, stream in enumerate(np.random.SeedSequence(seed).spawn(runs), start=1):
        kept, points = _noisy_points(np.random.default_rng(stream), bearings, true_ranges, sigma_m, max_range_m)
        for j, (degree, spacing_m) in enumerate(fits):
            total[j] += _range_mse(fit_curve(points, degree, spacing_m), bearings[kept], true_ranges[kept])
        if progress is not None:
            progress(done, runs)
    return (total / runs).tolist()


def _noisy_points(rng: np.random.Generator, bearings: np.ndarray, true_ranges: np.ndarray, sigma_m: float,
                  max_range_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(kept (n,) bool, points (k, 2)): one noisy scan, beams at or beyond max range dropped."""
    ranges = true_ranges + rng.normal(0.0, sigma_m, true_ranges.shape)
    kept = ranges < max_range_m
    return kept, _polar_points(bearings[kept], ranges[kept])


def _polar_points(bearings: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    return np.column_stack((ranges * np.cos(bearings), ranges * np.sin(bearings)))


def _range_mse(fit: FitResult, bearings: np.ndarray, true_ranges: np.ndarray) -> float:
    """Mean squared difference (m²) between the range to the fitted curve along each beam
    and the true range, over the beams that hit the curve."""
    # The fit parameter of each beam's own point is the natural Newton start for its ray.
    hits = intersect_rays(fit.curve, np.zeros(2), bearings, t0=fit.params)
    if not np.any(hits.hit):
        raise FitError("no beam hits the fitted spline")
    err = hits.range[hits.hit] - true_ranges[hits.hit]
    return float(np.mean(err * err))


def _write(results, header: tuple[str, str], stem: Path, example: FitExample, kind: str) -> list[Path]:
    from bsslam.viz.figures import new_figure, save_figure
    from bsslam.viz.fit_plots import plot_fit_example, plot_mse_vs_order, plot_mse_vs_spacing

    csv_path, png_path = stem.with_suffix(".csv"), stem.with_suffix(".png")
    with atomic_write(csv_path, "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        for x, mse in results:
            writer.writerow([x if kind == "order" else f"{x:g}", f"{mse:.9g}"])
    fig = new_figure(12.0, 4.8)
    ax_mse, ax_example = fig.subplots(1, 2, width_ratios=(1, 1.4))
    xs = [x for x, _ in results]
    ys = [y for _, y in results]
    if kind == "order":
        plot_mse_vs_order(ax_mse, xs, ys)
    else:
        plot_mse_vs_spacing(ax_mse, xs, ys)
    plot_fit_example(ax_example, example.true_points, example.points, example.curves)
    save_figure(fig, [png_path])
    return [csv_path, png_path]
