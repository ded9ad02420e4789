"""BS-SLAM in submaps: the paper's filter inside local maps of bounded size, tied together
by a pose graph with loop closures between them (``backend: submaps``).

The paper's single EKF keeps every spline ever seen in one joint covariance: its memory
grows with the square of the map and its time per scan with the map, and once the drift
around a large loop exceeds what the association gates accept the old walls are mapped
again beside themselves. Here:

- **Local filter.** :class:`~bsslam.slam.SplineSLAM` runs in the current submap's own
  frame, starting at the robot's pose with zero covariance. The submap is *full* when its
  state reaches ``submaps.max_state_size`` or the robot has travelled
  ``submaps.max_distance_m`` in it.
- **Freezing.** A full submap keeps only its splines with their covariance blocks (its own
  frame), the points sampled on them for matching, and the robot's final pose in it with
  its covariance: the odometry-like constraint to the next submap, which starts at that
  pose from the same scan (its splines seed the new map).
- **Global layer.** The submaps' base poses are the nodes of a
  :class:`~bsslam.submaps.pose_graph.PoseGraph` (GTSAM iSAM2).
- **Loop closure.** A newly frozen submap is matched against the old submaps whose area it
  may overlap given the graph's uncertainty (:func:`~bsslam.submaps.loop_closure.match_submaps`:
  a wide correlative search on the old submap's spline points, then verification). A
  verified match goes into the graph (with ``submaps.loop_support_submaps`` > 0 a
  surprising one first waits for a neighbouring match that agrees with it around the cycle
  they close, :mod:`~bsslam.submaps.loop_support`), which sets aside (graduated non-convexity, by default) or
  down-weights (a Cauchy kernel, ``submaps.loop_outliers: cauchy``) the ones the rest
  of the graph contradicts (see :mod:`~bsslam.submaps.pose_graph`).
- **One map out.** Each submap's splines in its optimised frame; splines that lie on one
  another in two submaps are marked as one surface (:func:`mark_surfaces`).

Live memory is the current submap's covariance (8 n² bytes, n ≤ ``max_state_size`` plus
one scan's growth) plus the frozen submaps' compact arrays; :attr:`SubmapSLAM.nbytes`
counts them and a run past ``max_memory_mb`` stops with :class:`MemoryBudgetError`.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from bsslam.config import SLAMConfig, SubmapConfig
from bsslam.errors import MemoryBudgetError
from bsslam.scan import LaserScan
from bsslam.se2 import compose, compose_with_covariance
from bsslam.slam import MapSpline, SplineSLAM
from bsslam.slam.features import SplineFeature
from bsslam.slam.filter import StepReport
from bsslam.spline import BSplineCurve
from bsslam.submaps.loop_closure import LoopMatch, SubmapShape, match_submaps
from bsslam.submaps.loop_support import LoopEdge, votes
from bsslam.submaps.pose_graph import PoseGraph

#: Threads matching the end-of-run sweep's pairs (at most the machine's cores).
_SWEEP_THREADS = 4

#: Prior σ on the first base pose when the configuration gives none: the map frame is
#: defined by it, but the optimiser needs a proper (invertible) prior.
_ANCHOR_SIGMA = 1e-6


@dataclass(frozen=True)
class FrozenSubmap:
    """A full submap: all the global layer keeps of it.

    Attributes:
        index: its node in the pose graph.
        splines: its splines in its own frame, each with its covariance block (m²).
        shape: the points sampled on them, for loop-closure matching.
        end_pose: (3,) the robot's pose at the freeze in the submap's frame (the next
            submap's base), and ``end_covariance`` (3, 3) its covariance: the local
            filter's plus the drift it does not know of (:func:`seam_covariance`).
        filter_steps: scans the filter processed in it.
    """

    index: int
    splines: list[MapSpline]
    shape: SubmapShape
    end_pose: np.ndarray
    end_covariance: np.ndarray
    filter_steps: int

    @property
    def nbytes(self) -> int:
        """Bytes of its arrays (splines, covariance blocks, matching points)."""
        n = sum(s.curve.control_points.nbytes + s.curve.knots.nbytes + s.covariance.nbytes for s in self.splines)
        return int(n + self.shape.points.nbytes + self.shape.normals.nbytes)


@dataclass(frozen=True)
class LoopRecord:
    """One loop-closure attempt that was accepted into the graph.

    Attributes:
        reference, query: the submaps (graph nodes); ``relative`` (3,) is the query's base
            in the reference's frame, ``covariance`` (3, 3) its covariance.
        inlier_fraction, overlap_m: the match's verification figures.
        loop_id: the factor's id in the graph (its weight in the solution: ``PoseGraph.loop_weights``);
            −1 while the match waits for support, not yet in the graph.
        rival: (3,) the runner-up alignment the match's covariance does not admit, or None
            (see :class:`~bsslam.submaps.loop_support.LoopEdge`).
        slide: the match was kept as a slide along walls (``submaps.loop_slides``): its
            runner-up is the same answer, and ``rival`` the best alignment beyond the slide.
    """

    reference: int
    query: int
    relative: np.ndarray
    covariance: np.ndarray
    inlier_fraction: float
    overlap_m: float
    loop_id: int = -1
    rival: np.ndarray | None = None
    slide: bool = False


@dataclass
class SubmapStats:
    """Counters of the global layer (added to a run's totals): ``loop_closures`` counts
    the end-of-run sweep's (``sweep_closures``) too; ``loop_candidates`` and
    ``loop_rejections`` are the frozen submaps' matching's; ``online_candidates`` and
    ``online_matches`` the growing submap's (``submaps.online_match_m``), which condition
    the current base and never enter the graph."""

    submaps: int = 1
    loop_candidates: int = 0
    loop_closures: int = 0
    sweep_candidates: int = 0
    sweep_closures: int = 0
    online_candidates: int = 0
    online_matches: int = 0
    loop_rejections: dict[str, int] = field(default_factory=dict)

    def reject(self, reason: str, count: int = 1) -> None:
        """Count ``count`` loop-closure candidates rejected for ``reason``."""
        self.loop_rejections[reason] = self.loop_rejections.get(reason, 0) + count


class SubmapSLAM:
    """BS-SLAM in local submaps with a pose graph over them; the interface the mapper uses
    of :class:`~bsslam.slam.SplineSLAM` (``step``, ``pose``, ``pose_covariance``,
    ``state_size``, ``map``, ``curves``), in the global frame.

    >>> slam = SubmapSLAM(SLAMConfig())
    >>> report = slam.step(None, scan)            # doctest: +SKIP
    >>> slam.pose, slam.pose_covariance, slam.map  # doctest: +SKIP

    Args:
        config: the filter's configuration and ``config.submaps``.
        initial_pose: (3,) the first base pose in the map frame (x m, y m, φ rad).
        initial_covariance: (3, 3) its covariance; from ``config.initial_pose_sigma`` by default.
    """

    def __init__(self, config: SLAMConfig | None = None, initial_pose=(0.0, 0.0, 0.0),
                 initial_covariance: np.ndarray | None = None) -> None:
        self.config = config or SLAMConfig()
        if initial_covariance is None:
            initial_covariance = np.diag(np.square(self.config.initial_pose_sigma))
        anchor = np.asarray(initial_covariance, dtype=float) + np.eye(3) * _ANCHOR_SIGMA ** 2
        cfg = self.config.submaps
        self.graph = PoseGraph(np.asarray(initial_pose, dtype=float), anchor, loop_outliers=cfg.loop_outliers,
                               robust_kernel_width=cfg.robust_kernel_width,
                               loop_inlier_probability=cfg.loop_inlier_probability,
                               drift_rate_sigma=cfg.drift_rate_sigma_rad_per_m)
        self.graph.optimize()
        self.frozen: list[FrozenSubmap] = []
        self._frozen_bytes = 0
        self.loops: list[LoopRecord] = []
        # verified matches waiting to enter the graph: (record, window_m, surprising)
        self._pending: list[tuple[LoopRecord, float, bool]] = []
        self.stats = SubmapStats()
        self._max_bytes = int(self.config.max_memory_mb * 2 ** 20)
        self._bases = self.graph.poses()               # (k, 3) optimised base poses
        self._base_cov = self.graph.covariance(0)      # the current base's marginal
        self._local = self._new_local()     # with the current submap's distance and matches
        self.step_submap = 0     # the submap the last step's scan was localised in
        self.steps = 0

    # -- views --------------------------------------------------------------------------
    @property
    def submap_index(self) -> int:
        """The current submap (graph node of its base)."""
        return len(self.frozen)

    @property
    def local(self) -> SplineSLAM:
        """The current submap's filter (its own frame)."""
        return self._local

    @property
    def base(self) -> np.ndarray:
        """(3,) the current submap's base pose in the map frame, as last optimised."""
        return self._bases[self.submap_index].copy()

    @property
    def pose(self) -> np.ndarray:
        """(3,) the robot's pose in the map frame."""
        return compose(self._bases[self.submap_index], self._local.pose)

    @property
    def pose_covariance(self) -> np.ndarray:
        """(3, 3) its covariance: the base's marginal (optimiser) composed with the local one."""
        return compose_with_covariance(self._bases[self.submap_index], self._base_cov,
                                       self._local.pose, self._local.pose_covariance)[1]

    @property
    def state_size(self) -> int:
        """The local filter's state dimension."""
        return self._local.state_size

    @property
    def nbytes(self) -> int:
        """Bytes of the live estimator arrays: the local filter's covariance storage and
        the frozen submaps' arrays (the pose graph's few hundred nodes are negligible)."""
        # the frozen submaps' bytes are summed as they freeze: this runs every scan, and a
        # sum over every frozen spline would grow with the building
        return self._local.state.nbytes + self._frozen_bytes

    @property
    def map(self) -> list[MapSpline]:
        """Every submap's splines in its optimised frame (map frame), covariance blocks
        rotated with them; splines of two submaps lying on one another share a ``surface``."""
        return mark_surfaces(self._global_splines(), SURFACE_SPACING_M)

    @property
    def curves(self) -> list[BSplineCurve]:
        """The map's curves (map frame, m), without covariances; leaves the filter untouched."""
        curves = []
        for f in self.frozen:
            b = self._bases[f.index]
            curves += [s.curve.transformed(b[2], b[:2]) for s in f.splines]
        b = self._bases[self.submap_index]
        return curves + [c.transformed(b[2], b[:2]) for c in self._local.curves]

    # -- the algorithm ------------------------------------------------------------------
    def step(self, odometry_delta, scan: LaserScan, laser_offset=None, odometry_covariance=None,
             features=None) -> StepReport:
        """One scan through the local filter (see :meth:`SplineSLAM.step`); a full submap
        is then frozen, matched against the old ones, and a new one started at this scan."""
        report = self._local.step(odometry_delta, scan, laser_offset, odometry_covariance, features)
        self.step_submap = self.submap_index
        self.steps += 1
        if odometry_delta is not None:
            self._distance += math.hypot(odometry_delta[0], odometry_delta[1])
        cfg = self.config.submaps
        if self._local.state_size >= cfg.max_state_size or self._distance >= cfg.max_distance_m:
            self._freeze()
            # the new submap starts at this scan: its splines seed the new map
            self._local.step(None, scan, laser_offset, features=report.features)
        elif cfg.online_match_m > 0 and self._distance - self._matched_at >= cfg.online_match_m:
            self._match_growing()
        self._check_memory()
        return report

    def finish(self) -> None:
        """Freeze the last submap (its loop closures found); call once, at the end of a
        run, then :meth:`sweep_loops`. Further steps start a new submap."""
        if self._local.steps > self._seed_steps:
            self._freeze()
        self._expire_pending(self.submap_index + self.config.submaps.loop_support_submaps)

    @property
    def _seed_steps(self) -> int:
        """Steps of the current submap that only seeded it (the scan that ended the last)."""
        return 1 if self.frozen else 0

    def _new_local(self, previous: SplineSLAM | None = None) -> SplineSLAM:
        """A filter for a new submap whose frame is the robot's pose, with zero covariance;
        with ``previous``, the splines it holds within ``submaps.carry_over_m`` of the
        robot come along (see :func:`carry_over`)."""
        self._distance = 0.0        # travelled in the current submap (m)
        self._matched_at = 0.0      # … at its last matching against the old ones (online_match_m)
        # its verified matches against old submaps: reference → (relative, covariance),
        # conditioning the current base (online_match_m)
        self._online: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        local = SplineSLAM(self.config, initial_pose=np.zeros(3), initial_covariance=np.zeros((3, 3)))
        if previous is not None:
            cfg = self.config.submaps
            carry_over(previous, local, cfg.carry_over_m, cfg.max_state_size)
        return local

    def _freeze(self) -> None:
        local, k = self._local, self.submap_index
        splines = local.map
        cfg = self.config.submaps
        end_cov = seam_covariance(local.pose_covariance, self._distance, cfg)
        frozen = FrozenSubmap(k, splines, matching_shape(splines, cfg), local.pose, end_cov, local.steps)
        self.frozen.append(frozen)
        self._frozen_bytes += frozen.nbytes
        self.graph.add_node(frozen.end_pose, _proper(frozen.end_covariance), self._distance)
        self.graph.optimize()
        self._bases = self.graph.poses()
        if self._close_loops(k):
            self._drop_loops(self.graph.optimize())
            self._bases = self.graph.poses()
        self._base_cov = self.graph.covariance(k + 1)
        self._local = self._new_local(local if cfg.carry_over_m > 0 else None)
        self.stats.submaps = k + 2

    def _close_loops(self, k: int) -> bool:
        """Match frozen submap ``k`` against the old submaps it may overlap (not its
        neighbour, tied to it by the odometry constraint); verified matches go to
        :meth:`_admit`. True when a loop closure was added to the graph."""
        query = self.frozen[k].shape
        if not self._matchable(k) or query.points.shape[0] == 0:
            return False
        verified, rejected = self._match_old(query, k, *self._areas())
        self.stats.loop_candidates += len(verified) + len(rejected)
        for reason in rejected:
            self.stats.reject(reason)
        found = [(_record(j, k, match), window_m, surprising) for j, match, window_m, surprising in verified]
        return self._admit(k, found)

    def _matchable(self, k: int) -> bool:
        """Whether submap ``k`` has old submaps to be matched against: loop closure is on
        and there is one beyond its neighbour (tied to it by the odometry constraint)."""
        return self.config.submaps.loop_max_candidates > 0 and k >= 2

    def _match_old(self, query: SubmapShape, k: int, centres: np.ndarray, radii: np.ndarray,
                   known: frozenset[int] = frozenset()) -> tuple[list[tuple[int, LoopMatch, float, bool]], list[str]]:
        """Match ``query``, the shape of submap ``k`` (node ``k`` optimised), against up to
        ``loop_max_candidates`` of submaps 0 … k − 2 whose areas (``centres`` (≥ k + 1, 2),
        ``radii``, map frame, m; entry k the query's) may overlap it within the search
        window the graph sets, nearest first; those in ``known`` (matched already) count
        as candidates but are not matched again. Returns the verified matches as
        (reference, match, window m, surprising: the graph does not vouch for it) and the
        reasons the other candidates tried were rejected. The caller has checked that
        there is something to match (:meth:`_matchable`, points in ``query``)."""
        cfg = self.config.submaps
        found, rejected = [], []
        gap = _gaps(centres, radii, k)
        skipped = 0
        for j in np.argsort(gap, kind="stable"):
            if len(found) + len(rejected) + skipped == cfg.loop_max_candidates or gap[j] > cfg.loop_max_window_m:
                break
            guess, cov = self.graph.relative(int(j), k)
            window_m, window_rad = search_window(cov, cfg)
            if gap[j] > window_m:     # cannot overlap anywhere in the search window
                continue
            if int(j) in known:
                skipped += 1
                continue
            match = match_submaps(self.frozen[j].shape, query, guess, cov, window_m, window_rad, cfg)
            if not match.ok:
                rejected.append(match.reason)
                continue
            surprising = cfg.loop_support_submaps > 0 and not vouched_by_graph(match, cov, window_m, window_rad, cfg)
            found.append((int(j), match, window_m, surprising))
        return found, rejected

    def _match_growing(self) -> None:
        """Match the growing submap against the old ones it has not matched yet and
        condition the current base on its match against each that the graph vouches for
        (``online_match_m``; every match when ``loop_support_submaps`` is 0, as the graph
        would take it). The matches never enter the graph (the frozen submap's own replace
        them) and the vote between matches is not held: a surprising one is left out."""
        self._matched_at = self._distance
        c = self.submap_index
        if not self._matchable(c):
            return
        query = matching_shape(self._local.map, self.config.submaps)
        if query.points.shape[0] == 0:
            return
        centres, radii = self._areas()
        base = self.graph.pose(c)
        centres = np.vstack([centres, compose(base, np.r_[query.center, 0.0])[:2]])
        radii = np.r_[radii, query.radius]
        # a wall matched once ties the base already; a later match of the same pair, on more
        # wall, would tighten it a little at the cost of a whole search
        found, rejected = self._match_old(query, c, centres, radii, frozenset(self._online))
        self.stats.online_candidates += len(found) + len(rejected)
        vouched = [(j, m, w) for j, m, w, surprising in found if not surprising]
        if not vouched:
            return
        self.stats.online_matches += len(vouched)
        for j, match, window_m in vouched:
            self._online[j] = (match.relative, _proper(match.covariance, window_m))
        pose, cov = self.graph.conditioned(c, [(j, r, q) for j, (r, q) in sorted(self._online.items())])
        self._bases[c] = pose
        self._base_cov = cov

    def sweep_loops(self) -> int:
        """Match each frozen submap again against the older ones whose areas overlap it
        where the graph now puts them and that no loop closure ties to it
        (``submaps.loop_sweep``): up to ``loop_max_candidates`` of them, the most
        overlapping first, each with the graph's guess and window; add the verified
        matches and solve once (the optimiser's guard against wrong loop closures
        classifies them with the rest).

        A newly frozen submap was matched once, against the graph as it then stood: a
        guess the later loop closures moved, a window as wide as the drift then. At the end
        the graph is as sure as it gets, so a match the checks refused then (ambiguous in
        the wide window, or not found) may now pass. The vote between neighbouring matches
        (``loop_support_submaps``) is not held: there are no later submaps to vote. So a
        match the graph can judge — its window covers the graph's region — and finds
        outside its 99 % region is refused (counted as ``sweep_unexpected``): on Edmonton
        one such match, 9.6 m off, took a whole run 4.1 m off; a match found in a window
        clipped short of the graph's region is taken as before (the campus's right matches
        after a long drift are such).

        Call once, after :meth:`finish`. Returns the number of loop closures added (the
        matches collected first, so an interrupt while matching leaves the graph as it was)."""
        cfg = self.config.submaps
        n = len(self.frozen)
        if not cfg.loop_sweep or cfg.loop_max_candidates == 0 or n < 3:
            return 0
        tied = {(r.reference, r.query) for r in self.loops}
        centres, radii = self._areas()
        jobs = []    # (reference, query, guess, its covariance, window m, window rad)
        for k in range(2, n):
            if self.frozen[k].shape.points.shape[0] == 0:
                continue
            gap = _gaps(centres, radii, k)
            untied = [int(j) for j in np.argsort(gap, kind="stable")
                      if gap[j] <= 0 and (int(j), k) not in tied and self.frozen[j].shape.points.shape[0]]
            # as many as the online matching tries, the most overlapping first: the cost
            # stays that of the online matching
            for j in untied[:cfg.loop_max_candidates]:
                guess, cov = self.graph.relative(j, k)      # GTSAM: from this thread only
                jobs.append((j, k, guess, cov, *search_window(cov, cfg)))
        self.stats.sweep_candidates += len(jobs)

        def match(job):
            j, k, guess, cov, window_m, window_rad = job
            return match_submaps(self.frozen[j].shape, self.frozen[k].shape, guess, cov, window_m, window_rad, cfg)

        # The matches are independent and their kernels release the GIL; map keeps the
        # jobs' order, so the result does not depend on the threads.
        with ThreadPoolExecutor(max_workers=min(_SWEEP_THREADS, os.cpu_count() or 1)) as pool:
            matches = list(pool.map(match, jobs))
        added = []
        for (j, k, _, cov, window_m, window_rad), m in zip(jobs, matches):
            if not m.ok:
                continue
            if not m.expected and window_covers(cov, window_m, window_rad, cfg):
                # the graph could judge this one (its window was not clipped) and finds it
                # outside its 99 % region; with no later submaps to vote, that is a refusal
                self.stats.reject("sweep_unexpected")
                continue
            added.append((_record(j, k, m), window_m))
        for record, window_m in added:
            loop_id = self.graph.add_loop(record.reference, record.query, record.relative,
                                          _proper(record.covariance, window_m))
            self.loops.append(replace(record, loop_id=loop_id))
        self.stats.loop_closures += len(added)
        dropped = self.graph.optimize() if added else []
        self._drop_loops(dropped)       # only ever the ones just added
        if added:
            self._bases = self.graph.poses()
            self._base_cov = self.graph.covariance(self.submap_index)
        self.stats.sweep_closures = len(added) - len(dropped)
        return self.stats.sweep_closures

    def _areas(self) -> tuple[np.ndarray, np.ndarray]:
        """(n, 2) the centres of the frozen submaps' matching points in the map frame (m,
        at their bases as last optimised) and (n,) the radii of circles around them (m)."""
        centres = np.array([compose(self._bases[f.index], np.r_[f.shape.center, 0.0])[:2] for f in self.frozen])
        return centres.reshape(-1, 2), np.array([f.shape.radius for f in self.frozen])

    def _admit(self, k: int, found: list[tuple[LoopRecord, float, bool]]) -> bool:
        """Add to the graph the verified matches (``found``: those of query ``k``, and
        those still waiting) that their neighbours let in (:func:`votes` among the graph's
        loop closures and the waiting matches): a match within the graph's 99 % region
        when no more neighbours contradict it than agree with it; a surprising one only
        when more agree than contradict (every match when ``loop_support_submaps`` is 0).
        The others wait while a later query can still vote on them. True when one was added."""
        cfg = self.config.submaps
        reach = cfg.loop_support_submaps
        self._pending += found
        if reach == 0:
            admitted = self._pending
        else:
            edges = [(f.end_pose, _proper(f.end_covariance)) for f in self.frozen]
            pool = [_edge(r) for r in self.loops if r.query >= k - 2 * reach] + [_edge(p[0]) for p in self._pending]
            admitted = []
            for p in self._pending:
                agree, disagree = votes(_edge(p[0]), pool, edges, reach, cfg.loop_distinct_m, cfg.loop_distinct_rad)
                if agree > disagree or (agree == disagree and not p[2]):
                    admitted.append(p)
        chosen = {id(p) for p in admitted}
        self._pending = [p for p in self._pending if id(p) not in chosen]
        for record, window_m, _ in admitted:     # in the order they were found
            loop_id = self.graph.add_loop(record.reference, record.query, record.relative,
                                          _proper(record.covariance, window_m))
            self.loops.append(replace(record, loop_id=loop_id))
            self.stats.loop_closures += 1
        self._expire_pending(k)
        return bool(admitted)

    def _expire_pending(self, k: int) -> None:
        """Drop the waiting matches no query after ``k`` can support (counted as
        ``unsupported`` rejections)."""
        reach = self.config.submaps.loop_support_submaps
        expired = [p for p in self._pending if p[0].query + reach <= k]
        if expired:
            self._pending = [p for p in self._pending if p[0].query + reach > k]
            self.stats.reject("unsupported", len(expired))

    def _drop_loops(self, dropped: list[int]) -> None:
        """Forget the loop closures the optimiser dropped (with them the system was
        ill-posed): a near-singular match, counted as a rejection ``ill_posed``."""
        if not dropped:
            return
        gone = set(dropped)
        self.loops = [loop for loop in self.loops if loop.loop_id not in gone]
        self.stats.loop_closures -= len(gone)
        self.stats.reject("ill_posed", len(gone))

    def _check_memory(self) -> None:
        used = self.nbytes
        if used > self._max_bytes:
            raise MemoryBudgetError(
                f"the estimator's live arrays need {used / 2 ** 20:.0f} MB, beyond max_memory_mb = "
                f"{self.config.max_memory_mb:g} MB ({len(self.frozen)} frozen submaps, local state "
                f"{self.state_size}); raise --max-memory or lower submaps.max_state_size", used)

    # -- the second pass ----------------------------------------------------------------
    def base_of(self, submap: int) -> tuple[np.ndarray, np.ndarray]:
        """(3,) the optimised base pose of ``submap`` and (3, 3) its marginal covariance."""
        return self._bases[submap].copy(), self.graph.covariance(submap)

    def local_map(self, submap: int) -> list[MapSpline]:
        """The splines of ``submap`` in its own frame (the current one's as they are now)."""
        return self.frozen[submap].splines if submap < len(self.frozen) else self._local.map

    def _global_splines(self) -> list[MapSpline]:
        out = []
        for k in range(self.submap_index + 1):
            splines = self.local_map(k) if k < len(self.frozen) or self._local.steps > self._seed_steps else []
            b = self._bases[k]
            out += [transform_spline(s, b, k) for s in splines]
        return out

    def loop_weights(self) -> np.ndarray:
        """(loops,) the weight of each accepted loop closure in the graph's solution (the
        Cauchy kernel's, or 1 / 0 for an inlier / outlier of the GNC classification)."""
        return self.graph.loop_weights() if self.loops else np.empty(0)


def carry_over(previous: SplineSLAM, local: SplineSLAM, radius_m: float, max_state: int) -> int:
    """Copy the splines of ``previous`` that come within ``radius_m`` of its robot into
    ``local``, a new filter whose frame is that robot pose (its pose the origin with zero
    covariance): their control points in the robot's frame, with their joint covariance
    *relative to the robot* (J P Jᵀ over the pose and the splines, J the Jacobian of
    p′ = R(φ)ᵀ (p − t)). The new submap then starts with the walls around it instead of one
    scan's, so its first steps are localised as well as the old submap's last.

    The copies carry information the old submap also used for its final pose (the
    odometry-like constraint between the two): the graph counts those walls' share twice,
    a small overconfidence of the chain, against a new map built from nothing at every
    seam. The nearest splines come first, up to half of ``max_state`` (the new submap
    must have room to grow). Returns the number of splines copied."""
    pose = previous.pose
    candidates = []
    for f in previous.features.values():
        if not f.in_state:
            continue
        box = f.curve(previous.state.x).bbox()      # xmin, ymin, xmax, ymax
        gap = np.maximum(np.maximum(box[:2] - pose[:2], pose[:2] - box[2:]), 0.0)
        if math.hypot(gap[0], gap[1]) <= radius_m:
            candidates.append((math.hypot(gap[0], gap[1]), f))
    # nearest first, at most half the submap's state: it must have room to grow
    near, room = [], max_state // 2
    for _, f in sorted(candidates, key=lambda item: item[0]):
        if 2 * f.idx_x.shape[0] > room:
            break
        near.append(f)
        room -= 2 * f.idx_x.shape[0]
    if not near:
        return 0
    idx = np.concatenate([np.arange(3)] + [f.state_indices for f in near])
    P = previous.state.block(idx, idx)
    x = previous.state.x[idx[3:]]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    # x holds, per spline, its n x-coordinates then its n y-coordinates
    xs, ys = [], []
    start = 0
    for f in near:
        n = f.idx_x.shape[0]
        xs.append(np.arange(start, start + n))
        ys.append(np.arange(start + n, start + 2 * n))
        start += 2 * n
    ix, iy = np.concatenate(xs), np.concatenate(ys)
    dx, dy = x[ix] - pose[0], x[iy] - pose[1]
    moved = np.empty_like(x)
    moved[ix] = c * dx + s * dy
    moved[iy] = -s * dx + c * dy
    m = x.shape[0]
    J = np.zeros((m, m + 3))
    J[ix, 0], J[ix, 1], J[ix, 2] = -c, -s, -s * dx + c * dy
    J[iy, 0], J[iy, 1], J[iy, 2] = s, -c, -c * dx - s * dy
    J[ix, 3 + ix], J[ix, 3 + iy] = c, s
    J[iy, 3 + ix], J[iy, 3 + iy] = -s, c
    cov = J @ P @ J.T
    # the estimator takes new control points as all their x coordinates, then their y's
    order = np.concatenate([ix, iy])
    cov = cov[np.ix_(order, order)]
    appended = local.state.append(moved[order], np.empty(0, dtype=np.intp), np.empty((m, 0)), 0.5 * (cov + cov.T))
    new = np.empty_like(appended)
    new[order] = appended                        # the state index of each entry of x
    for f, fx, fy in zip(near, xs, ys):
        g = SplineFeature(local.spline_map.new_id(), f.degree, f.knots.copy(), idx_x=new[fx], idx_y=new[fy],
                          observations=1)     # confirmed: the old submap's updates used it
        local.spline_map.add(g)
    return len(near)


def seam_covariance(filter_covariance: np.ndarray, distance_m: float, config: SubmapConfig) -> np.ndarray:
    """(3, 3) the covariance of the odometry-like constraint between a submap's base and
    the next one's: the local filter's pose covariance ``filter_covariance`` (3, 3) plus
    ``seam_drift_m_per_m`` × ``distance_m`` squared in x and y and
    ``seam_drift_rad_per_m`` × ``distance_m`` squared in heading.

    The filter's covariance holds only the errors it models (independent beams, the
    odometry's noise); what it leaves out — a wall fitted a little off, beams on one
    surface sharing an error, the front end's corridor matches coming out short — biases
    each scan the same way, so it grows with the distance travelled, not its square root.
    On real logs the seams were off by several σ (Acapulco: 1.23 m where σ said 0.26 m),
    and the graph then trusted them over the loop closures that would have corrected them.
    """
    d = float(distance_m)
    drift = np.array([config.seam_drift_m_per_m * d, config.seam_drift_m_per_m * d, config.seam_drift_rad_per_m * d])
    return np.asarray(filter_covariance, dtype=float) + np.diag(drift ** 2)


def matching_shape(splines: list[MapSpline], config: SubmapConfig) -> SubmapShape:
    """The points loop closure matches a submap by: its splines sampled every
    ``point_spacing_m``; with ``loop_max_wall_sigma_m`` > 0 not those whose place in the
    submap is known to worse than that (:attr:`MapSpline.position_sigma`). Such a wall
    cannot tell two distinct alignments apart, and a filter that lost itself maps walls
    metres off (the Freiburg campus, a run with 1 mm of range noise: four loop closures
    turned 30° against one such submap); they stay in the map."""
    limit = config.loop_max_wall_sigma_m
    sigmas = [s.position_sigma for s in splines]      # an eigen-decomposition per control point: once
    sure = [i for i, sigma in enumerate(sigmas) if limit == 0 or sigma <= limit]
    return SubmapShape.from_curves([splines[i].curve for i in sure], config.point_spacing_m,
                                   [sigmas[i] for i in sure])


def _gaps(centres: np.ndarray, radii: np.ndarray, k: int) -> np.ndarray:
    """(k − 1,) the gaps (m) between the area of submap ``k`` and those of submaps
    0 … k − 2 (not its neighbour, tied to it by the odometry constraint), from
    :meth:`SubmapSLAM._areas`; below 0 the areas overlap."""
    return np.hypot(*(centres[:k - 1] - centres[k]).T) - radii[:k - 1] - radii[k]


def search_window(covariance: np.ndarray, config: SubmapConfig) -> tuple[float, float]:
    """The loop-closure search's half-widths (m, rad) for a relative pose with
    ``covariance`` (3, 3): ``loop_sigmas`` σ of its larger position σ and of its heading,
    clipped to the configured bounds."""
    reach_m, reach_rad = _window_reach(covariance, config)
    window_m = min(max(reach_m, config.loop_min_window_m), config.loop_max_window_m)
    window_rad = min(max(reach_rad, config.loop_min_window_rad), config.loop_max_window_rad)
    return window_m, window_rad


def _window_reach(covariance: np.ndarray, config: SubmapConfig) -> tuple[float, float]:
    """``loop_sigmas`` σ of the larger position σ (m) and of the heading (rad) of a
    relative pose with ``covariance`` (3, 3): what a loop-closure search means to cover."""
    sigma_xy = math.sqrt(max(covariance[0, 0], covariance[1, 1]))
    return config.loop_sigmas * sigma_xy, config.loop_sigmas * math.sqrt(covariance[2, 2])


def vouched_by_graph(match: LoopMatch, covariance: np.ndarray, window_m: float, window_rad: float,
                     config: SubmapConfig) -> bool:
    """Whether the pose graph vouches for a verified ``match`` searched for with the
    graph's relative-pose ``covariance`` (3, 3) in a window of ±``window_m``, ±``window_rad``:
    the match lies within the graph's 99 % region (``match.expected``) and the search
    examined the alignments the graph would expect (:func:`window_covers`). One the graph
    does not vouch for enters only with its neighbours' support (``loop_support_submaps``).

    A window clipped at ``loop_max_window_m`` holds one copy of a repeated structure among
    those the graph admits: on the campus, after a long drift, a graph σ of 70 m and a
    match 15 m off at 98 % inliers, "within the region" and so taken on its own."""
    return match.expected and window_covers(covariance, window_m, window_rad, config)


def window_covers(covariance: np.ndarray, window_m: float, window_rad: float, config: SubmapConfig) -> bool:
    """Whether a search of ±``window_m`` (m) and ±``window_rad`` (rad) covers
    ``loop_sigmas`` σ of a relative pose with ``covariance`` (3, 3), as
    :func:`search_window` means it to (False when that clipped it at its maximum); a
    heading window of π covers every heading."""
    reach_m, reach_rad = _window_reach(covariance, config)
    return reach_m <= window_m and (reach_rad <= window_rad or window_rad >= math.pi)


def _record(reference: int, query: int, match: LoopMatch) -> LoopRecord:
    """A verified match as a loop record (not yet in the graph), its rival kept for the vote."""
    rival = match.alternative.copy() if match.ambiguity > 0 else None
    return LoopRecord(reference, query, match.relative, match.covariance, match.inlier_fraction, match.overlap_m,
                      rival=rival, slide=match.slide)


def _edge(record: LoopRecord) -> LoopEdge:
    return LoopEdge(record.reference, record.query, record.relative, record.covariance, record.rival)


def _proper(cov: np.ndarray, max_sigma: float = 100.0) -> np.ndarray:
    """A covariance the optimiser can use: symmetric, its eigenvalues clamped to
    [(1e-6)², max_sigma²] — a pose the local filter knows exactly (a submap of one scan)
    would be an infinite weight, a direction a match leaves free (a corridor) a nearly
    singular one; either makes the linear systems ill-posed. ``max_sigma``: for a loop
    closure the search window, which bounds its error anyway."""
    cov = 0.5 * (np.asarray(cov, dtype=float) + np.asarray(cov, dtype=float).T)
    w, V = np.linalg.eigh(cov)
    w = np.clip(w, _ANCHOR_SIGMA ** 2, max_sigma ** 2)
    cov = (V * w) @ V.T
    # symmetric to the last bit: with eigenvalues 1e-12 to 1e4 apart the product is not
    return 0.5 * (cov + cov.T)


def transform_spline(spline: MapSpline, pose: np.ndarray, submap: int = 0) -> MapSpline:
    """``spline`` (its submap's frame) in the frame where the submap's base is ``pose``
    (3,): control points moved rigidly, the covariance of [x_0 … x_{n−1}, y_0 … y_{n−1}]
    rotated with them."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    curve = spline.curve.transformed(pose[2], pose[:2])
    n = spline.curve.control_points.shape[0]
    eye = np.eye(n)
    T = np.block([[c * eye, -s * eye], [s * eye, c * eye]])
    cov = T @ spline.covariance @ T.T
    return MapSpline(spline.id, curve, cov, submap=submap, surface=spline.surface)


#: Spacing (m) of the points compared to find splines on one surface: twice the default
#: tolerance, so a point meets at most one or two neighbours of its own curve. At the
#: matching's 5 cm the campus map's point pairs took over a gigabyte.
SURFACE_SPACING_M = 0.2


def mark_surfaces(splines: list[MapSpline], spacing_m: float, tolerance_m: float = 0.1,
                  min_shared: float = 0.5) -> list[MapSpline]:
    """The splines with ``surface`` set: splines of different submaps that lie on one
    another (at least ``min_shared`` of the shorter one's points, sampled every
    ``spacing_m``, within ``tolerance_m`` of the other) are one surface, transitively;
    a surface's id is its first spline's index. The map keeps both (each carries its own
    submap's covariance); a reader draws or counts a surface once."""
    if not splines:
        return []
    samples = [_sample(s.curve, spacing_m) for s in splines]
    owner = np.repeat(np.arange(len(splines)), [p.shape[0] for p in samples])
    submap = np.array([s.submap for s in splines])[owner]
    points = np.vstack(samples)
    tree = cKDTree(points)
    pairs = tree.query_pairs(tolerance_m, output_type="ndarray")
    pairs = pairs[submap[pairs[:, 0]] != submap[pairs[:, 1]]]
    parent = np.arange(len(splines))
    if pairs.size:
        # points of spline a near spline b (each point counted once per other spline)
        both = np.concatenate([np.c_[pairs[:, 0], owner[pairs[:, 1]]], np.c_[pairs[:, 1], owner[pairs[:, 0]]]])
        point_spline = np.unique(both, axis=0)
        link, shared = np.unique(np.c_[owner[point_spline[:, 0]], point_spline[:, 1]], axis=0, return_counts=True)
        counts = np.array([p.shape[0] for p in samples])
        for (a, b), m in zip(link, shared):
            if m >= min_shared * min(counts[a], counts[b]):
                ra, rb = _root(parent, a), _root(parent, b)
                parent[max(ra, rb)] = min(ra, rb)
    roots = [_root(parent, i) for i in range(len(splines))]
    return [replace(s, surface=int(r)) for s, r in zip(splines, roots)]


def _root(parent: np.ndarray, i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return int(i)


def _sample(curve: BSplineCurve, spacing_m: float) -> np.ndarray:
    """(k, 2) points along ``curve`` about ``spacing_m`` apart: the splines are fitted with
    chord-length parameters, so the parameter domain's length is close to the arc length
    (and costs nothing, where :meth:`BSplineCurve.length` integrates)."""
    lo, hi = curve.domain
    k = max(2, int(math.ceil((hi - lo) / spacing_m)) + 1)
    return curve.evaluate(np.linspace(lo, hi, k))
