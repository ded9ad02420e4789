"""The compiled inner loop of the occupancy grid: every beam of every scan walked through
the cells it crosses (one call for many scans, no Python loop per beam).

Cells are addressed in "cell units": a world point (x, y) is at
``((x − x_low) / resolution, (y − y_low) / resolution)``, so cell (i, j) of the y-up array
covers ``[j, j + 1) × [i, i + 1)``. The caller makes the grid large enough for every origin
and end point; the loop still skips cells outside it rather than trusting that.
"""

from __future__ import annotations

import math

import numpy as np

from bsslam.compiled import jit


@jit
def integrate_scans(log_odds, stamp, first_scan, origins, beam_start, ends, hit,
                    log_odds_hit, log_odds_miss, limit):
    """Add the evidence of a batch of scans to ``log_odds`` in place.

    Args:
        log_odds: (H, W) float32, y-up (row i covers y ∈ [i, i+1) in cell units).
        stamp: (H, W) int32, initialised to −1: ``2s + 1`` when scan s hit the cell,
            ``2s`` when scan s only passed through it. A cell takes one update per scan,
            and a return of a scan wins over that scan's pass-throughs in any order.
        first_scan: global index of the batch's first scan (scan numbers must increase
            over calls, so the stamps of earlier batches never look current).
        origins: (S, 2) laser position of each scan (cell units).
        beam_start: (S + 1,) beams of scan s are ``beam_start[s] : beam_start[s + 1]``.
        ends: (B, 2) end point of each beam (cell units).
        hit: (B,) True when the end is a return (its cell is occupied evidence); False for
            a "no return" beam that only clears up to its end.
        log_odds_hit, log_odds_miss: increments of a return and of a pass-through.
        limit: the log-odds are clamped to ±limit after every update.
    """
    height, width = log_odds.shape
    for s in range(origins.shape[0]):
        hit_mark = 2 * (first_scan + s) + 1
        miss_mark = hit_mark - 1
        # returns first, so the pass-throughs of the same scan can see them
        for b in range(beam_start[s], beam_start[s + 1]):
            if hit[b]:
                col = int(math.floor(ends[b, 0]))
                row = int(math.floor(ends[b, 1]))
                if 0 <= row < height and 0 <= col < width and stamp[row, col] != hit_mark:
                    stamp[row, col] = hit_mark
                    log_odds[row, col] = min(log_odds[row, col] + log_odds_hit, limit)
        x0 = origins[s, 0]
        y0 = origins[s, 1]
        for b in range(beam_start[s], beam_start[s + 1]):
            _walk(log_odds, stamp, miss_mark, x0, y0, ends[b, 0], ends[b, 1], log_odds_miss, limit, False)


@jit
def draw_segments(log_odds, starts, ends, value):
    """Set every cell that segments (k, 2) → (k, 2) (cell units) pass through, both end
    cells included, to ``value``: the same walk as the beams', so no cell a line clips at a
    corner is missed (as sampling points along it would)."""
    height, width = log_odds.shape
    stamp = np.empty((0, 0), dtype=np.int32)       # not consulted when assigning
    for k in range(starts.shape[0]):
        _walk(log_odds, stamp, 0, starts[k, 0], starts[k, 1], ends[k, 0], ends[k, 1], value, value, True)
        col = int(math.floor(ends[k, 0]))
        row = int(math.floor(ends[k, 1]))
        if 0 <= row < height and 0 <= col < width:
            log_odds[row, col] = value


@jit
def _walk(log_odds, stamp, miss_mark, x0, y0, x1, y1, log_odds_miss, limit, assign):
    """Every cell from the one holding (x0, y0) up to, not including, the one holding
    (x1, y1), in order (Amanatides & Woo's traversal): each takes a miss unless this scan
    already touched it, or, with ``assign``, is set to ``log_odds_miss`` (``stamp`` unused). The number of steps is fixed by the two end cells, so rounding in
    the crossing distances cannot make the walk overshoot or loop."""
    height, width = log_odds.shape
    col = int(math.floor(x0))
    row = int(math.floor(y0))
    end_col = int(math.floor(x1))
    end_row = int(math.floor(y1))
    dx = x1 - x0
    dy = y1 - y0
    step_col = 1 if dx > 0 else -1
    step_row = 1 if dy > 0 else -1
    # parameter (0 … 1 along the beam) of the next vertical / horizontal cell border
    if dx != 0:
        next_x = ((col + 1 - x0) if dx > 0 else (x0 - col)) / abs(dx)
        delta_x = 1.0 / abs(dx)
    else:
        next_x = np.inf
        delta_x = np.inf
    if dy != 0:
        next_y = ((row + 1 - y0) if dy > 0 else (y0 - row)) / abs(dy)
        delta_y = 1.0 / abs(dy)
    else:
        next_y = np.inf
        delta_y = np.inf
    steps = abs(end_col - col) + abs(end_row - row)
    for _ in range(steps):
        if 0 <= row < height and 0 <= col < width:
            if assign:
                log_odds[row, col] = log_odds_miss
            elif stamp[row, col] < miss_mark:
                stamp[row, col] = miss_mark
                log_odds[row, col] = max(log_odds[row, col] + log_odds_miss, -limit)
        # the walk must end in the end cell: once a coordinate has reached its end, only
        # the other one moves, whatever the rounded crossing distances say
        if col == end_col or (row != end_row and next_y < next_x):
            next_y += delta_y
            row += step_row
        else:
            next_x += delta_x
            col += step_col
