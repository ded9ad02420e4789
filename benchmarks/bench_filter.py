"""Time per scan against state size, single-threaded, from a simulated run that grows the map
past 1000 state dimensions; then where the time of a scan goes at about 1000 dimensions.

    python benchmarks/bench_filter.py [--world NAME] [--steps N] [--repeats R] [--profile] [--defaults]
                                      [--estimator ekf|oc-ekf|invariant]

The default world is a 30 × 20 m corridor loop (3 m wide, rounded corners) driven twice:
about 175 m of walls, so with knot spacing ρ = 0.2 m and no extension (the map grows by new
splines) the state passes 1000 dimensions during the first lap. Built-in worlds can be
chosen with ``--world`` (they are smaller; ``mixed`` stops near 800).

``--defaults`` runs the library's default spline and mapping configuration instead (ρ = 1 m,
extension on) in an 80 × 50 m corridor loop driven once (1200 scans), which passes 1000
dimensions after about 400 scans: fewer, longer splines than at ρ = 0.2 m.

Runs of the same seeded data: the first times whole scans (medians per state-size bin), and
``--repeats`` − 1 more repeat it, so that each scan's least time over the repeats is given
as well (the least time filters out what the machine's other work added); the last run
times the filter's stages with light wrappers around its methods and reports them for the
scans whose state size is within ``--around`` ± 10 %. ``--profile`` adds a cProfile
listing of those scans.

The speed of a shared machine drifts (here by up to 1.6× within minutes), so the first run is
bracketed by a reference timed in the same process: the textbook EKF's covariance update at
1000 state dimensions, P ← P − Z Zᵀ on a dense P with Z = P[:, cols] W of rank 55 (the
rank of a typical scan's update here). Each bin's median is also given as a multiple of it,
which says what the scan costs against the textbook filter's own update. It follows the
machine's drift only in part: at the defaults the multiple went from 0.61 to 0.82 while the
median went from 3.1 to 5.1 ms, and between runs of one phase it varies as much as the
milliseconds do.
"""

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import cProfile  # noqa: E402
import functools  # noqa: E402
import pstats  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

import bsslam.slam.ekf as ekf_module  # noqa: E402
import bsslam.slam.estimator as estimator_module  # noqa: E402
from bsslam.config import MappingConfig, SLAMConfig, SplineConfig  # noqa: E402
from bsslam.experiments.consistency import simulation_config  # noqa: E402
from bsslam.se2 import between as relative  # noqa: E402
from bsslam.sim import SimConfig, get_world, simulate  # noqa: E402
from bsslam.sim.worlds import large_corridor  # noqa: E402
from bsslam.slam import SplineSLAM  # noqa: E402
from bsslam.slam.measurement import RangeModel  # noqa: E402
from bsslam.slam.state import JointState, _subtract_outer  # noqa: E402

BINS = [0, 250, 500, 750, 1000, 1250, 1500, 2000, 3000, 10**9]
# Stages in the order of a scan; each is the time spent in the listed callables, less the time
# of other listed callables they call (so the stages do not overlap). "other" is the rest of
# step() (beam grouping, row selection, bookkeeping).
# - "covariance reads" are the reads of P through the state's deferred update (base − B G Bᵀ, B K):
#   the blocks the gains, gates and association read, and P[:, cols]·v, the mean correction of
#   the whole state. They grow with the state (n rows) and with the deferred term's width.
# - "S/gain" is the rest of the gains: S = H P Hᵀ + R, its factorisation and the solves.
# - "covariance update" is the deferred low-rank update and, every few dozen scans, the O(n²) fold of
#   the deferred term into P (JointState), so its mean, not its median, is its cost per scan. A
#   fold counts here wherever it happens: in an update, or when a new spline finds the state's
#   exact block full (inside "enlarge" otherwise).
STAGES = {
    "predict": [(estimator_module.CompressedEKF, "predict")],
    "segment+fit": [(SplineSLAM, "_observe")],
    "associate": [(SplineSLAM, "_associate")],
    "linearise": [(RangeModel, "linearize")],
    "covariance reads": [(JointState, "block"), (JointState, "diagonal"), (JointState, "rows"),
                         (JointState, "columns_times")],
    "S/gain": [(ekf_module.StackedGain, "__init__"), (ekf_module.StackedGain, "correction"),
               (ekf_module.StackedGain, "state_correction"), (ekf_module.StackedGain, "pose_variances"),
               (ekf_module.StackedGain, "posterior_variances"), (ekf_module, "innovation_variances")],
    "covariance update": [(ekf_module.StackedGain, "update_covariance"), (JointState, "fold")],
    "enlarge": [(SplineSLAM, "_enlarge")],
}


