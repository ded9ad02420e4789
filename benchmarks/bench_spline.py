"""Ray–spline intersection throughput (not a test: prints figures, asserts nothing).

A 20-control-point cubic wall (17 spans, about 20 m long, knot spacing ~1.2 m) is hit by
fans of rays from sensor poses in front of it, as the filter's observation model does for
each scan. Reported: rays per second, median of repeated runs, single-threaded, for

- ``global``: no guesses (convex-hull culling, bracketing, refinement), and
- ``t0``: Newton from guesses 2 cm (of arc length) off the true hit parameters.

Run:  python benchmarks/bench_spline.py [--repeat 15]
"""

from __future__ import annotations

import os

# Single-threaded BLAS, before numpy is imported: the figure must not depend on cores.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from bsslam.spline import BSplineCurve, chord_length_parameters, fit_curve, intersect_rays  # noqa: E402


def wall() -> BSplineCurve:
    """A wavy 20 m wall as a cubic with exactly 20 control points (17 spans)."""
    x = np.linspace(-10.0, 10.0, 2000)
    pts = np.column_stack([x, 4.0 + 0.6 * np.sin(0.5 * x) + 0.2 * np.cos(1.7 * x)])
    length = chord_length_parameters(pts)[-1]
    curve = fit_curve(pts, 3, length / 17.0).curve
    assert curve.n_control == 20, curve.n_control
    return curve


def fans(n_rays: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) origins and (n,) world angles: 361-beam 180° scans from random poses."""
    n_scans = -(-n_rays // 361)
    xy = np.column_stack([rng.uniform(-6, 6, n_scans), rng.uniform(-2, 1, n_scans)])
    heading = np.pi / 2 + rng.uniform(-0.5, 0.5, n_scans)
    bearings = np.linspace(-np.pi / 2, np.pi / 2, 361)
    origins = np.repeat(xy, 361, axis=0)[:n_rays]
    angles = (heading[:, None] + bearings[None, :]).ravel()[:n_rays]
    return origins, angles


def rays_per_second(call, n_rays: int, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return n_rays / statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15, help="timed runs per figure (median)")
    args = parser.parse_args()
    curve = wall()
    rng = np.random.default_rng(0)
    print(f"cubic, {curve.n_control} control points, domain {curve.domain[1]:.2f} m; "
          f"median of {args.repeat} runs, single-threaded")
    print(f"{'rays/call':>10} {'hit %':>6} {'global rays/s':>14} {'t0 rays/s':>12}")
    for n_rays in (361, 3610, 36100):
        origins, angles = fans(n_rays, rng)
        reference = intersect_rays(curve, origins, angles)
        guess = reference.t + rng.choice([-0.02, 0.02], n_rays)  # NaN stays NaN: no guess
        intersect_rays(curve, origins, angles, t0=guess)  # warm-up (and the pieces cache)
        global_rate = rays_per_second(lambda: intersect_rays(curve, origins, angles), n_rays, args.repeat)
        t0_rate = rays_per_second(lambda: intersect_rays(curve, origins, angles, t0=guess), n_rays, args.repeat)
        print(f"{n_rays:>10} {100 * reference.hit.mean():>6.1f} {global_rate:>14,.0f} {t0_rate:>12,.0f}")


if __name__ == "__main__":
    main()
