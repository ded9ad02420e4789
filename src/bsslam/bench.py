"""Accuracy and speed on real logs: several logs, one configuration, the logs run in
parallel through :func:`bsslam.parallel.run_all`.

A benchmark, not a test: it prints figures (``bsslam bench``); nothing asserts on them.
"""

from __future__ import annotations

import math
import resource
import time
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path
from typing import Sequence

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.errors import BsslamError
from bsslam.eval import ate, relations_error
from bsslam.eval.pose_nees import pose_nees
from bsslam.io import open_dataset
from bsslam.io.reader_config import ReaderConfig
from bsslam.io.trajectory_file import read_trajectory
from bsslam.parallel import run_all
from bsslam.perturbed_dataset import PerturbedDataset
from bsslam.pipeline import run_dataset

#: The Intel relations file counts time from the Unix epoch; our Intel logs from the start.
INTEL_RELATIONS_OFFSET_S = 976052857.337

#: The shared references' own uncertainty (m, rad) that the NEES adds: a scan-matched
#: reference is good to a few centimetres and half a degree (``../shared/data/README.md``).
REFERENCE_SIGMA = (0.03, math.radians(0.5))


@dataclass(frozen=True)
class BenchRow:
    """One log's figures (NaN where there is no reference)."""

    log: str
    scans: int
    wall_s: float
    ms_per_scan: float
    splines: int
    state_size: int
    ate_m: float
    online_ate_m: float
    odometry_ate_m: float
    frontend_ate_m: float
    relations: str
    #: peak resident memory of the process that ran the log, by its end (MB); the processes
    #: of a cluster run several logs each, so this is the most any of them had needed
    peak_rss_mb: float
    #: the input as run: "as logged", "noise seed K" or "float32" (see :class:`Perturbation`)
    variant: str = "as logged"
    #: the submap backend's submaps and accepted loop closures (0 with ``backend: ekf``)
    submaps: int = 0
    loop_closures: int = 0
    #: why the run stopped early (the memory budget), or "" when it ran to the end
    stopped: str = ""
    #: the online trajectory's pose NEES against the reference with the reference's own
    #: σ (:data:`REFERENCE_SIGMA`) added, in the first pose's frame (the frame of its
    #: covariances, see :func:`~bsslam.eval.pose_nees.pose_nees`): the share of poses
    #: outside the 95 % χ²(3) region (0.05 if consistent) and the median (2.37 if
    #: consistent); and the share after the ATE's best rigid fit instead. NaN without a
    #: reference
    nees_outside_95: float = float("nan")
    nees_median: float = float("nan")
    nees_outside_95_aligned: float = float("nan")


@dataclass(frozen=True)
class Perturbation:
    """How a bench run alters the log's ranges (:class:`~bsslam.perturbed_dataset.PerturbedDataset`):
    seeded Gaussian noise of ``sigma_m`` (m) or float32 rounding."""

    sigma_m: float = 0.0
    seed: int = 0
    float32: bool = False

    @property
    def label(self) -> str:
        return "float32" if self.float32 else f"noise seed {self.seed}"


def perturbations(runs: int, sigma_m: float = 0.001, first_seed: int = 0) -> list[Perturbation]:
    """The runs of ``bench --perturb N [--first-seed K]``: N seeded noise runs (seeds K …
    K+N−1) and one float32 run."""
    return [Perturbation(sigma_m, seed) for seed in range(first_seed, first_seed + runs)] + [Perturbation(float32=True)]


@dataclass(frozen=True)
class Stability:
    """A log's ATE over its perturbed runs (m): median, least and most, and the float32 run's;
    and how honest the online covariance was over all of them (noise and float32): the
    median over the runs of each run's median pose NEES (2.37 is calibrated, χ²(3)) and of
    its share of poses outside the 95 % region (:attr:`BenchRow.nees_outside_95`)."""

    log: str
    runs: int
    median_m: float
    min_m: float
    max_m: float
    float32_m: float
    nees_median: float = float("nan")
    outside_95: float = float("nan")

    @property
    def spread(self) -> float:
        """(max − min) / median; the target is ≤ 0.2."""
        return (self.max_m - self.min_m) / self.median_m

    @property
    def worst_ratio(self) -> float:
        """The worst run (noise or float32) over the median; the target is ≤ 1.5."""
        return max(self.max_m, self.float32_m) / self.median_m


def stability(rows: Sequence["BenchRow | BenchFailure"]) -> list[Stability]:
    """Per log, the ATE spread over the runs of :func:`perturbations` (logs in first-seen order)."""
    out = []
    for log in dict.fromkeys(r.log for r in rows if isinstance(r, BenchRow)):
        runs = [r for r in rows if isinstance(r, BenchRow) and r.log == log
                and (r.variant.startswith("noise") or r.variant == "float32")]
        noisy = np.array([r.ate_m for r in runs if r.variant.startswith("noise")])
        f32 = [r.ate_m for r in runs if r.variant == "float32"]
        if noisy.size:
            out.append(Stability(log, int(noisy.size), float(np.median(noisy)), float(noisy.min()), float(noisy.max()),
                                 f32[0] if f32 else float("nan"),
                                 float(np.median([r.nees_median for r in runs])),
                                 float(np.median([r.nees_outside_95 for r in runs]))))
    return out