def reference_update_ms(n: int = 1000, rank: int = 55, repeats: int = 15) -> float:
    """Median ms of the textbook EKF covariance update on a dense (n, n) P: P ← P − Z Zᵀ with
    Z = P[:, cols] W for ``rank`` columns, written exactly symmetric as the filter's fold
    writes it (:func:`bsslam.slam.state._subtract_outer`)."""
    rng = np.random.default_rng(0)
    A = rng.standard_normal((n, n)) / np.sqrt(n)
    P = A @ A.T + np.eye(n)
    cols = np.sort(rng.choice(n, rank, replace=False))
    W = 1e-3 * rng.standard_normal((rank, rank))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        _subtract_outer(P, P[:, cols] @ W)
        times.append(time.perf_counter() - t0)
    return 1000 * float(np.median(times))


def run(frames, config, stage_times=None, profile_window=None):
    """Run the filter over ``frames``; (state sizes (N,), ms per scan (N,)). With
    ``stage_times`` (dict stage -> list), append each scan's ms per stage."""
    slam = SplineSLAM(config, initial_pose=frames[0].odometry)
    clock = _StageClock() if stage_times is not None else None
    prof = cProfile.Profile() if profile_window is not None else None
    sizes, times = [], []
    prev = frames[0].odometry
    try:
        if clock:
            clock.install()
        for fr in frames:
            delta = relative(prev, fr.odometry)
            prev = fr.odometry
            profiling = prof is not None and profile_window[0] <= slam.state_size < profile_window[1]
            if clock:
                clock.reset()
            if profiling:
                prof.enable()
            t0 = time.perf_counter()
            slam.step(delta, fr.scan)
            elapsed = time.perf_counter() - t0
            if profiling:
                prof.disable()
            times.append(elapsed * 1000)
            sizes.append(slam.state_size)
            if clock:
                for name, t in clock.totals(elapsed).items():
                    stage_times.setdefault(name, []).append(t * 1000)
    finally:
        if clock:
            clock.uninstall()
    return np.array(sizes), np.array(times), prof


