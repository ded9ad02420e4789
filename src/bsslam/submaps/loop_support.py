"""Pairwise consistency of loop closures (``submaps.loop_support_submaps`` > 0): verified
matches vote on each other before they enter the pose graph.

Two loop closures a (query k seen from reference i) and b (query l seen from reference j)
close a cycle with the submaps' own odometry-like constraints:
i → k (a), k → l (the chain of submaps between them), l → j (b reversed), j → i (the chain
again). Both right, the cycle composes to the identity within its covariance; one of them
wrong, it does not — unless the chains are so uncertain that their covariance admits
anything, which is why only matches whose references and queries are both within
``reach`` submaps of each other are compared, and only cycles precise enough to tell two
distinct alignments apart count as agreeing (the idea of Pairwise Consistency
Maximisation, Mangelson et al. 2018, restricted to informative neighbours); a cycle
beyond its 99 % region always disagrees.

Why: a match that passes every local check can still be wrong — a building turned by 90°,
a facade's copy — and the robust kernel of the graph cannot tell it from drift when the
graph is uncertain. A right match is seldom alone: the robot that comes back to a place
stays there for a few submaps, and each of them matches the old ones. On the Freiburg
campus (three runs, every accepted loop closure against the reference) 97–99 % of the
right ones had a consistent neighbour, and the wrong ones 7–68 m off and turned by ~90°
had none. In a building with few loop closures, though, a right one is often alone
(Acapulco: 6 of 17), which is why the vote is off by default.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bsslam.chi2 import chi2_quantile
from bsslam.se2 import compose, compose_with_covariance, inverse, inverse_with_covariance

#: χ²(3) at 99 %: a cycle within this squared Mahalanobis distance of the identity is
#: consistent.
CONSISTENT_CHI2 = chi2_quantile(0.99, 3)


@dataclass(frozen=True)
class LoopEdge:
    """A verified match between two submaps.

    Attributes:
        reference, query: the submaps (graph nodes).
        relative: (3,) the query's base in the reference's frame (x m, y m, φ rad).
        covariance: (3, 3) its covariance (m², m·rad, rad²).
        rival: (3,) the best alignment the match's search found distinct from
            ``relative`` that its covariance does not admit (the runner-up: a copy of the
            structure), or None when the search window held none.
    """

    reference: int
    query: int
    relative: np.ndarray
    covariance: np.ndarray
    rival: np.ndarray | None = None


def chain(edges: Sequence[tuple[np.ndarray, np.ndarray]], i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
    """Node ``j``'s pose in node ``i``'s frame composed along the odometry-like
    constraints, and its first-order covariance.

    Args:
        edges: ``edges[m]`` = ((3,) pose of node m+1 in node m's frame, (3, 3) covariance),
            for every m < max(i, j).
    """
    lo, hi = min(i, j), max(i, j)
    pose, cov = np.zeros(3), np.zeros((3, 3))
    for m in range(lo, hi):
        pose, cov = compose_with_covariance(pose, cov, *edges[m])
    return (pose, cov) if i <= j else inverse_with_covariance(pose, cov)


def cycle(a: LoopEdge, b: LoopEdge, edges: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """The cycle a, chain(a.query → b.query), b⁻¹, chain(b.reference → a.reference): (3,)
    its composition (the identity if all four are right) and (3, 3) its first-order
    covariance (the four parts taken as independent)."""
    pose, cov = compose_with_covariance(a.relative, a.covariance, *chain(edges, a.query, b.query))
    pose, cov = compose_with_covariance(pose, cov, *inverse_with_covariance(b.relative, b.covariance))
    return compose_with_covariance(pose, cov, *chain(edges, b.reference, a.reference))


def cycle_distance(a: LoopEdge, b: LoopEdge, edges: Sequence[tuple[np.ndarray, np.ndarray]]) -> float:
    """Squared Mahalanobis distance of :func:`cycle` from the identity."""
    return _squared_distance(*cycle(a, b, edges))


def _squared_distance(pose: np.ndarray, cov: np.ndarray) -> float:
    try:
        return float(pose @ np.linalg.solve(cov, pose))
    except np.linalg.LinAlgError:
        return float("inf")


def neighbours(a: LoopEdge, b: LoopEdge, reach: int) -> bool:
    """Both ends of ``a`` and ``b`` within ``reach`` submaps of each other (and not the
    same pair of submaps)."""
    return (abs(a.reference - b.reference) <= reach and abs(a.query - b.query) <= reach
            and (a.reference, a.query) != (b.reference, b.query))


def twins(a: LoopEdge, b: LoopEdge) -> bool:
    """Both ends of ``a`` and ``b`` in the same or consecutive submaps: their matches see
    largely the same walls (:func:`ballots`)."""
    return abs(a.reference - b.reference) <= 1 and abs(a.query - b.query) <= 1


@dataclass(frozen=True)
class Ballot:
    """One neighbour's say on a candidate match (:func:`ballots`).

    Attributes:
        other: the neighbouring match.
        cycle: (3,) the cycle candidate, chain, other⁻¹, chain (:func:`cycle`).
        chi2: its squared Mahalanobis distance from the identity under its covariance.
        rival_chi2: the same with the candidate's rival in its place, to first order
            (None without a rival).
        vote: +1 agrees, −1 disagrees, 0 cannot tell.
    """

    other: LoopEdge
    cycle: np.ndarray
    chi2: float
    rival_chi2: float | None
    vote: int


def ballots(candidate: LoopEdge, others: Sequence[LoopEdge], edges: Sequence[tuple[np.ndarray, np.ndarray]],
            reach: int, distinct_m: float, distinct_rad: float) -> list[Ballot]:
    """What each neighbouring match in ``others`` (:func:`neighbours`) says of
    ``candidate`` through the cycle they close (χ²(3) at 99 %).

    An inconsistent cycle always disagrees: the candidate and the neighbour cannot both be
    right. A consistent one agrees only when it is informative, when it can tell the
    candidate from the alignment it would be confused with. With a ``rival`` that is that
    alignment: the cycle agrees when putting the rival in the candidate's place would move
    the cycle beyond its 99 % region. Without one, any alignment distinct from it by
    ``distinct_m`` (m) in position or ``distinct_rad`` (rad) in heading: the cycle agrees
    when its 99 % region is within those. A cycle that cannot tell them apart (one through
    a submap whose filter lost itself, with a metre of uncertainty) would support either.

    Why a disagreement needs no such test: a cycle that cannot tell the candidate from its
    rival and still finds the candidate beyond its 99 % region finds the rival there too —
    it speaks against both. Skipping it made the vote lopsided: on Acapulco (perturbed
    seed 3) two matches of one submap against two neighbouring ones closed a cycle 4.7 m
    off (χ² 100); the right one, whose rival the cycle could tell apart, waited on the
    other's disagreement, and the wrong one, its rival close by, heard nothing and
    entered the graph, taking the run 1.08 m off.

    A *twin* (:func:`twins`) never agrees: consecutive submaps share the walls carried over
    between them, so a match of the next pair sees the same facade from the same place and
    aliases with the candidate rather than vouching for it (the Freiburg campus, perturbed
    seed 25: 1→52, 14.6 m off, entered on the agreement of 0→53, the same wrong alignment,
    and took the run 3.26 m off). It may still disagree."""
    scale = float(np.sqrt(CONSISTENT_CHI2))
    swap = None if candidate.rival is None else compose(candidate.rival, inverse(candidate.relative))
    result = []
    for other in others:
        if not neighbours(candidate, other, reach):
            continue
        pose, cov = cycle(candidate, other, edges)
        chi2 = _squared_distance(pose, cov)
        # the cycle starts with the candidate (reference frame): the rival in its place
        # moves the cycle by ``swap`` to first order
        rival_chi2 = None if swap is None else _squared_distance(swap, cov)
        if chi2 > CONSISTENT_CHI2:
            vote = -1
        elif twins(candidate, other):
            vote = 0
        elif rival_chi2 is not None:
            vote = int(rival_chi2 > CONSISTENT_CHI2)
        else:
            vote = int(scale * np.sqrt(np.linalg.eigvalsh(cov[:2, :2])[-1]) <= distinct_m
                       and scale * np.sqrt(cov[2, 2]) <= distinct_rad)
        result.append(Ballot(other, pose, chi2, rival_chi2, vote))
    return result


def votes(candidate: LoopEdge, others: Sequence[LoopEdge], edges: Sequence[tuple[np.ndarray, np.ndarray]],
          reach: int, distinct_m: float, distinct_rad: float) -> tuple[int, int]:
    """How many of the neighbouring matches in ``others`` agree with ``candidate`` and how
    many disagree (:func:`ballots`, which says when a cycle counts)."""
    return tally(ballots(candidate, others, edges, reach, distinct_m, distinct_rad))


def tally(cast: Sequence[Ballot]) -> tuple[int, int]:
    """(agree, disagree): the ballots voting +1 and −1."""
    vote = [b.vote for b in cast]
    return vote.count(1), vote.count(-1)
