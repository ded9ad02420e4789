"""Pairwise consistency of loop closures (``submaps/loop_support.py``): the cycle two
right matches close is χ²(3)-distributed under its first-order covariance, a wrong one
leaves it, and the support rule counts only neighbours."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import binom, chi2

from bsslam.se2 import between, compose, inverse, inverse_with_covariance
from bsslam.submaps.loop_support import CONSISTENT_CHI2, LoopEdge, chain, cycle_distance, votes

EDGE_SIGMA = np.array([0.05, 0.05, 0.01])      # m, m, rad: one submap's odometry-like constraint
LOOP_SIGMA = np.array([0.03, 0.03, 0.005])     # a loop closure's match


def _wrap(a):
    return np.remainder(a + np.pi, 2 * np.pi) - np.pi


def _bases(n=12, seed=0) -> np.ndarray:
    """(n, 3) true base poses of a robot driving round a loop."""
    rng = np.random.default_rng(seed)
    poses = [np.zeros(3)]
    for _ in range(n - 1):
        poses.append(compose(poses[-1], np.array([4.0, 0.0, 0.6]) + rng.normal(0, [0.3, 0.3, 0.1])))
    return np.array(poses)


def _draw(bases, rng):
    """Noisy edges and two right loop closures (0 → 8, 1 → 9), each drawn from its covariance."""
    edges = [(between(bases[m], bases[m + 1]) + rng.normal(0, EDGE_SIGMA), np.diag(EDGE_SIGMA ** 2))
             for m in range(len(bases) - 1)]
    loops = [LoopEdge(i, k, between(bases[i], bases[k]) + rng.normal(0, LOOP_SIGMA), np.diag(LOOP_SIGMA ** 2))
             for i, k in ((0, 8), (1, 9))]
    return edges, loops


def test_inverse_covariance_is_the_first_order_propagation():
    a = np.array([1.5, -0.7, 2.2])
    cov = np.array([[0.04, 0.01, 0.002], [0.01, 0.09, -0.003], [0.002, -0.003, 0.01]])
    eps = 1e-6
    J = np.column_stack([(inverse(a + d) - inverse(a - d)) / (2 * eps) for d in np.eye(3) * eps])
    pose, out = inverse_with_covariance(a, cov)
    np.testing.assert_allclose(pose, inverse(a))
    np.testing.assert_allclose(out, J @ cov @ J.T, rtol=1e-7, atol=1e-12)


def test_chain_composes_the_edges_both_ways():
    bases = _bases()
    edges = [(between(bases[m], bases[m + 1]), np.diag(EDGE_SIGMA ** 2)) for m in range(len(bases) - 1)]
    forward, cov_f = chain(edges, 2, 6)
    np.testing.assert_allclose(forward, between(bases[2], bases[6]), atol=1e-12)
    backward, cov_b = chain(edges, 6, 2)
    np.testing.assert_allclose(backward, between(bases[6], bases[2]), atol=1e-12)
    # four independent edges: the heading variance adds up
    assert cov_f[2, 2] == pytest.approx(4 * EDGE_SIGMA[2] ** 2)
    assert cov_b[2, 2] == pytest.approx(4 * EDGE_SIGMA[2] ** 2)
    np.testing.assert_array_equal(chain(edges, 3, 3)[0], np.zeros(3))


def test_two_right_loop_closures_close_a_chi2_cycle():
    """Over 400 draws of the edges and both loops from their covariances, the cycle's
    squared distance exceeds the 99 % quantile about 1 % of the time and its mean is ~3
    (a binomial bound at a 1e-6 false-alarm rate; the mean's standard error is
    √(6/400) ≈ 0.12, the bound 5 of them)."""
    bases = _bases()
    rng = np.random.default_rng(7)
    d = []
    for _ in range(400):
        edges, (a, b) = _draw(bases, rng)
        d.append(cycle_distance(a, b, edges))
    d = np.array(d)
    assert np.count_nonzero(d > CONSISTENT_CHI2) <= binom.ppf(1 - 1e-6, 400, 0.01)
    assert abs(d.mean() - chi2.mean(3)) < 0.6


@pytest.mark.parametrize("offset", [(0.5, 0.0, 0.0), (0.0, -0.4, 0.0), (0.0, 0.0, np.radians(5.0)),
                                    (8.0, 3.0, np.pi / 2)])
def test_a_wrong_loop_closure_breaks_the_cycle(offset):
    bases = _bases()
    edges, (right, _) = _draw(bases, np.random.default_rng(3))
    truth = between(bases[1], bases[9])
    wrong = LoopEdge(1, 9, compose(truth, np.array(offset)), np.diag(LOOP_SIGMA ** 2))
    assert cycle_distance(right, wrong, edges) > CONSISTENT_CHI2
    assert cycle_distance(wrong, right, edges) > CONSISTENT_CHI2


def test_support_counts_neighbours_that_agree_against_those_that_do_not():
    bases = _bases(16)
    edges = [(between(bases[m], bases[m + 1]), np.diag(EDGE_SIGMA ** 2)) for m in range(len(bases) - 1)]

    def loop(i, k, shift=(0.0, 0.0)):
        """A match of submap k against submap i; with ``shift`` (m, map frame) against a
        copy of i's walls that far away."""
        return LoopEdge(i, k, between(bases[i], bases[k] + np.r_[shift, 0.0]), np.diag(LOOP_SIGMA ** 2))

    def count(candidate, others, graph_edges=edges, distinct=(np.inf, np.inf)):
        return votes(candidate, others, graph_edges, 3, *distinct)

    candidate = loop(1, 9)
    assert count(candidate, [candidate]) == (0, 0)                   # alone: itself does not vote
    assert count(candidate, [candidate, loop(3, 10)]) == (1, 0)      # a right neighbour agrees
    # a twin (both ends in the next submaps) sees the same walls: it may not agree ...
    assert count(candidate, [loop(2, 10)]) == (0, 0)
    assert count(loop(1, 9, (6.0, 0.0)), [loop(2, 10, (6.0, 0.0))]) == (0, 0)   # nor alias a wrong one in
    # ... but may disagree
    assert count(candidate, [loop(2, 10, (1.0, 0.0))]) == (0, 1)
    # a right match beyond the reach does not vote; a wrong neighbour disagrees
    assert count(candidate, [loop(5, 13)]) == (0, 0)
    assert count(candidate, [loop(3, 10, (1.0, 0.0))]) == (0, 1)
    # more neighbours contradict it than agree: it is the odd one out
    many = [loop(3, 10), loop(0, 11, (1.0, 0.0)), loop(3, 11, (1.0, 0.0))]
    assert count(candidate, many) == (1, 2)
    # two matches against the same copy agree with each other: the vote cannot tell a
    # consistent pair of wrong ones (the graph's robust kernel is left with those)
    assert count(many[1], many[1:]) == (1, 0)
    # a cycle through a submap that lost itself (1 m, 0.3 rad of σ between submaps 1 and 2)
    # cannot tell distinct alignments apart: it does not vote; precise edges do
    lost = list(edges)
    lost[1] = (edges[1][0], np.diag([1.0, 1.0, 0.09]))
    distinct = (0.5, np.radians(10.0))
    assert count(candidate, [loop(3, 10, (1.0, 0.0))], edges, distinct) == (0, 1)
    assert count(candidate, [loop(3, 10, (1.0, 0.0))], lost, distinct) == (0, 0)


