"""The global layer of the submap backend: a pose graph over the submaps' base poses,
solved incrementally by GTSAM's iSAM2.

- **Nodes** are the base poses (x m, y m, φ rad) of the submaps in the map frame. Node 0
  carries a prior that defines the map frame (by default a tiny one: the first submap
  *is* the map frame).
- **Odometry factors** tie consecutive submaps: the base pose of submap i seen from
  submap i−1, as the local filter estimated it when submap i−1 was frozen. They come from
  the filter itself, so they are trusted: a plain Gaussian noise model. Optionally
  (``drift_rate_sigma``) they share one more unknown, a heading drift rate that turns
  each of them by rate × the distance travelled (:mod:`bsslam.submaps.drift_factor`).
- **Loop-closure factors** tie a submap to an old one it was matched against. Matching
  can be fooled (repetitive corridors, façades, symmetric rooms): a wrong match can look as
  good locally as a right one (inlier fractions of 0.85–1.0 on the campus), so only the
  rest of the graph can tell it apart. Two ways, ``loop_outliers``:

  ``cauchy`` (this class's default; the submap configuration's is ``gnc``): every loop factor carries a robust noise model, a Cauchy kernel
  of width k (in whitened units, σ). Its weight 1 / (1 + (d/k)²) at a whitened residual d
  is ½ at d = k, and its influence (weight × d) peaks at d = k and then decays as k²/d, so
  a false loop tens of σ off pulls the graph with a small fraction of the force of a true
  loop. Huber's influence stays at k however wrong the loop is; a hard gate drops a true
  loop whenever drift makes it look large. Cauchy's weight is smooth and never exactly
  zero, so a true loop that looks large at first regains its weight as the graph moves
  towards it. But iSAM2 re-weights only at relinearisation, from wherever the graph
  stands: once several wrong loop closures pull a large graph their way, the right ones
  look wrong in turn (a local minimum).

  ``gnc``: new loop closures are first taken as inliers. When that leaves an inlier whose
  whitened squared residual is beyond the χ²(3) quantile at ``loop_inlier_probability``,
  or an outlier within it, every loop factor so far is classified afresh by graduated
  non-convexity (GTSAM's ``GncLMOptimizer``, Yang et al. 2020) with a
  truncated-least-squares loss, starting from the convex least-squares problem: the
  odometry factors are known inliers; a loop factor beyond the threshold at the solution
  is an outlier and leaves the solve (weight 0), the others stay as plain Gaussian
  factors (weight 1). A loop set aside is reconsidered at every later classification. On
  the Freiburg campus's graph with 1 mm perturbed ranges (seed 1: 326 loop closures, 27
  of them off by 0.3–10 m; ``benchmarks/replay_pose_graph.py``) the Cauchy kernel leaves
  the bases 6.13 m off, no better than no loop closure at all (6.18 m), and GNC 0.87 m
  (0.72 m with only the right loop closures, known from the reference). It picks whole
  consistent groups, though, and a wrong group can win when the loop closures'
  covariances are too small (see the configuration's ``loop_outliers``).

Covariances at the interface are bsslam's: covariances of pose *coordinates*
(x, y, φ) in the parent frame. GTSAM's are of its right tangent perturbation
pose·Exp(ξ), ξ = (vx, vy, ω) in the pose's own frame. To first order the two differ by
the rotation of the translation part, ``Σ_bsslam = B Σ_gtsam Bᵀ`` with
``B = blockdiag(R(θ), 1)`` and θ the heading of the pose the covariance belongs to;
the conversion happens here and nowhere else.

iSAM2 keeps the factorisation of the graph and updates only the part of its Bayes tree
that new factors touch, so an odometry update costs roughly a constant. A loop closure
re-eliminates the loop's span and is followed by a few extra iterations so that the
relinearisation (and the Cauchy kernel's weights, which are recomputed at
relinearisation) converges. A GNC classification solves the whole graph in batch (many
Levenberg–Marquardt solves of a few hundred nodes) and restarts iSAM2 from its solution
with the inlier loops; it runs only when new loop closures break the classification.

iSAM2's objects do not pickle. A :class:`PoseGraph` pickles as the calls that built it
(its arguments, then every :meth:`add_node`, :meth:`add_loop`, :meth:`optimize` and
marginal query, with their arguments) and unpickles by making them again: iSAM2 is
deterministic, so the replayed solver holds the same numbers bit for bit (the marginal
queries are replayed too because they fill iSAM2's caches of clique marginals). That is
what a run's checkpoint needs (:mod:`bsslam.io.checkpoint`); the log is a few calls per
submap.
"""

