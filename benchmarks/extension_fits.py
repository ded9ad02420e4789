"""Why the filter's map splines are seldom extended: every extension a run tries, and how
far the extended curve passes from the new points.

    python benchmarks/extension_fits.py LOG [--seed N] [--config X.yaml] [--plot PNG]

A benchmark, not a test (prints figures, asserts nothing). LOG runs once (the default
configuration or ``--config``'s; ``--seed`` moves every range by 1 mm of seeded noise, as
``bsslam bench --perturb``). Every time the filter tries to extend a map spline past one of
its ends (paper §III-F, :meth:`bsslam.slam.SplineSLAM._extend_feature`: the new points'
stretch beyond the matched interval, continued with C² continuity) this records the new
points' distances to the extended curve, as the fit check sees them
(``mapping.max_extension_rms_m`` and ``extension_fit_probability``), and whether it was
kept. It prints how many were tried (every call; some end before the fit, with too few
points past the end or no well-posed fit), how many reached the fit check and how many
were kept; the RMS distance (cm) at the 10th, 50th and 90th percentiles; the median number
of new points; the median RMS over the half of the points nearer the old end (along its
tangent) and over the farther half (an old end that points the wrong way errs near it
already); and the median range of the old end from the robot (m).

With ``--plot`` the first twelve attempts are drawn in the frame of the old end (its
tangent along x, m; the offset along its normal in cm, so that centimetres show): the map
spline, the observed segment's points, those past the end, and the extended curve.

What the shared logs gave is in docs/real_logs.md ("Why the halls' walls stay short").
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.io import open_dataset
from bsslam.io.config_file import load_config
from bsslam.perturbed_dataset import PerturbedDataset
from bsslam.pipeline import run_dataset
from bsslam.slam import filter as filter_module
from bsslam.slam.enlarge import beam_points
from bsslam.spline import BSplineCurve


@dataclass
class Attempt:
    """One extension the filter tried (world frame of its filter, m)."""

    curve: BSplineCurve          # the map spline before it
    side: str                    # 'left' or 'right'
    segment: np.ndarray          # (k, 2) the observed segment's points
    beyond: np.ndarray           # (j, 2) the points past the end it was fitted to (none if it ended before)
    extended: BSplineCurve | None
    distances: np.ndarray        # (j,) the points' distances to the extended curve
    robot: np.ndarray            # (3,) the corrected pose
    kept: bool = False


def record_attempts(log: Path, seed: int | None, config: SLAMConfig) -> list[Attempt]:
    """Run ``log`` once and return every extension attempt. The filter's extension, the
    fit it calls (``extend_curve``, in the filter's module) and its fit check are wrapped
    to record what they were given and gave; nothing is computed again here but the
    segment's points for the pictures."""
    attempts: list[Attempt] = []
    extend, fits = filter_module.SplineSLAM._extend_feature, filter_module.SplineSLAM._extension_fits
    fit = filter_module.extend_curve

    def recording_extend(slam, feature, obs, side, sel, offset):
        segment = beam_points(slam.state.pose, offset, obs.angles, obs.ranges).points
        attempt = Attempt(feature.curve(slam.state.x), side, segment, np.zeros((0, 2)), None, np.zeros(0),
                          slam.state.pose.copy())
        attempts.append(attempt)
        attempt.kept = extend(slam, feature, obs, side, sel, offset)
        return attempt.kept

    def recording_fit(curve, side, points, *args, **kwargs):
        attempts[-1].beyond = np.array(points, dtype=float)
        extension = fit(curve, side, points, *args, **kwargs)
        attempts[-1].extended = extension.curve
        return extension

    def recording_fits(slam, distances, new_control_points):
        attempts[-1].distances = np.asarray(distances, dtype=float).copy()
        return fits(slam, distances, new_control_points)

    filter_module.SplineSLAM._extend_feature = recording_extend
    filter_module.SplineSLAM._extension_fits = recording_fits
    filter_module.extend_curve = recording_fit
    try:
        data = open_dataset(log)
        run_dataset(data if seed is None else PerturbedDataset(data, 0.001, seed), config, point_stride=0)
    finally:
        filter_module.SplineSLAM._extend_feature = extend
        filter_module.SplineSLAM._extension_fits = fits
        filter_module.extend_curve = fit
    return attempts


def _end_frame(attempt: Attempt) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The old end (2,), its outward tangent (2,) and normal (2,)."""
    lo, hi = attempt.curve.domain
    right = attempt.side == "right"
    u, inside = (hi, hi - 1e-3) if right else (lo, lo + 1e-3)
    end, before = attempt.curve.evaluate(np.array([u, inside]))
    tangent = (end - before) / np.linalg.norm(end - before)
    return end, tangent, np.array([-tangent[1], tangent[0]])


def _halves(attempt: Attempt) -> tuple[np.ndarray, np.ndarray]:
    """The attempt's distances (m) of the half of its new points nearer the old end (along
    the end's tangent) and of the farther half."""
    end, tangent, _ = _end_frame(attempt)
    d = attempt.distances[np.argsort((attempt.beyond - end) @ tangent, kind="stable")]
    return d[: d.size // 2], d[d.size // 2:]


def summary(name: str, attempts: list[Attempt]) -> str:
    """One line of figures over ``attempts`` (those that reached the fit check)."""
    checked = [a for a in attempts if a.distances.size]
    if not checked:
        return f"{name}: {len(attempts)} extensions tried, none reached the fit check"
    rms = np.array([np.sqrt(np.mean(a.distances ** 2)) for a in checked]) * 100
    half = [_halves(a) for a in checked]
    near = np.median([np.sqrt(np.mean(h[0] ** 2)) for h in half if h[0].size]) * 100
    far = np.median([np.sqrt(np.mean(h[1] ** 2)) for h in half]) * 100
    ranges = [np.linalg.norm(_end_frame(a)[0] - a.robot[:2]) for a in checked]
    q10, q50, q90 = np.percentile(rms, [10, 50, 90])
    return (f"{name}: {len(attempts)} extensions tried, {len(checked)} reached the fit check, "
            f"{sum(a.kept for a in attempts)} kept; "
            f"RMS distance of the new points to the extended curve {q10:.1f} / {q50:.1f} / {q90:.1f} cm "
            f"(10th / 50th / 90th percentile) over a median of {np.median([a.distances.size for a in checked]):.0f} "
            f"points; nearer half {near:.1f} cm, farther half {far:.1f} cm; old end {np.median(ranges):.1f} m "
            "from the robot (medians)")


def plot(attempts: list[Attempt], path: Path) -> None:
    """The first twelve ``attempts`` in the frame of each old end, into the PNG ``path``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = attempts[:12]
    fig, axes = plt.subplots(3, 4, figsize=(16, 10), squeeze=False)
    for ax, attempt in zip(axes.flat, shown):
        end, tangent, normal = _end_frame(attempt)

        def local(points):
            d = np.atleast_2d(points) - end
            return d @ tangent, 100 * (d @ normal)

        lo, hi = attempt.curve.domain
        ax.plot(*local(attempt.curve.evaluate(np.linspace(lo, hi, 300))), "k-", lw=2, label="map spline")
        ax.plot(*local(attempt.segment), ".", color="tab:blue", ms=5, label="observed segment")
        ax.plot(*local(attempt.beyond), "o", mfc="none", mec="tab:red", ms=8, label="past the end")
        if attempt.extended is not None:
            a, b = attempt.extended.domain
            ax.plot(*local(attempt.extended.evaluate(np.linspace(a, b, 300))), "-", color="tab:green", lw=1,
                    label="extended curve")
        rms = 100 * np.sqrt(np.mean(attempt.distances ** 2)) if attempt.distances.size else np.nan
        rng = np.linalg.norm(end - attempt.robot[:2])
        ax.set_title(f"{'kept' if attempt.kept else 'refused'}: RMS {rms:.1f} cm, {rng:.1f} m away", fontsize=9)
        ax.set_xlim(-3, 3)
        ax.set_ylim(-20, 20)
        ax.axvline(0, color="0.7", lw=0.5)
        ax.set_xlabel("along the old end's tangent (m)", fontsize=8)
        ax.set_ylabel("along its normal (cm)", fontsize=8)
    for ax in list(axes.flat)[len(shown):]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=70)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path, help="a log bsslam reads (CARMEN or a ROS bag)")
    parser.add_argument("--seed", type=int, default=None, help="1 mm of range noise with this seed")
    parser.add_argument("--config", type=Path, default=None, help="a YAML configuration (default: the defaults)")
    parser.add_argument("--plot", type=Path, default=None, help="draw the first twelve attempts into this PNG")
    args = parser.parse_args()
    config = load_config(args.config) if args.config else SLAMConfig()
    attempts = record_attempts(args.log, args.seed, config)
    print(summary(args.log.name + ("" if args.seed is None else f" (seed {args.seed})"), attempts))
    if args.plot:
        plot(attempts, args.plot)


if __name__ == "__main__":
    main()