class _StageClock:
    """Wraps the callables of STAGES with timers (~1 µs each call). A timed callable called
    from another counts for its own stage only: the caller's stage is charged its exclusive
    time."""

    def __init__(self):
        self.acc = dict.fromkeys(STAGES, 0.0)
        self._saved = []
        self._inner = []   # per active timed call: time spent in timed calls nested in it

    def install(self):
        for stage, targets in STAGES.items():
            for owner, name in targets:
                if owner is None:
                    continue
                original = getattr(owner, name)
                setattr(owner, name, self._wrap(original, stage))
                self._saved.append((owner, name, original))

    def uninstall(self):
        for owner, name, original in reversed(self._saved):
            setattr(owner, name, original)
        self._saved.clear()

    def _wrap(self, fn, stage):
        acc, inner = self.acc, self._inner

        @functools.wraps(fn)
        def timed(*args, **kwargs):
            inner.append(0.0)
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                elapsed = time.perf_counter() - t0
                acc[stage] += elapsed - inner.pop()
                if inner:
                    inner[-1] += elapsed
        return timed

    def reset(self):
        for k in self.acc:
            self.acc[k] = 0.0

    def totals(self, step_time):
        out = dict(self.acc)
        out["other"] = step_time - sum(self.acc.values())
        out["total"] = step_time
        return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--world", default="large-corridor", help="large-corridor (default) or a built-in world")
    ap.add_argument("--steps", type=int, default=None, help="scans (default: the whole double loop)")
    ap.add_argument("--around", type=float, default=1000.0, help="state size of the stage table")
    ap.add_argument("--profile", action="store_true", help="also cProfile the scans of the stage table")
    ap.add_argument("--repeats", type=int, default=3,
                    help="timing runs; each scan's least time over them is reported too (default 3)")
    ap.add_argument("--defaults", action="store_true",
                    help="default spline and mapping configuration in an 80 × 50 m corridor loop")
    ap.add_argument("--estimator", default=None, choices=("ekf", "oc-ekf", "invariant"),
                    help="the joint Gaussian's filter (default: the library's with --defaults, "
                         "else the paper's EKF)")
    args = ap.parse_args()
    sim = SimConfig()
    if args.defaults:
        base, world, steps = SLAMConfig(), large_corridor(80.0, 50.0), args.steps or 1200
    else:
        # no extension: the map grows by new splines, which is what drives the state past 1000
        base = SLAMConfig(spline=SplineConfig(degree=3, knot_spacing_m=0.2, min_knot_spacing_m=0.2),
                          mapping=MappingConfig(extend=False))
        world = large_corridor() if args.world == "large-corridor" else get_world(args.world)
        steps = args.steps
    estimator = args.estimator or (base.estimator if args.defaults else "ekf")
    config = simulation_config(base.replace(estimator=estimator), sim)
    frames = list(simulate(world, sim, seed=0, steps=steps))

    before = reference_update_ms()
    sizes, times, _ = run(frames, config)
    reference = 0.5 * (before + reference_update_ms())
    # Each scan's least time over the repeats: the run is deterministic (same scans, same
    # folds), so what the repeats differ by is the machine's interference, not the work.
    least = times.copy()
    for _ in range(args.repeats - 1):
        sizes_again, times_again, _ = run(frames, config)
        assert np.array_equal(sizes_again, sizes), "the filter is deterministic"
        np.minimum(least, times_again, out=least)
    print(f"world {world.name}, estimator {estimator}: {len(frames)} scans, final state size {sizes[-1]}")
    print(f"reference: the textbook covariance update at n = 1000 (dense, rank 55) took {reference:.2f} ms "
          f"(median of 15 before the first run and 15 after it: {before:.2f} ms before)")
    print(f"{'state size':>14} {'scans':>6} {'median ms/scan':>15} {'p90 ms/scan':>12} {'median/reference':>17} "
          f"{'least of ' + str(args.repeats) + ': median':>21} {'mean':>7}")
    for lo, hi in zip(BINS[:-1], BINS[1:]):
        sel = (sizes >= lo) & (sizes < hi)
        if sel.sum() >= 3:
            print(f"{lo:>6}–{min(hi, sizes.max()):<7} {sel.sum():>6} {np.median(times[sel]):>15.2f} "
                  f"{np.percentile(times[sel], 90):>12.2f} {np.median(times[sel]) / reference:>17.2f} "
                  f"{np.median(least[sel]):>21.2f} {least[sel].mean():>7.2f}")

    window = (0.9 * args.around, 1.1 * args.around)
    stage_times: dict[str, list[float]] = {}
    sizes2, _, prof = run(frames, config, stage_times, window if args.profile else None)
    sel = (sizes2 >= window[0]) & (sizes2 < window[1])
    if not sel.any():
        print(f"\nno scan with state size in [{window[0]:.0f}, {window[1]:.0f})")
        return
    total = np.array(stage_times["total"])[sel]
    print(f"\nstages of the {sel.sum()} scans with state size in [{window[0]:.0f}, {window[1]:.0f}) "
          f"(ms per scan; the medians need not add up):")
    print(f"{'stage':>18} {'median':>8} {'mean':>8} {'share':>7}")
    for name in [*STAGES, "other", "total"]:
        t = np.array(stage_times[name])[sel]
        print(f"{name:>18} {np.median(t):>8.2f} {t.mean():>8.2f} {100 * t.mean() / total.mean():>6.1f}%")
    if prof is not None:
        print("\ncProfile of those scans:")
        pstats.Stats(prof).sort_stats("cumulative").print_stats(25)


if __name__ == "__main__":
    main()
