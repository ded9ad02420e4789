"""The pose graph against an independent dense least-squares oracle (scipy), the robust
kernel against a false loop closure, the covariance convention against bsslam's
first-order propagation, and incremental against batch solving."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from scipy.optimize import least_squares

from bsslam import se2
from bsslam.errors import FilterError
from bsslam.submaps.pose_graph import PoseGraph

WIDE = 1e6  # a Cauchy kernel this wide is Gaussian for every residual here


# --- an independent model of the graph's cost --------------------------------------------


def se2_log(pose: np.ndarray) -> np.ndarray:
    """Tangent vector (vx, vy, ω) of a pose (x, y, θ): the inverse of the SE(2) exponential."""
    x, y, w = pose
    if abs(w) < 1e-9:
        return np.array([x, y, w])
    a, b = np.sin(w) / w, (1.0 - np.cos(w)) / w
    V = np.array([[a, -b], [b, a]])
    return np.concatenate([np.linalg.solve(V, [x, y]), [w]])


def whitener(covariance: np.ndarray, theta: float) -> np.ndarray:
    """W with WᵀW = Σ_tangent⁻¹, for a measurement with heading θ whose coordinate
    covariance is ``covariance``: a tangent ξ moves the coordinates by blockdiag(R(θ), 1) ξ."""
    c, s = np.cos(theta), np.sin(theta)
    B = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    tangent = B.T @ covariance @ B
    return np.linalg.cholesky(np.linalg.inv(tangent)).T


def residuals(x: np.ndarray, problem: dict, kernel: float) -> np.ndarray:
    """All whitened residuals at the stacked coordinates x (3n,). A loop's residual e is
    rescaled to norm sqrt(2 ρ(|e|)), ρ the Cauchy loss k²/2 ln(1 + d²/k²), so that half the
    sum of squares is the robust cost."""
    P = x.reshape(-1, 3)
    out = [problem["W0"] @ se2_log(se2.between(problem["first"], P[0]))]
    for (i, j, z, W) in problem["odometry"]:
        out.append(W @ se2_log(se2.between(z, se2.between(P[i], P[j]))))
    for (i, j, z, W) in problem["loops"]:
        e = W @ se2_log(se2.between(z, se2.between(P[i], P[j])))
        d = np.linalg.norm(e)
        scale = np.sqrt(kernel ** 2 * np.log1p((d / kernel) ** 2)) / d if d > 0 else 1.0
        out.append(scale * e)
    return np.concatenate(out)


def loop_norms(x: np.ndarray, problem: dict) -> np.ndarray:
    P = x.reshape(-1, 3)
    return np.array([np.linalg.norm(W @ se2_log(se2.between(z, se2.between(P[i], P[j]))))
                     for (i, j, z, W) in problem["loops"]])


def random_covariance(rng, sigmas) -> np.ndarray:
    """A correlated, anisotropic covariance with roughly the given σ."""
    A = np.diag(sigmas) @ (np.eye(3) + 0.4 * rng.uniform(-1, 1, (3, 3)))
    return A @ A.T + 1e-3 * np.diag(np.square(sigmas))


def make_problem(seed: int, n: int = 7, loops=((0, 5), (1, 6))) -> dict:
    """A small noisy graph: a curved trajectory, odometry and loops with noisy measurements
    and correlated covariances."""
    rng = np.random.default_rng(seed)
    steps = np.column_stack([rng.uniform(0.8, 1.5, n - 1), rng.uniform(-0.3, 0.3, n - 1),
                             rng.uniform(0.5, 1.1, n - 1)])
    truth = [np.array([0.3, -0.2, 0.4])]
    for u in steps:
        truth.append(se2.compose(truth[-1], u))
    truth = np.array(truth)
    first_cov = random_covariance(rng, [0.01, 0.01, 0.005])
    problem = {"first": truth[0], "first_cov": first_cov, "W0": whitener(first_cov, truth[0, 2]),
               "odometry": [], "loops": [], "truth": truth, "n": n}
    for kind, pairs, sig in (("odometry", [(k, k + 1) for k in range(n - 1)], [0.03, 0.02, 0.01]),
                             ("loops", list(loops), [0.05, 0.05, 0.02])):
        for i, j in pairs:
            cov = random_covariance(rng, sig)
            z = se2.compose(se2.between(truth[i], truth[j]), rng.multivariate_normal(np.zeros(3), cov))
            problem[kind].append((i, j, z, whitener(cov, z[2])))
            problem.setdefault(kind + "_cov", []).append(cov)
    return problem


def build(problem: dict, kernel: float, incremental: bool = False, **kwargs) -> PoseGraph:
    graph = PoseGraph(problem["first"], problem["first_cov"], robust_kernel_width=kernel, **kwargs)
    pending = list(zip(problem["loops"], problem["loops_cov"]))
    for (i, j, z, _), cov in zip(problem["odometry"], problem["odometry_cov"]):
        assert graph.add_node(z, cov) == j
        if incremental:
            graph.optimize()
            for (a, b, zl, _), cl in [p for p in pending if max(p[0][:2]) <= j]:
                graph.add_loop(a, b, zl, cl)
                graph.optimize()
            pending = [p for p in pending if max(p[0][:2]) > j]
    for (a, b, zl, _), cl in pending:
        graph.add_loop(a, b, zl, cl)
    graph.optimize()
    return graph


def solve_oracle(problem: dict, kernel: float) -> np.ndarray:
    """Dense least squares from the odometry chain (the graph's own initial guess)."""
    chain = [problem["first"]]
    for (_, _, z, _) in problem["odometry"]:
        chain.append(se2.compose(chain[-1], z))
    sol = least_squares(residuals, np.ravel(chain), args=(problem, kernel), method="lm",
                        xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert sol.success
    return sol.x


def assert_covariance_close(got, expected, rtol):
    """Elementwise within ``rtol`` of the matrix's largest entry: small correlations are
    differences of large products, relative precision on them alone means little."""
    np.testing.assert_allclose(got, expected, rtol=0, atol=rtol * np.abs(expected).max())


def angle_diff(a, b):
    return np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b))))


