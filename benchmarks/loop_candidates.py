"""Every loop-closure candidate of one run against the reference.

    python benchmarks/loop_candidates.py LOG [--seed N] [--all]

A benchmark, not a test. It runs LOG once with the default configuration (``--seed``
moves every range by 1 mm of seeded noise, as ``bsslam bench --perturb``) and lists each
pair of submaps the backend tried to match: the verdict (``ok`` or the first check that
failed), the verification figures (overlap m, inlier fraction, ambiguity, information
ratio), and how far the match and the pose graph's guess were from the reference's
relative pose of the two bases, with the match's Mahalanobis distance under its own
covariance. It answers: are the rejected candidates right ones (a check too strict), are
the accepted ones wrong (a check too loose), and does a wrong one's covariance admit its
error. By default only accepted matches and rejections with at least 4 m of overlap are
listed (``--all``: every candidate). ``--votes`` also prints, as the run makes them, the
votes between neighbouring matches (``submaps.loop_support_submaps``): each candidate's
agree : disagree count and, per neighbour, the cycle's χ² against its 99 % bound and the
χ² its rival would give in its place (the test a consistent cycle must pass to agree).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import bsslam.submaps.backend as backend
from bsslam.config import SLAMConfig
from bsslam.se2 import between
from bsslam.submaps import loop_support
from bsslam.trajectory import wrap_angle
from graph_consistency import reference_bases, run_log


def run_recording_candidates(log: Path, seed: int | None, config: SLAMConfig):
    """One run; returns it and every candidate as (reference submap, query submap, guess
    (3,), :class:`~bsslam.submaps.loop_closure.LoopMatch`)."""
    recorded = []
    match = backend.match_submaps

    def recording_match(reference, query, guess, covariance, window_m, window_rad, cfg):
        result = match(reference, query, guess, covariance, window_m, window_rad, cfg)
        recorded.append((reference, query, np.array(guess, dtype=float), result))
        return result

    backend.match_submaps = recording_match
    try:
        result = run_log(log, seed, config)
    finally:
        backend.match_submaps = match
    # The pair is known by the submaps' shapes: the end-of-run sweep asks the graph for
    # every pair's guess first and matches them afterwards, on threads.
    submap_of = {id(f.shape): f.index for f in result.submaps.frozen}
    return result, [(submap_of[id(r)], submap_of[id(q)], guess, m) for r, q, guess, m in recorded]


def printing_votes(candidate, others, edges, reach, distinct_m, distinct_rad):
    """:func:`bsslam.submaps.loop_support.votes`, printing its count and each neighbour's
    ballot: the cycle's χ² and size, and the χ² with the rival in its place (``–``
    without a rival)."""
    cast = loop_support.ballots(candidate, others, edges, reach, distinct_m, distinct_rad)
    agree, disagree = loop_support.tally(cast)
    if cast:
        cells = [f"{b.other.reference}→{b.other.query}: χ² {b.chi2:.1f}, {np.hypot(*b.cycle[:2]):.2f} m; "
                 f"rival χ² {'–' if b.rival_chi2 is None else f'{b.rival_chi2:.1f}'}" for b in cast]
        print(f"vote on {candidate.reference}→{candidate.query}: {agree} : {disagree} "
              f"(99 %: {loop_support.CONSISTENT_CHI2:.1f}) — " + "; ".join(cells))
    return agree, disagree


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", type=Path, help="a CARMEN log with a .gt.txt reference beside it")
    parser.add_argument("--seed", type=int, default=None, help="1 mm of range noise with this seed")
    parser.add_argument("--all", action="store_true", help="list every candidate")
    parser.add_argument("--votes", action="store_true", help="print the votes between neighbouring matches")
    args = parser.parse_args()
    if args.votes:
        backend.votes = printing_votes
    result, candidates = run_recording_candidates(args.log, args.seed, SLAMConfig())
    reference, index = reference_bases(result, args.log)
    print(f"{args.log.name}: {len(candidates)} candidates, {sum(c[3].ok for c in candidates)} accepted")
    print("| pair | verdict | overlap m | inliers | ambiguity | information ratio | match error m, ° | "
          "Mahalanobis² | guess error m, ° |")
    print("|---|---|---|---|---|---|---|---|---|")
    for i, j, guess, m in candidates:
        if not (args.all or m.ok or m.overlap_m >= 4.0) or index[i] < 0 or index[j] < 0:
            continue
        truth = between(reference.poses[index[i]], reference.poses[index[j]])
        error, guess_error = m.relative - truth, guess - truth
        error[2], guess_error[2] = wrap_angle(error[2]), wrap_angle(guess_error[2])
        maha = float(error @ np.linalg.solve(m.covariance, error)) if np.all(np.isfinite(m.covariance)) else np.nan
        print(f"| {i}→{j} | {m.reason} | {m.overlap_m:.1f} | {m.inlier_fraction:.2f} | {m.ambiguity:.2f} | "
              f"{m.information_ratio:.2g} | {np.hypot(*error[:2]):.2f}, {np.degrees(error[2]):+.1f} | {maha:.1f} | "
              f"{np.hypot(*guess_error[:2]):.2f}, {np.degrees(guess_error[2]):+.1f} |")


if __name__ == "__main__":
    main()