def bench_report(rows: Sequence["BenchRow | BenchFailure"], perturb_sigma_m: float | None = None) -> dict:
    """The figures of a bench as one JSON-ready object: ``runs`` (every
    :class:`BenchRow`'s fields), ``failures`` (log, message) and, with ``perturb_sigma_m``
    (m, the ``--perturb`` noise), ``stability`` (every :class:`Stability`'s fields with its
    ``spread`` and ``worst_ratio``). Units are in the field names (``_m``, ``_s``, ``_mb``);
    a figure that is undefined (NaN: no reference) is ``None``, so that the JSON is valid."""

    def clean(d: dict) -> dict:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}

    report = {"runs": [clean(asdict(r)) for r in rows if isinstance(r, BenchRow)],
              "failures": [asdict(r) for r in rows if isinstance(r, BenchFailure)]}
    if perturb_sigma_m is not None:
        report["perturb_sigma_m"] = perturb_sigma_m
        report["stability"] = [clean({**asdict(st), "spread": st.spread, "worst_ratio": st.worst_ratio})
                               for st in stability(rows)]
    return report


@dataclass(frozen=True)
class BenchFailure:
    """A log that could not be run (unreadable, or rejected by the filter)."""

    log: str
    message: str


def bench_log(log: Path, config: SLAMConfig, steps: int | None = None, progress=None,
              relocalize_progress=None, perturbation: Perturbation | None = None) -> BenchRow:
    """Run one log (its ranges altered by ``perturbation``, if given) and score it against
    ``<log>.gt.txt`` (and ``intel.relations`` for Intel)."""
    data = open_dataset(log, reader_config=ReaderConfig(limits=config.input))
    if perturbation is not None:
        data = PerturbedDataset(data, perturbation.sigma_m, perturbation.seed, perturbation.float32)
    t0 = time.perf_counter()
    quiet = lambda done, total: None  # noqa: E731
    result = run_dataset(data, config, steps=steps, progress=progress or quiet, point_stride=0,
                         relocalize_progress=relocalize_progress or quiet)
    wall = time.perf_counter() - t0
    ref_path = log.with_suffix(".gt.txt")
    nan = float("nan")
    ate_m = online_m = odo_m = fe_m = outside = median = outside_aligned = nan
    if ref_path.exists():
        ref = read_trajectory(ref_path)
        ate_m = ate(result.trajectory, ref)[0]
        online_m = ate(result.estimate, ref)[0]
        if result.estimate.covariances is not None and len(result.estimate) > 1:
            sigmas = dict(reference_sigma_xy_m=REFERENCE_SIGMA[0], reference_sigma_phi_rad=REFERENCE_SIGMA[1])
            report = pose_nees(result.estimate, ref, result.estimate.covariances, **sigmas)
            outside, median = report.fraction_outside_95, report.median
            outside_aligned = pose_nees(result.estimate, ref, result.estimate.covariances, frame="aligned",
                                        **sigmas).fraction_outside_95
        odo_m = ate(result.odometry, ref)[0]
        if result.frontend is not None:
            fe_m = ate(result.frontend, ref)[0]
    rel = "-"
    rel_path = log.parent / "intel.relations"
    if log.name.startswith("intel") and rel_path.exists():
        r = relations_error(result.trajectory, rel_path, offset=INTEL_RELATIONS_OFFSET_S)
        if r.used:
            rel = f"{r.trans_mean_m:.3f}±{r.trans_std_m:.3f} m, {r.rot_mean_deg:.2f}±{r.rot_std_deg:.2f}° ({r.used})"
    return BenchRow(log.name, result.steps, wall, 1000.0 * result.wall_time_s / max(result.steps, 1),
                    len(result.map), int(result.state_sizes.max()) if result.steps else 3, ate_m, online_m, odo_m, fe_m, rel,
                    resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                    perturbation.label if perturbation is not None else "as logged",
                    result.totals.get("submaps", 0), result.totals.get("loop_closures", 0),
                    result.stop_reason or ("interrupted" if result.interrupted else ""), outside, median,
                    outside_aligned)


def _bench_or_failure(job: tuple[Path, Perturbation | None], config: SLAMConfig,
                      steps: int | None) -> BenchRow | BenchFailure:
    log, perturbation = job
    name = log.name if perturbation is None else f"{log.name} ({perturbation.label})"
    try:
        return bench_log(log, config, steps=steps, perturbation=perturbation)
    except BsslamError as exc:  # one bad log must not cost the others' figures
        return BenchFailure(name, str(exc))
    except Exception as exc:  # nor one bug: it is reported (red, by type) with the figures of the rest
        first = (str(exc).strip().splitlines() or [""])[0]
        return BenchFailure(name, f"{type(exc).__name__}: {first}")


def bench_logs(logs: Sequence[Path], config: SLAMConfig, steps: int | None = None, *,
               workers: int | None = None, scheduler: str | None = None, progress=None,
               perturb: Sequence[Perturbation] = ()) -> list[BenchRow | BenchFailure]:
    """:func:`bench_log` for every log — once as logged, or once per ``perturb`` entry —
    the runs spread over ``workers``/``scheduler`` as :func:`bsslam.parallel.run_all` does (a
    local cluster over every core by default); ``progress(done_runs, total)``. Results in
    the order of ``logs``, each log's runs in the order of ``perturb``."""
    fn = partial(_bench_or_failure, config=config, steps=steps)
    jobs = [(Path(log), p) for log in logs for p in (perturb or [None])]
    return run_all(fn, jobs, workers=workers, scheduler=scheduler, progress=progress)