def test_a_cycle_votes_when_it_can_tell_the_match_from_its_rival():
    """With the match's runner-up known, a cycle votes when putting the rival in the
    match's place would leave the cycle's 99 % region: a coarse cycle (through a submap
    whose filter lost itself) can still tell a match from a copy 8 m away, not from one
    0.6 m away (the matcher's rivals are at least ``loop_distinct_m`` apart); without a
    rival the fixed distinct thresholds decide, as before."""
    bases = _bases(16)
    edges = [(between(bases[m], bases[m + 1]), np.diag(EDGE_SIGMA ** 2)) for m in range(len(bases) - 1)]
    lost = list(edges)
    lost[1] = (edges[1][0], np.diag([1.0, 1.0, 0.09]))
    distinct = (0.5, np.radians(10.0))

    def loop(i, k, shift=(0.0, 0.0), rival=None):
        relative = between(bases[i], bases[k] + np.r_[shift, 0.0])
        return LoopEdge(i, k, relative, np.diag(LOOP_SIGMA ** 2),
                        None if rival is None else compose(relative, np.array(rival)))

    far, near = (8.0, 3.0, np.pi / 2), (0.6, 0.0, 0.0)
    assert votes(loop(1, 9), [loop(3, 10)], lost, 3, *distinct) == (0, 0)            # no rival: too coarse
    assert votes(loop(1, 9, rival=far), [loop(3, 10)], lost, 3, *distinct) == (1, 0)
    assert votes(loop(1, 9, rival=near), [loop(3, 10)], lost, 3, *distinct) == (0, 0)
    # the copy 8 m away as the candidate, the truth its rival: the neighbour disagrees
    copy = dataclasses.replace(loop(1, 9, shift=(8.0, 0.0)), rival=loop(1, 9).relative)
    assert votes(copy, [loop(3, 10)], lost, 3, *distinct) == (0, 1)
    # precise edges tell the far rival apart too
    assert votes(loop(1, 9, rival=far), [loop(3, 10)], edges, 3, *distinct) == (1, 0)


def test_an_inconsistent_cycle_disagrees_whatever_the_rival():
    """Two matches of one query against neighbouring references, 4 m apart: each cycle
    through the other is far outside its 99 % region, so each disagrees with the other —
    also for the wrong one, whose rival lies so close that no cycle could tell them apart
    (before, that cycle did not vote and the wrong match entered unopposed). A consistent
    cycle that cannot tell a match from its rival still does not agree."""
    bases = _bases(16)
    edges = [(between(bases[m], bases[m + 1]), np.diag(EDGE_SIGMA ** 2)) for m in range(len(bases) - 1)]
    right = LoopEdge(12, 14, between(bases[12], bases[14]), np.diag(LOOP_SIGMA ** 2),
                     rival=compose(between(bases[12], bases[14]), np.array([8.0, 0.0, 0.0])))
    relative = compose(between(bases[11], bases[14]), np.array([4.0, 0.0, 0.0]))
    wrong = LoopEdge(11, 14, relative, np.diag(LOOP_SIGMA ** 2), rival=compose(relative, np.array([0.01, 0.0, 0.0])))
    assert cycle_distance(wrong, right, edges) > 100 * CONSISTENT_CHI2
    assert votes(right, [wrong], edges, 3, 0.5, np.radians(10.0)) == (0, 1)
    assert votes(wrong, [right], edges, 3, 0.5, np.radians(10.0)) == (0, 1)
    # a right neighbour of the right match: consistent, but a rival 1 cm away is not told apart
    near_rival = dataclasses.replace(right, rival=compose(right.relative, np.array([0.01, 0.0, 0.0])))
    other = LoopEdge(10, 14, between(bases[10], bases[14]), np.diag(LOOP_SIGMA ** 2))
    assert votes(near_rival, [other], edges, 3, 0.5, np.radians(10.0)) == (0, 0)
    assert votes(right, [other], edges, 3, 0.5, np.radians(10.0)) == (1, 0)