from __future__ import annotations

import gtsam
import numpy as np

from bsslam.chi2 import chi2_quantile
from bsslam.errors import FilterError
from bsslam.submaps.drift_factor import DRIFT_KEY, drift_corrected, drift_factor

#: Default σ² of node 0's prior: the map frame is defined by node 0, held (almost) fixed.
_ANCHOR_VARIANCE = 1e-9


def _frame_rotation(theta: float) -> np.ndarray:
    """blockdiag(R(θ), 1) (3, 3): maps a tangent perturbation of a pose with heading θ
    to the first-order change of its coordinates."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _to_tangent(covariance: np.ndarray, theta: float) -> np.ndarray:
    """bsslam coordinate covariance (3, 3) of a pose with heading θ → GTSAM tangent covariance."""
    B = _frame_rotation(theta)
    cov = B.T @ covariance @ B
    return 0.5 * (cov + cov.T)


def _from_tangent(covariance: np.ndarray, theta: float) -> np.ndarray:
    """GTSAM tangent covariance (3, 3) of a pose with heading θ → bsslam coordinate covariance."""
    B = _frame_rotation(theta)
    cov = B @ covariance @ B.T
    return 0.5 * (cov + cov.T)


def _check_pose(pose, name: str) -> np.ndarray:
    pose = np.asarray(pose, dtype=float)
    if pose.shape != (3,) or not np.all(np.isfinite(pose)):
        raise ValueError(f"{name} must be a finite (3,) pose (x m, y m, φ rad), got {pose!r}")
    return pose


def _check_covariance(covariance, name: str) -> np.ndarray:
    covariance = np.asarray(covariance, dtype=float)
    if covariance.shape != (3, 3) or not np.all(np.isfinite(covariance)):
        raise ValueError(f"{name} must be a finite (3, 3) covariance, got shape {covariance.shape}")
    if not np.allclose(covariance, covariance.T, rtol=1e-9, atol=1e-15):
        raise ValueError(f"{name} must be symmetric")
    try:
        np.linalg.cholesky(covariance)
    except np.linalg.LinAlgError:
        raise ValueError(f"{name} must be positive definite") from None
    return covariance


class PoseGraph:
    """A pose graph over submap base poses (node i ↔ GTSAM key i), solved by iSAM2, with
    a guard against wrong loop closures (see the module docstring).

    Factors and initial estimates are queued by :meth:`add_node` and :meth:`add_loop`
    and go into the solver at :meth:`optimize`. Poses can be read at any time (a queued
    node reads its initial estimate); marginal covariances and loop weights need the nodes
    involved to have been optimised.

    Args:
        first_pose: node 0's pose (3,) (x m, y m, φ rad) in the map frame.
        first_covariance: covariance (3, 3) of node 0's prior in bsslam convention
            (coordinates), or None for a tiny one (1e-9 on the diagonal): node 0 defines
            the map frame.
        loop_outliers: ``"cauchy"`` (a robust kernel on each loop factor), ``"gnc"``
            (classification into inliers and outliers) or None (every loop factor a plain
            Gaussian: least squares, for tests and comparisons).
        robust_kernel_width: (cauchy) width k of the Cauchy kernel on loop factors, in
            whitened units (σ); a loop factor k σ from the graph's consensus gets weight ½.
        loop_inlier_probability: (gnc) a loop factor is an inlier when its whitened
            squared residual at the solution is within the χ²(3) quantile at this
            probability (0.99: 11.3, a residual of 3.4 σ).
        relinearize_threshold: iSAM2 relinearises a node whose pending update exceeds
            this (m / rad, per tangent component). It bounds how far the solution is from
            the exact optimum: roughly its square for Gaussian factors, but about the
            threshold itself (times a factor below 1) once the Cauchy kernel is active, as
            the kernel's weights are only refreshed where the graph is relinearised.
        max_iterations: at most this many extra iSAM2 iterations after a loop closure.
        drift_rate_sigma: σ (rad/m) of a heading drift rate every odometry factor shares,
            an unknown of the graph with a zero-mean prior (:mod:`bsslam.submaps.drift_factor`);
            an odometry factor takes it in proportion to the ``distance_m`` given to
            :meth:`add_node`. 0 leaves it out (plain between factors).
    """

    def __init__(self, first_pose, first_covariance=None, *, loop_outliers: str | None = "cauchy",
                 robust_kernel_width: float = 3.0, loop_inlier_probability: float = 0.99,
                 relinearize_threshold: float = 1e-4, max_iterations: int = 20,
                 drift_rate_sigma: float = 0.0):
        first_pose = _check_pose(first_pose, "first_pose")
        if first_covariance is None:
            first_covariance = _ANCHOR_VARIANCE * np.eye(3)
        first_covariance = _check_covariance(first_covariance, "first_covariance")
        if loop_outliers not in ("cauchy", "gnc", None):
            raise ValueError(f"loop_outliers must be 'cauchy', 'gnc' or None, got {loop_outliers!r}")
        if not robust_kernel_width > 0:
            raise ValueError(f"robust_kernel_width must be > 0, got {robust_kernel_width}")
        if not 0.0 < loop_inlier_probability < 1.0:
            raise ValueError(f"loop_inlier_probability must be in (0, 1), got {loop_inlier_probability}")
        if not relinearize_threshold > 0:
            raise ValueError(f"relinearize_threshold must be > 0, got {relinearize_threshold}")
        if not (isinstance(max_iterations, int) and max_iterations >= 0):
            raise ValueError(f"max_iterations must be an integer ≥ 0, got {max_iterations!r}")
        if not (np.isfinite(drift_rate_sigma) and drift_rate_sigma >= 0):
            raise ValueError(f"drift_rate_sigma must be finite and ≥ 0, got {drift_rate_sigma!r}")
        self.loop_outliers = loop_outliers
        self.robust_kernel_width = float(robust_kernel_width)
        self.loop_inlier_probability = float(loop_inlier_probability)
        self._max_iterations = max_iterations
        # the calls that built this graph, replayed on unpickling (see the module docstring)
        self._init_args = dict(first_pose=first_pose.copy(), first_covariance=first_covariance.copy(),
                               loop_outliers=loop_outliers, robust_kernel_width=self.robust_kernel_width,
                               loop_inlier_probability=self.loop_inlier_probability,
                               relinearize_threshold=float(relinearize_threshold), max_iterations=max_iterations,
                               drift_rate_sigma=float(drift_rate_sigma))
        self.drift_rate_sigma = float(drift_rate_sigma)
        self._calls: list[tuple] = []

        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(float(relinearize_threshold))
        params.relinearizeSkip = 1  # check every update: loop closures must converge promptly
        # QR, not the default Cholesky: a chain of submaps without loop closures is badly
        # conditioned (a base known to 1e-6 m next to one uncertain by 100 m, an edge whose
        # lateral σ is 0.1 mm while its heading's is 0.1 rad), and iSAM2's Cholesky calls
        # such a system indeterminate within a few nodes (the campus's chain alone failed
        # at its 94th submap). The graphs have hundreds of nodes: the cost is small.
        params.setFactorization("QR")
        self._isam_params = params
        self._isam = gtsam.ISAM2(params)
        self._kernel = gtsam.noiseModel.mEstimator.Cauchy.Create(self.robust_kernel_width)
        # the prior and the odometry factors; the loop factors (Gaussian), their robust
        # versions (cauchy) and whether each is an inlier at the last classification (gnc)
        self._chain_factors = gtsam.NonlinearFactorGraph()
        # the odometry factors that take the drift rate: chain index → (i, j, z, distance, noise)
        self._drift_seams: dict[int, tuple] = {}
        self._loop_factors: list[gtsam.BetweenFactorPose2] = []
        self._robust_loops: list[gtsam.BetweenFactorPose2] = []
        self._loop_pairs: list[tuple[int, int]] = []
        self._loop_inlier = np.zeros(0, dtype=bool)

        # Pending input for the next optimize().
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._loop_pending = False
        # Current estimate of every node (optimised, or initial for queued ones): the
        # gtsam Values for factor errors, the numpy buffer for cheap reads.
        self._values = gtsam.Values()
        self._poses = np.empty((16, 3))
        self._size = 0
        self._optimized_size = 0

        prior = gtsam.noiseModel.Gaussian.Covariance(_to_tangent(first_covariance, first_pose[2]))
        self._add_chain_factor(gtsam.PriorFactorPose2(0, gtsam.Pose2(*first_pose), prior))
        self._append_node(first_pose)
        if self.drift_rate_sigma > 0:
            rate = np.zeros(1)
            self._add_chain_factor(gtsam.PriorFactorVector(
                DRIFT_KEY, rate, gtsam.noiseModel.Isotropic.Sigma(1, self.drift_rate_sigma)))
            self._new_values.insert(DRIFT_KEY, rate)
            self._values.insert(DRIFT_KEY, rate)

    # -- building ------------------------------------------------------------------------

    def _add_chain_factor(self, factor) -> None:
        self._chain_factors.add(factor)
        self._new_factors.add(factor)

    def _append_node(self, pose: np.ndarray) -> int:
        i = self._size
        if i == len(self._poses):  # amortised growth: doubling
            self._poses = np.concatenate([self._poses, np.empty_like(self._poses)])
        self._poses[i] = pose
        p = gtsam.Pose2(*pose)
        self._new_values.insert(i, p)
        self._values.insert(i, p)
        self._size += 1
        return i

    def _check_node(self, i, name: str) -> int:
        if not isinstance(i, (int, np.integer)) or not 0 <= i < self._size:
            raise ValueError(f"{name} must be a node index in [0, {self._size}), got {i!r}")
        return int(i)

    def add_node(self, relative, covariance, distance_m: float = 0.0) -> int:
        """Add node i = (node i−1) ⊕ ``relative`` with a Gaussian odometry factor from
        node i−1 and return i.

        Args:
            relative: (3,) pose of the new node in the previous node's frame (m, m, rad).
            covariance: (3, 3) covariance of ``relative`` in bsslam convention.
            distance_m: the distance travelled between the two (m), over which the
                shared drift rate turns ``relative`` (with ``drift_rate_sigma`` > 0).
        """
        relative = _check_pose(relative, "relative")
        covariance = _check_covariance(covariance, "covariance")
        if not (np.isfinite(distance_m) and distance_m >= 0):
            raise ValueError(f"distance_m must be finite and ≥ 0, got {distance_m!r}")
        self._calls.append(("add_node", relative.copy(), covariance.copy(), float(distance_m)))
        previous = self._size - 1
        z = gtsam.Pose2(*relative)
        noise = gtsam.noiseModel.Gaussian.Covariance(_to_tangent(covariance, relative[2]))
        i = self._size
        if self.drift_rate_sigma > 0:
            self._drift_seams[self._chain_factors.size()] = (previous, i, z, float(distance_m), noise)
            self._add_chain_factor(drift_factor(previous, i, z, distance_m, noise))
            z = drift_corrected(z, float(self._values.atVector(DRIFT_KEY)[0]), distance_m)
        else:
            self._add_chain_factor(gtsam.BetweenFactorPose2(previous, i, z, noise))
        guess = self._values.atPose2(previous).compose(z)
        return self._append_node(np.array([guess.x(), guess.y(), guess.theta()]))

    def add_loop(self, i: int, j: int, relative, covariance) -> int:
        """Add a loop-closure factor between nodes i and j and return its loop id (0, 1, …
        in order of addition). It goes into the solver at the next :meth:`optimize`
        behind the graph's guard against wrong loop closures (see the module docstring).

        Args:
            i, j: distinct node indices (either may be queued, not yet optimised).
            relative: (3,) measured pose of node j in node i's frame, i.e. the measured
                ``se2.between(pose_i, pose_j)``.
            covariance: (3, 3) covariance of ``relative`` in bsslam convention.
        """
        i, j = self._check_node(i, "i"), self._check_node(j, "j")
        if i == j:
            raise ValueError("a loop closure needs two distinct nodes")
        relative = _check_pose(relative, "relative")
        covariance = _check_covariance(covariance, "covariance")
        self._calls.append(("add_loop", i, j, relative.copy(), covariance.copy()))
        gaussian = gtsam.noiseModel.Gaussian.Covariance(_to_tangent(covariance, relative[2]))
        z = gtsam.Pose2(*relative)
        self._loop_factors.append(gtsam.BetweenFactorPose2(i, j, z, gaussian))
        if self.loop_outliers == "gnc":   # an inlier until a classification says otherwise
            self._new_factors.add(self._loop_factors[-1])
        else:
            noise = gaussian if self.loop_outliers is None else gtsam.noiseModel.Robust.Create(self._kernel, gaussian)
            self._robust_loops.append(gtsam.BetweenFactorPose2(i, j, z, noise))
            self._new_factors.add(self._robust_loops[-1])
        self._loop_pairs.append((i, j))
        self._loop_inlier = np.append(self._loop_inlier, True)
        self._loop_pending = True
        return len(self._loop_factors) - 1

    # -- solving -------------------------------------------------------------------------

    def optimize(self) -> list[int]:
        """Put the factors and nodes added since the last call into the solver and update
        the estimate: an incremental iSAM2 update; with new loop closures and ``gnc``, a
        classification of every loop factor over the whole graph and iSAM2 restarted from
        its solution with the inliers.

        When iSAM2 finds the system ill-posed, the graph is solved in batch
        (Levenberg–Marquardt) and iSAM2 restarted from it. Returns the ids of the loop
        factors added since the last call that were dropped because even that failed with
        them (usually none): the graph is then rebuilt from its calls without them, and
        the ids of later loops shift down.

        Raises:
            FilterError: the system is ill-posed without a new loop closure.
        """
        if self._new_factors.size() == 0 and self._new_values.size() == 0 and not self._loop_pending:
            return []
        self._calls.append(("optimize",))
        try:
            self._update()
        except RuntimeError:   # gtsam's IndeterminateLinearSystemException
            # iSAM2 is Gauss–Newton on a partly relinearised system and can meet a
            # numerically singular one where the problem itself is well posed (a known
            # iSAM2 failure): solve the whole graph in batch with Levenberg–Marquardt,
            # whose damping copes, and restart iSAM2 from that solution. Deterministic, so
            # replaying the calls (unpickling) takes the same path.
            try:
                self._solve_in_batch()
            except RuntimeError as exc:
                return self._drop_pending_loops(exc)
        return []

    def _chain_with(self, loops) -> gtsam.NonlinearFactorGraph:
        """The prior and the odometry factors, then ``loops``."""
        graph = gtsam.NonlinearFactorGraph(self._chain_factors)
        for factor in loops:
            graph.add(factor)
        return graph

    def _solved_graph(self) -> gtsam.NonlinearFactorGraph:
        """The factors the solution minimises: the prior, the odometry factors and the loop
        factors (robust ones; with ``gnc`` the Gaussian ones classified as inliers)."""
        if self.loop_outliers == "gnc":
            return self._chain_with(f for f, inlier in zip(self._loop_factors, self._loop_inlier) if inlier)
        return self._chain_with(self._robust_loops)

    def _classify_loops(self) -> gtsam.Values:
        """Graduated non-convexity (truncated least squares) over the whole graph from the
        current estimate; sets which loop factors are inliers and returns the solution.

        GTSAM's GNC re-weights every factor by cloning it, which a factor written in Python
        (the drift factor) cannot do; so for the classification the seams enter as plain
        between factors with the drift rate held at its current estimate, and the solution
        keeps that estimate (iSAM2 then solves for it again with the inliers)."""
        rate = None
        graph = self._chain_with(self._loop_factors)
        if self._drift_seams:
            rate = float(self._values.atVector(DRIFT_KEY)[0])
            for k, (i, j, z, distance, noise) in self._drift_seams.items():
                graph.replace(k, gtsam.BetweenFactorPose2(i, j, drift_corrected(z, rate, distance), noise))
        params = gtsam.GncLMParams()
        params.setLossType(gtsam.GncLossType.TLS)
        params.setKnownInliers(list(range(self._chain_factors.size())))
        gnc = gtsam.GncLMOptimizer(graph, self._values, params)
        gnc.setInlierCostThresholdsAtProbability(self.loop_inlier_probability)
        result = gnc.optimize()
        weights = np.asarray(gnc.getWeights(), dtype=float)[self._chain_factors.size():]
        self._loop_inlier = weights > 0.5
        if rate is not None:     # held, not solved for: the prior alone pulled it to 0
            result.update(DRIFT_KEY, np.array([rate]))
        return result

    def _update(self) -> None:
        self._isam.update(self._new_factors, self._new_values)
        if self._loop_pending:
            self._iterate()
            if self.loop_outliers == "gnc" and not self._classification_holds():
                values = self._classify_loops()
                self._isam = gtsam.ISAM2(self._isam_params)
                self._isam.update(self._solved_graph(), values)
                self._iterate()
        self._finish_update()

    def _iterate(self) -> None:
        """Extra iSAM2 iterations until no node needs relinearising (a loop closure moves
        the graph by more than one Gauss–Newton step)."""
        for _ in range(self._max_iterations):
            if self._isam.update().getVariablesRelinearized() == 0:
                break

    def _classification_holds(self) -> bool:
        """With the new loop closures taken as inliers, is every inlier still within the
        threshold and every outlier beyond it? Then the classification is a fixed point of
        the truncated least squares (its solution is the least-squares one of its inliers
        and agrees with them) and the whole-graph classification is not needed: most new
        loop closures agree with the graph, and a classification costs a few hundred
        Levenberg–Marquardt solves of the whole graph."""
        errors = self._loop_errors_at(self._isam.calculateBestEstimate())
        within = errors ** 2 <= chi2_quantile(self.loop_inlier_probability, 3)
        return bool(np.array_equal(within, self._loop_inlier))

    def _solve_in_batch(self) -> None:
        """Levenberg–Marquardt over every factor solved (see :meth:`_solved_graph`; with
        ``gnc`` classified first when loop closures are pending) from the current
        estimate; iSAM2 restarted with its result."""
        values = self._values
        if self._loop_pending and self.loop_outliers == "gnc":
            values = self._classify_loops()
        graph = self._solved_graph()
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
        self._isam = gtsam.ISAM2(self._isam_params)
        self._isam.update(graph, result)
        self._finish_update()

    def _drop_pending_loops(self, exc: RuntimeError) -> list[int]:
        """Rebuild the graph from its calls without the loop factors added since the last
        successful :meth:`optimize` (iSAM2's state is not usable after a failed update),
        then optimise the new nodes alone."""
        calls = self._calls[:-1]                      # the failed optimize
        last = max((k for k, c in enumerate(calls) if c[0] == "optimize"), default=-1)
        pending = calls[last + 1:]
        loops = [c for c in pending if c[0] == "add_loop"]
        if not loops:
            raise FilterError(f"the pose graph is ill-posed ({str(exc).strip().splitlines()[0]}); "
                              "the submaps' constraints are degenerate") from None
        first_dropped = len(self._loop_factors) - len(loops)
        self.__setstate__({"init_args": self._init_args,
                           "calls": calls[:last + 1] + [c for c in pending if c[0] != "add_loop"]})
        self.optimize()
        return list(range(first_dropped, first_dropped + len(loops)))

    def _finish_update(self) -> None:
        """The pending input is in the solver: clear it and read the new estimate."""
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._loop_pending = False
        # calculateBestEstimate back-substitutes the whole tree (no wildfire cut-off):
        # exact for the current linearisation, O(n), cheap at a few hundred nodes.
        self._values = self._isam.calculateBestEstimate()
        self._poses[:self._size] = gtsam.utilities.extractPose2(self._values)
        self._optimized_size = self._size

    # -- pickling ------------------------------------------------------------------------

    def __getstate__(self) -> dict:
        return {"init_args": self._init_args, "calls": list(self._calls)}

    def __setstate__(self, state: dict) -> None:
        self.__init__(**state["init_args"])
        for name, *args in state["calls"]:
            getattr(self, name)(*args)     # each call records itself again

    # -- reading -------------------------------------------------------------------------

    @property
    def size(self) -> int:
        """Number of nodes (queued ones included)."""
        return self._size

    @property
    def loop_count(self) -> int:
        """Number of loop factors added."""
        return len(self._loop_factors)

    @property
    def loops(self) -> list[tuple[int, int]]:
        """Node pairs (i, j) of the loop factors, indexed by loop id."""
        return list(self._loop_pairs)

    @property
    def distances(self) -> np.ndarray:
        """(nodes − 1,) the distance (m) given with each odometry factor, in order."""
        return np.array([c[3] if len(c) > 3 else 0.0 for c in self._calls if c[0] == "add_node"], dtype=float)

    def pose(self, i: int) -> np.ndarray:
        """Current estimate (3,) of node i (x m, y m, φ rad)."""
        return self._poses[self._check_node(i, "i")].copy()

    def poses(self) -> np.ndarray:
        """Current estimates (n, 3) of all nodes."""
        return self._poses[:self._size].copy()

    def drift_rate(self) -> tuple[float, float]:
        """The seams' shared heading drift rate (rad/m): its current estimate and, once
        optimised, its marginal σ (the prior's before; (0, 0) without one)."""
        if self.drift_rate_sigma == 0:
            return 0.0, 0.0
        rate = float(self._values.atVector(DRIFT_KEY)[0])
        if self._optimized_size == 0:
            return rate, self.drift_rate_sigma
        self._calls.append(("drift_rate",))     # a marginal query fills iSAM2's caches
        return rate, float(np.sqrt(self._isam.marginalCovariance(DRIFT_KEY)[0, 0]))

    def _check_optimized(self, i: int, name: str) -> int:
        i = self._check_node(i, name)
        if i >= self._optimized_size:
            raise RuntimeError(f"node {i} is not in the solver yet: call optimize() first")
        return i

    def covariance(self, i: int) -> np.ndarray:
        """Marginal covariance (3, 3) of node i's coordinates in the map frame (bsslam
        convention), at the current linearisation point."""
        i = self._check_optimized(i, "i")
        self._calls.append(("covariance", i))
        return _from_tangent(self._isam.marginalCovariance(i), self._poses[i, 2])

    def relative(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """``se2.between(pose_i, pose_j)`` (3,) and its covariance (3, 3) in bsslam
        convention, from the joint marginal of nodes i and j (their correlation matters:
        two nodes far from node 0 can be well known relative to each other)."""
        i, j = self._check_optimized(i, "i"), self._check_optimized(j, "j")
        pi, pj = self._values.atPose2(i), self._values.atPose2(j)
        r = pi.between(pj)
        rel = np.array([r.x(), r.y(), r.theta()])
        if i == j:
            return rel, np.zeros((3, 3))
        self._calls.append(("relative", i, j))
        joint = self._isam.jointMarginalCovariance([i, j])
        S = np.block([[joint.at(i, i), joint.at(i, j)], [joint.at(j, i), joint.at(j, j)]])
        # Right perturbations: (pi·Exp(a))⁻¹ (pj·Exp(b)) ≈ r·Exp(b − Ad(r⁻¹) a).
        H = np.hstack([-r.inverse().AdjointMap(), np.eye(3)])
        return rel, _from_tangent(H @ S @ H.T, rel[2])

    def conditioned(self, node: int, loops) -> tuple[np.ndarray, np.ndarray]:
        """Node ``node``'s pose (3,) and covariance (3, 3, bsslam convention) as the graph
        would give them with ``loops`` added as plain Gaussian loop factors, without adding
        them: one Kalman update of the joint marginal of the nodes involved (exact for the
        linearised graph, as its other nodes are summed out).

        For measurements that will enter the graph later in another form (a growing
        submap's matches, which its full match replaces when it is frozen): the graph
        stays as it is.

        Args:
            node: an optimised node.
            loops: [(i, relative, covariance)]: the measured ``se2.between(pose_i,
                pose_node)`` (3,) with its covariance (3, 3, bsslam convention), i an
                optimised node other than ``node``.
        """
        node = self._check_optimized(node, "node")
        loops = [(self._check_optimized(i, "i"), _check_pose(r, "relative"), _check_covariance(c, "covariance"))
                 for i, r, c in loops]
        if any(i == node for i, _, _ in loops):
            raise ValueError("a loop closure needs two distinct nodes")
        pc = self._values.atPose2(node)
        if not loops:
            return self._poses[node].copy(), self.covariance(node)
        self._calls.append(("conditioned", node, [(i, r.copy(), c.copy()) for i, r, c in loops]))
        keys = sorted({i for i, _, _ in loops}) + [node]
        block = {k: 3 * n for n, k in enumerate(keys)}
        joint = self._isam.jointMarginalCovariance(keys)
        prior = np.block([[joint.at(a, b) for b in keys] for a in keys])
        H = np.zeros((3 * len(loops), 3 * len(keys)))
        innovation = np.empty(3 * len(loops))
        noise = np.zeros((3 * len(loops), 3 * len(loops)))
        for m, (i, rel, cov) in enumerate(loops):
            r = self._values.atPose2(i).between(pc)
            rows = slice(3 * m, 3 * m + 3)
            # as in relative(): (pi·Exp(a))⁻¹ (pc·Exp(b)) ≈ r·Exp(b − Ad(r⁻¹) a)
            H[rows, block[i]:block[i] + 3] = -r.inverse().AdjointMap()
            H[rows, block[node]:block[node] + 3] = np.eye(3)
            innovation[rows] = gtsam.Pose2.Logmap(r.between(gtsam.Pose2(*rel)))
            noise[rows, rows] = _to_tangent(cov, rel[2])
        S = H @ prior @ H.T + noise
        gain = np.linalg.solve(S, H @ prior).T
        step = gain @ innovation
        posterior = prior - gain @ S @ gain.T
        pose = pc.compose(gtsam.Pose2.Expmap(step[-3:]))
        out = np.array([pose.x(), pose.y(), pose.theta()])
        return out, _from_tangent(posterior[-3:, -3:], out[2])

    def solution_chi2(self) -> float:
        """χ² of the solution: the sum of the squared whitened residuals (2 × GTSAM's
        error) of the factors it minimises — the prior, the odometry factors and the loop
        factors (robust ones; with ``gnc`` the inliers) — at the current estimate. Over the
        graph's redundancy (3 per loop closure it keeps) it is the a-posteriori variance
        factor: about 1 when the constraints' covariances are right."""
        return 2.0 * float(self._solved_graph().error(self._values))

    def loop_errors(self) -> np.ndarray:
        """Whitened residual norm (loops,) of each loop factor at the current estimate,
        under its Gaussian model (σ units), inliers and outliers alike."""
        return self._loop_errors_at(self._values)

    def _loop_errors_at(self, values: gtsam.Values) -> np.ndarray:
        return np.array([np.linalg.norm(f.noiseModel().whiten(f.unwhitenedError(values)))
                         for f in self._loop_factors], dtype=float)

    def loop_weights(self) -> np.ndarray:
        """Weight (loops,) of each loop factor in the solution: the Cauchy kernel's at the
        current estimate (1 for a loop that agrees with the graph, → 0 for one it
        rejects); with ``gnc`` 1 for an inlier, 0 for a loop closure the last
        classification set aside; 1 without a guard."""
        if self.loop_outliers == "gnc":
            return self._loop_inlier.astype(float)
        if self.loop_outliers is None:
            return np.ones(len(self._loop_factors))
        return np.array([self._kernel.weight(e) for e in self.loop_errors()], dtype=float)