def assert_poses_close(P, Q, atol):
    np.testing.assert_allclose(P[:, :2], Q[:, :2], atol=atol, rtol=0)
    np.testing.assert_allclose(angle_diff(P[:, 2], Q[:, 2]), 0.0, atol=atol)


# --- 1. the optimum ------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("kernel", [WIDE, 3.0, 1.0])
def test_optimum_matches_dense_least_squares(seed, kernel):
    problem = make_problem(seed)
    expected = solve_oracle(problem, kernel)
    # An active kernel's weights are refreshed only at relinearisation, so its optimum is
    # as exact as the threshold (Gaussian factors converge quadratically at the default).
    graph = build(problem, kernel, relinearize_threshold=1e-4 if kernel == WIDE else 1e-6)
    assert graph.size == problem["n"] and graph.loop_count == 2
    assert_poses_close(graph.poses(), expected.reshape(-1, 3), atol=1e-6)
    # The loops' residuals and weights are those of the oracle's optimum.
    errors = loop_norms(expected, problem)
    np.testing.assert_allclose(graph.loop_errors(), errors, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(graph.loop_weights(), 1.0 / (1.0 + (errors / kernel) ** 2), rtol=1e-4)
    # The odometry chain is not already the answer (the test would pass vacuously).
    chain = build(problem | {"loops": [], "loops_cov": []}, kernel).poses()
    assert np.abs(chain[:, :2] - expected.reshape(-1, 3)[:, :2]).max() > 1e-3


def test_solution_chi2_is_the_weighted_disagreement_of_a_loop_with_the_odometry():
    # One odometry edge and one loop closure over it that disagree by δ: the optimum splits
    # δ by the covariances, and the χ² left is δᵀ (Σ_odometry + Σ_loop)⁻¹ δ (linear:
    # headings zero, δ a translation; node 0 held by a prior of σ 1 µm).
    odo_cov = np.diag(np.square([0.05, 0.02, 0.01]))
    loop_cov = np.diag(np.square([0.03, 0.04, 0.02]))
    delta = np.array([0.08, -0.05, 0.0])
    graph = PoseGraph(np.zeros(3), np.eye(3) * 1e-12, loop_outliers=None)
    graph.add_node(np.array([2.0, 0.0, 0.0]), odo_cov)
    graph.optimize()
    assert graph.solution_chi2() == pytest.approx(0.0, abs=1e-12)
    graph.add_loop(0, 1, np.array([2.0, 0.0, 0.0]) + delta, loop_cov)
    graph.optimize()
    expected = delta @ np.linalg.solve(odo_cov + loop_cov, delta)
    # (to iSAM2's convergence: it stops relinearising at its threshold)
    assert graph.solution_chi2() == pytest.approx(expected, rel=1e-4)
    # neither covariance alone would give it
    assert expected / (delta @ np.linalg.solve(loop_cov, delta)) < 0.5


# --- 2. a false loop closure ---------------------------------------------------------------


def square_problem(seed: int) -> dict:
    """A 4 m square walked in 1 m steps (17 nodes, node 16 back at node 0) with drift,
    and three true loop closures."""
    rng = np.random.default_rng(seed)
    steps = np.array([[1.0, 0.0, np.pi / 2 if k % 4 == 3 else 0.0] for k in range(16)])
    truth = [np.zeros(3)]
    for u in steps:
        truth.append(se2.compose(truth[-1], u))
    truth = np.array(truth)
    odo_cov = np.diag(np.square([0.02, 0.02, 0.01]))
    loop_cov = np.diag(np.square([0.05, 0.05, 0.02]))
    odometry = [se2.compose(u, rng.multivariate_normal(np.zeros(3), odo_cov)) for u in steps]
    loops = []
    for i, j in ((0, 16), (1, 15), (5, 11)):
        loops.append((i, j, se2.compose(se2.between(truth[i], truth[j]),
                                        rng.multivariate_normal(np.zeros(3), loop_cov))))
    false = (3, 10, se2.compose(se2.between(truth[3], truth[10]), np.array([1.5, -1.0, 0.6])))
    return {"odometry": odometry, "odo_cov": odo_cov, "loops": loops, "loop_cov": loop_cov,
            "false": false}


def square_graph(problem: dict, with_false: str | None, **graph_args) -> PoseGraph:
    """The square's graph (``graph_args`` for :class:`PoseGraph`), its false loop closure
    added first, together with the true ones, last, or not at all (None)."""
    graph = PoseGraph(np.zeros(3), **graph_args)
    for u in problem["odometry"]:
        graph.add_node(u, problem["odo_cov"])
    if with_false == "first":
        graph.add_loop(*problem["false"], problem["loop_cov"])
        graph.optimize()
    for loop in problem["loops"]:
        graph.add_loop(*loop, problem["loop_cov"])
    if with_false == "together":
        graph.add_loop(*problem["false"], problem["loop_cov"])
    graph.optimize()
    if with_false == "last":
        graph.add_loop(*problem["false"], problem["loop_cov"])
        graph.optimize()
    return graph


@pytest.mark.parametrize("when", ["first", "together", "last"])
@pytest.mark.parametrize("seed", [0, 1])
def test_false_loop_is_down_weighted(seed, when):
    problem = square_problem(seed)
    clean = square_graph(problem, None, robust_kernel_width=3.0)
    graph = square_graph(problem, when, robust_kernel_width=3.0)
    false_id = 0 if when == "first" else 3
    weights = graph.loop_weights()
    assert weights[false_id] < 0.1
    assert np.all(np.delete(weights, false_id) > 0.5)
    assert graph.loops[false_id] == (3, 10)
    assert_poses_close(graph.poses(), clean.poses(), atol=0.03)
    # Without the kernel the false loop wrecks the map: the kernel is what saves it.
    gaussian = square_graph(problem, when, robust_kernel_width=WIDE)
    assert np.abs(gaussian.poses()[:, :2] - clean.poses()[:, :2]).max() > 0.3


# --- 3. covariances ------------------------------------------------------------------------


def test_chain_marginal_is_first_order_composition():
    """Prior on node 0 and one odometry factor: node 1's marginal is se2's first-order
    propagation, in bsslam's coordinate convention. Headings and correlations are
    non-trivial so that a missing or inverted frame rotation shows."""
    rng = np.random.default_rng(3)
    a, z = np.array([1.0, -2.0, 1.1]), np.array([0.8, 0.3, 0.7])
    cov_a = random_covariance(rng, [0.2, 0.05, 0.03])
    cov_z = random_covariance(rng, [0.1, 0.02, 0.05])
    graph = PoseGraph(a, cov_a)
    graph.add_node(z, cov_z)
    graph.optimize()
    pose_1, cov_1 = se2.compose_with_covariance(a, cov_a, z, cov_z)
    np.testing.assert_allclose(graph.pose(1), pose_1, atol=1e-12)
    np.testing.assert_allclose(graph.covariance(0), cov_a, rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(graph.covariance(1), cov_1, rtol=1e-8, atol=1e-14)
    rel, cov_rel = graph.relative(0, 1)
    np.testing.assert_allclose(rel, z, atol=1e-12)
    np.testing.assert_allclose(cov_rel, cov_z, rtol=1e-8, atol=1e-14)


def coordinate_covariance(x: np.ndarray, problem: dict) -> np.ndarray:
    """(JᵀJ)⁻¹ (3n, 3n) of the whitened residuals' Jacobian in pose coordinates, by central
    differences: the Laplace covariance of the Gaussian problem at its optimum."""
    h = 1e-6
    J = np.column_stack([(residuals(x + h * e, problem, WIDE) - residuals(x - h * e, problem, WIDE)) / (2 * h)
                         for e in np.eye(x.size)])
    return np.linalg.inv(J.T @ J)


def rel_difference(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """between(u_i, u_j) − between(v_i, v_j) for stacked pose pairs (6,), heading wrapped."""
    d = se2.between(u[:3], u[3:]) - se2.between(v[:3], v[3:])
    return np.r_[d[:2], angle_diff(d[2], 0.0)]


@pytest.mark.parametrize("seed", [0, 4])
def test_marginals_match_dense_laplace_covariance(seed):
    problem = make_problem(seed)
    x = solve_oracle(problem, WIDE)
    sigma = coordinate_covariance(x, problem)
    graph = build(problem, WIDE)
    P = x.reshape(-1, 3)
    for i in range(problem["n"]):
        assert_covariance_close(graph.covariance(i), sigma[3 * i:3 * i + 3, 3 * i:3 * i + 3], 1e-4)
    for i, j in ((2, 5), (6, 1), (3, 4), (0, 6)):
        idx = np.r_[3 * i:3 * i + 3, 3 * j:3 * j + 3]
        v0 = np.concatenate([P[i], P[j]])
        G = np.column_stack([rel_difference(v0 + 1e-6 * e, v0 - 1e-6 * e) / 2e-6 for e in np.eye(6)])
        expected = G @ sigma[np.ix_(idx, idx)] @ G.T
        got_rel, got_cov = graph.relative(i, j)
        np.testing.assert_allclose(got_rel[:2], se2.between(P[i], P[j])[:2], atol=1e-6)
        np.testing.assert_allclose(angle_diff(got_rel[2], se2.between(P[i], P[j])[2]), 0.0, atol=1e-6)
        assert_covariance_close(got_cov, expected, 1e-4)
    # Correlation matters: the relative covariance is not the sum of the two marginals.
    _, cov_26 = graph.relative(2, 6)
    assert np.trace(cov_26) < 0.9 * np.trace(graph.covariance(2) + graph.covariance(6))


@pytest.mark.parametrize("seed", [0, 4])
def test_conditioning_on_loops_matches_the_graph_that_holds_them(seed):
    """``conditioned`` gives the node's pose and marginal as the graph with those loop
    closures in it would (against the dense oracle of the whole problem: a single linearised
    update, so to the correction's second order), and leaves the graph as it was."""
    problem = make_problem(seed, n=7, loops=((0, 4), (1, 6), (2, 6)))
    x = solve_oracle(problem, WIDE)
    sigma = coordinate_covariance(x, problem)
    without = {key: problem[key] for key in problem}
    without["loops"], without["loops_cov"] = problem["loops"][:1], problem["loops_cov"][:1]
    graph = build(without, WIDE)
    before_poses, before_cov = graph.poses(), graph.covariance(6)
    loops = [(i, z, cov) for (i, _, z, _), cov in zip(problem["loops"][1:], problem["loops_cov"][1:])]
    pose, cov = graph.conditioned(6, loops)
    expected = x.reshape(-1, 3)[6]
    moved = np.linalg.norm(before_poses[6][:2] - expected[:2])
    assert moved > 0.01                         # the loops move the node …
    np.testing.assert_allclose(pose[:2], expected[:2], atol=0.05 * moved)   # … where the oracle puts it
    assert abs(angle_diff(pose[2], expected[2])) < 1e-3
    # linearised where the graph stood, not at the optimum: a few per cent of the largest entry
    assert_covariance_close(cov, sigma[18:21, 18:21], 0.05)
    assert np.trace(cov) < 0.8 * np.trace(before_cov)
    # the graph did not take the loops
    np.testing.assert_array_equal(graph.poses(), before_poses)
    np.testing.assert_array_equal(graph.covariance(6), before_cov)
    assert graph.loop_count == 1
    # no loops: the graph's own estimate; a loop from the node to itself is refused
    np.testing.assert_array_equal(graph.conditioned(6, [])[0], before_poses[6])
    with pytest.raises(ValueError):
        graph.conditioned(6, [(6, loops[0][1], loops[0][2])])
    # the query is replayed on unpickling like the other marginal queries
    back = pickle.loads(pickle.dumps(graph))
    np.testing.assert_array_equal(back.covariance(5), graph.covariance(5))


# --- 4. incremental ------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 5])
def test_incremental_equals_batch(seed):
    problem = make_problem(seed, n=8, loops=((0, 4), (1, 7), (2, 6)))
    # A tight threshold: both runs must get to the (robust) optimum, not only near it.
    batch = build(problem, 3.0, relinearize_threshold=1e-6)
    incremental = build(problem, 3.0, incremental=True, relinearize_threshold=1e-6)
    assert_poses_close(incremental.poses(), batch.poses(), atol=1e-6)
    # Loop ids follow the order of addition, which differs: compare by node pair.
    order = [incremental.loops.index(pair) for pair in batch.loops]
    np.testing.assert_allclose(incremental.loop_weights()[order], batch.loop_weights(), rtol=1e-5)
    for i in range(problem["n"]):
        assert_covariance_close(incremental.covariance(i), batch.covariance(i), 1e-4)


# --- API edges -----------------------------------------------------------------------------


def test_queued_nodes_read_their_initial_estimate_and_need_optimize_for_marginals():
    graph = PoseGraph([0.0, 0.0, 0.0])
    graph.add_node([1.0, 0.0, np.pi / 2], 1e-4 * np.eye(3))
    graph.add_node([1.0, 0.0, 0.0], 1e-4 * np.eye(3))
    np.testing.assert_allclose(graph.pose(2), [1.0, 1.0, np.pi / 2], atol=1e-12)
    with pytest.raises(RuntimeError, match="optimize"):
        graph.covariance(2)
    graph.optimize()
    np.testing.assert_allclose(graph.poses(), [[0, 0, 0], [1, 0, np.pi / 2], [1, 1, np.pi / 2]], atol=1e-9)
    assert np.all(np.diag(graph.covariance(2)) > np.diag(graph.covariance(1)))
    assert graph.loop_weights().shape == (0,) and graph.loop_errors().shape == (0,)


@pytest.mark.parametrize("call", [
    lambda g: g.add_loop(0, 0, [0, 0, 0], np.eye(3)),
    lambda g: g.add_loop(0, 5, [0, 0, 0], np.eye(3)),
    lambda g: g.add_node([0, 0], np.eye(3)),
    lambda g: g.add_node([0, 0, np.nan], np.eye(3)),
    lambda g: g.add_node([0, 0, 0], -np.eye(3)),
    lambda g: g.add_node([0, 0, 0], np.triu(np.ones((3, 3)))),
    lambda g: g.pose(3),
])
def test_invalid_input_is_rejected(call):
    graph = PoseGraph([0.0, 0.0, 0.0])
    graph.add_node([1.0, 0.0, 0.0], np.eye(3))
    with pytest.raises(ValueError):
        call(graph)


def _square_graph(**graph_args) -> PoseGraph:
    """Four nodes around a 2 m square, optimised, no loop closure yet."""
    g = PoseGraph(np.zeros(3), **graph_args)
    for _ in range(3):
        g.add_node(np.array([2.0, 0.0, np.pi / 2]), np.diag([1e-4, 1e-4, 1e-5]))
    g.optimize()
    return g


def _fail(graph: PoseGraph, *, batch_too: bool, when_loop_pending: bool = True) -> list:
    """Make the next iSAM2 update (with a loop pending) fail as gtsam does on an ill-posed
    system, and with ``batch_too`` the batch re-solve as well."""
    failed = []
    message = "\nIndeterminate linear system detected while working near variable\n3 (Symbol: 3)."

    def update():
        if not failed and (graph._loop_pending or not when_loop_pending):
            failed.append("isam2")
            raise RuntimeError(message)
        PoseGraph._update(graph)

    def batch():
        if batch_too:
            failed.append("batch")
            raise RuntimeError(message)
        PoseGraph._solve_in_batch(graph)
    graph._update, graph._solve_in_batch = update, batch
    return failed


def _with_two_loops(fail=None, first=np.array([0.0, -2.0, -np.pi / 2]),
                    **graph_args) -> tuple[PoseGraph, list[int]]:
    """The square with a loop closure ``first`` (node 3 seen from node 0) optimised, then a
    node and a second loop closure (1, 4) that ``fail`` may make the next update fail on."""
    g = _square_graph(**graph_args)
    g.add_loop(0, 3, first, np.diag([1e-3, 1e-3, 1e-4]))
    g.optimize()
    g.add_node(np.array([1.0, 0.0, 0.0]), np.diag([1e-4, 1e-4, 1e-5]))
    g.add_loop(1, 4, np.array([0.0, 1.0, 0.0]), np.diag([1e-3, 1e-3, 1e-4]))
    failed = fail(g) if fail else None
    return g, g.optimize(), failed


def test_an_ill_posed_isam2_update_is_solved_in_batch_instead():
    """iSAM2 failing on a well-posed graph: the batch solution (Levenberg–Marquardt) is
    the optimum the incremental solver would have reached, and iSAM2 goes on from it."""
    g, dropped, failed = _with_two_loops(lambda g: _fail(g, batch_too=False))
    ref, _, _ = _with_two_loops()
    assert dropped == [] and failed == ["isam2"] and g.loop_count == 2
    np.testing.assert_allclose(g.poses(), ref.poses(), atol=1e-6)
    np.testing.assert_allclose(g.covariance(4), ref.covariance(4), atol=1e-8)   # entries ~1e-4 m²
    g.add_node(np.array([1.0, 0.0, 0.0]), np.diag([1e-4, 1e-4, 1e-5]))
    assert g.optimize() == [] and g.size == 6


def test_an_ill_posed_loop_closure_is_dropped_and_the_graph_rebuilt_without_it():
    g, dropped, failed = _with_two_loops(lambda g: _fail(g, batch_too=True))
    assert dropped == [1] and failed == ["isam2", "batch"]     # the second loop (id 1) went
    # the same as a graph that never had that loop, bit for bit
    ref = _square_graph()
    ref.add_loop(0, 3, np.array([0.0, -2.0, -np.pi / 2]), np.diag([1e-3, 1e-3, 1e-4]))
    ref.optimize()
    ref.add_node(np.array([1.0, 0.0, 0.0]), np.diag([1e-4, 1e-4, 1e-5]))
    ref.optimize()
    assert g.loop_count == 1 and g.loops == [(0, 3)]
    np.testing.assert_array_equal(g.poses(), ref.poses())
    np.testing.assert_array_equal(g.covariance(4), ref.covariance(4))
    # and it goes on: a later loop closure is taken, and the graph pickles without the dropped one
    g.add_loop(1, 4, np.array([0.0, 1.0, 0.0]), np.diag([1e-3, 1e-3, 1e-4]))
    assert g.optimize() == []
    back = pickle.loads(pickle.dumps(g))
    np.testing.assert_array_equal(back.poses(), g.poses())
    assert back.loops == [(0, 3), (1, 4)]


def test_an_ill_posed_graph_without_a_new_loop_closure_is_a_filter_error():
    g = _square_graph()
    g.add_node(np.array([1.0, 0.0, 0.0]), np.diag([1e-4, 1e-4, 1e-5]))
    _fail(g, batch_too=True, when_loop_pending=False)
    with pytest.raises(FilterError, match="ill-posed"):
        g.optimize()


# --- 5. graduated non-convexity (loop_outliers="gnc") ----------------------------------------

#: χ²(3) at 99 %: the default classification's threshold on a loop's whitened squared residual
CHI2_3_99 = 11.345


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_gnc_keeps_true_loops_and_reaches_the_least_squares_optimum(seed):
    """True loop closures (noise drawn from their covariance) are inliers, and the solution
    is the Gaussian least-squares optimum."""
    problem = make_problem(seed)
    expected = solve_oracle(problem, WIDE)
    errors = loop_norms(expected, problem)
    assert np.all(errors ** 2 < CHI2_3_99)           # the scenario: both loops are inliers
    graph = build(problem, WIDE, loop_outliers="gnc")
    np.testing.assert_array_equal(graph.loop_weights(), [1.0, 1.0])
    assert_poses_close(graph.poses(), expected.reshape(-1, 3), atol=1e-6)
    np.testing.assert_allclose(graph.loop_errors(), errors, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("when", ["first", "together", "last"])
@pytest.mark.parametrize("seed", [0, 1])
def test_gnc_sets_a_false_loop_aside(seed, when):
    problem = square_problem(seed)
    clean = square_graph(problem, None, loop_outliers=None)
    graph = square_graph(problem, when, loop_outliers="gnc")
    false_id = 0 if when == "first" else 3
    assert graph.loops[false_id] == (3, 10)
    # set aside whether it came before the true ones (it then bent the graph alone), with
    # them or after them; the true ones are kept, and the solution is the one without it
    np.testing.assert_array_equal(graph.loop_weights(), np.where(np.arange(4) == false_id, 0.0, 1.0))
    assert_poses_close(graph.poses(), clean.poses(), atol=1e-6)
    # Taken as an inlier, the false loop wrecks the map: the classification is what saves it.
    gaussian = square_graph(problem, when, loop_outliers=None)
    assert np.abs(gaussian.poses()[:, :2] - clean.poses()[:, :2]).max() > 0.3


@pytest.mark.parametrize("seed", [0, 1])
def test_gnc_revisits_a_wrong_loop_closure_once_the_graph_contradicts_it(seed):
    """With loose odometry (σ four times the square's) a false loop closure that arrives
    alone fits the bent graph and is kept; the first true one contradicts it, and the
    classification then sets the false one aside and keeps the true ones."""
    problem = square_problem(seed)
    graph = PoseGraph(np.zeros(3), loop_outliers="gnc")
    for u in problem["odometry"]:
        graph.add_node(u, 16.0 * problem["odo_cov"])
    graph.optimize()
    weights = []
    for loop in [problem["false"]] + problem["loops"]:
        graph.add_loop(*loop, problem["loop_cov"])
        graph.optimize()
        weights.append(graph.loop_weights().tolist())
    assert weights == [[1.0], [0.0, 1.0], [0.0, 1.0, 1.0], [0.0, 1.0, 1.0, 1.0]]
    errors = graph.loop_errors() ** 2
    assert errors[0] > CHI2_3_99 and np.all(errors[1:] < CHI2_3_99)


@pytest.mark.parametrize("seed", [0, 5])
def test_gnc_incremental_equals_batch(seed):
    problem = make_problem(seed, n=8, loops=((0, 4), (1, 7), (2, 6)))
    batch = build(problem, WIDE, loop_outliers="gnc", relinearize_threshold=1e-6)
    incremental = build(problem, WIDE, incremental=True, loop_outliers="gnc", relinearize_threshold=1e-6)
    assert_poses_close(incremental.poses(), batch.poses(), atol=1e-6)
    order = [incremental.loops.index(pair) for pair in batch.loops]
    np.testing.assert_array_equal(incremental.loop_weights()[order], batch.loop_weights())
    for i in range(problem["n"]):
        assert_covariance_close(incremental.covariance(i), batch.covariance(i), 1e-4)


def test_gnc_graph_pickles_to_the_same_numbers():
    problem = square_problem(1)
    graph = square_graph(problem, "together", loop_outliers="gnc")
    back = pickle.loads(pickle.dumps(graph))
    np.testing.assert_array_equal(back.poses(), graph.poses())
    np.testing.assert_array_equal(back.loop_weights(), graph.loop_weights())
    np.testing.assert_array_equal(back.covariance(7), graph.covariance(7))


def test_an_ill_posed_gnc_update_is_solved_in_batch_with_the_same_classification():
    """iSAM2 failing after a classification: the batch re-solve classifies the same way
    (the true first loop is kept, the wildly wrong second one set aside) and reaches the
    same optimum."""
    true_first = np.array([0.0, 2.0, -np.pi / 2])
    g, dropped, failed = _with_two_loops(lambda g: _fail(g, batch_too=False), true_first, loop_outliers="gnc")
    ref, _, _ = _with_two_loops(None, true_first, loop_outliers="gnc")
    assert dropped == [] and failed == ["isam2"]
    np.testing.assert_array_equal(g.loop_weights(), [1.0, 0.0])
    np.testing.assert_array_equal(ref.loop_weights(), [1.0, 0.0])
    assert_poses_close(g.poses(), ref.poses(), atol=1e-6)


def test_invalid_guard_settings_are_rejected():
    for kwargs in ({"loop_outliers": "huber"}, {"robust_kernel_width": 0.0}, {"loop_inlier_probability": 1.0}):
        with pytest.raises(ValueError):
            PoseGraph(np.zeros(3), **kwargs)


def test_a_long_badly_conditioned_chain_is_solved():
    """200 submaps without a loop closure, each edge's lateral σ 0.1 mm and heading σ
    0.1 rad: iSAM2's Cholesky called this indeterminate at the third node (the campus's
    chain alone at its 94th); the heading marginal of the last node is exactly √200 × 0.1
    rad (headings add along a chain) and the poses are the chain's composition."""
    rng = np.random.default_rng(0)
    graph = PoseGraph(np.zeros(3))
    pose = np.zeros(3)
    for _ in range(200):
        step = np.array([4.0, 0.0, rng.uniform(-0.5, 0.5)])
        graph.add_node(step, np.diag([0.05 ** 2, 1e-4 ** 2, 0.1 ** 2]))
        pose = se2.compose(pose, step)
        assert graph.optimize() == []
    np.testing.assert_allclose(np.sqrt(graph.covariance(200)[2, 2]), np.sqrt(200) * 0.1, rtol=1e-6)
    assert_poses_close(graph.poses()[-1:], pose[None, :], atol=1e-6)
