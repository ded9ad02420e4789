"""Many spline curves at once: evaluation and closest points over a table of the
polynomial pieces of all of them.

The filter asks the same questions of dozens of curves per scan (where does each beam hit
its map spline, which map point is closest to each observed spline end). Asked one curve
at a time, each question costs a fixed ~1 ms of Python and numpy call overhead. Here every
query carries the index of its own curve, the pieces of all curves sit in one array, and
each search is a single vectorised computation whatever the mix of curves.

Two layers:

* :class:`CurveTable` — what depends on the knots only: the pieces of every curve, and for
  each piece the power-basis form of its degree + 1 non-zero basis functions. It survives
  any change of the control points (the filter moves them at every update).
* :class:`CurveBatch` — a table plus control points: the per-piece polynomial coefficients,
  one tensor contraction away from the table.

Per-call cost is numpy call overhead (tens of queries, a few curves), so the searches are
written for few numpy calls: pieces are found with one exact complex-key searchsorted and
coefficients are gathered as (p+1, 2, m) rows. The Newton iterations, a dozen numpy calls
per step, are compiled loops over the starts (:mod:`bsslam.spline.kernels`) that do the
same floating-point operations in the same order, so the results are bit-identical to the
numpy forms they replaced.

Curves may differ in degree: the table is padded to the largest degree p with zero
coefficients (which Horner evaluates exactly), and a padded piece's control-point window
repeats its last real control point with zero weight.

The closest-point search (:func:`closest_points_batch`, also behind the one-curve
:func:`bsslam.spline.closest_point`) follows the numpy form it replaced step for step (same
starts, iterations, tolerances and acceptance tests; ``tests/spline/closest_oracle.py``);
results agree with it up to rounding.

Where each beam hits its map spline is asked of the table's arrays directly by the filter's
compiled linearisation (:func:`bsslam.slam.range_kernels.linearize_beams`). The numpy ray
intersection over a batch that it replaced, which followed
:func:`bsslam.spline.intersect_rays` step for step, is the tests' oracle
(``tests/spline/ray_oracle.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from bsslam.errors import SplineError
from bsslam.spline import kernels
from bsslam.spline.pieces import horner_with_derivatives

#: The closest-point search: Newton iterations per start, and its step tolerance (a fraction
#: of the curve's domain).
_CLOSEST_MAX_NEWTON = 30
_CLOSEST_STEP_TOLERANCE = 1e-13
#: Most coarse samples per piece: a wildly long control polygon (a diverged estimate) must
#: cost bounded memory.
MAX_SAMPLES_PER_SPAN = 256


@dataclass(frozen=True, eq=False)
class CurveTable:
    """The knot structure of C curves with N control points in all and S pieces in all.

    Attributes:
        degree: (C,) polynomial degree of each curve; ``p`` is the largest.
        p: the padded degree of the table.
        cp_start: (C+1,) curve c owns control-point rows ``cp_start[c] … cp_start[c+1]−1``
            of a batch's stacked (N, 2) control points.
        piece_start: (C+1,) curve c owns pieces ``piece_start[c] … piece_start[c+1]−1``.
        lo, hi: (C,) parameter domain of each curve (m).
        piece_lo: (S,) parameter where each piece starts (m); width: (S,) its length (m).
        piece_curve: (S,) owning curve of each piece.
        window: (S, p+1) control-point rows of each piece (padding repeats the last row).
        real: (S, p+1) bool, False on padded window entries.
        power_basis: (S, p+1, p+1) ``power_basis[s, k, r]`` is the k-th Taylor coefficient
            at ``piece_lo[s]`` of the basis function of control point ``window[s, r]``
            (1/mᵏ): on piece s, ``β_r(piece_lo + u) = Σ_k power_basis[s, k, r] uᵏ``.
        keys: (S+C,) complex search keys ``curve + 1j·break`` of every curve's breaks in
            order; numpy orders complex numbers lexicographically, so one searchsorted
            finds the piece of (curve, t) for any mix of curves, exactly.
        break_start: (C+1,) offsets of each curve's S_c + 1 breaks in ``keys``.
    """

    degree: np.ndarray
    p: int
    cp_start: np.ndarray
    piece_start: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    piece_lo: np.ndarray
    width: np.ndarray
    piece_curve: np.ndarray
    window: np.ndarray
    real: np.ndarray
    power_basis: np.ndarray
    keys: np.ndarray
    break_start: np.ndarray

    @property
    def n_curves(self) -> int:
        return self.lo.shape[0]

    @cached_property
    def piece_keys(self) -> np.ndarray:
        """(S,) complex search keys ``curve + 1j·piece_lo`` of every piece, in order: for t
        inside its curve's domain, ``searchsorted(piece_keys, curve + 1j·t, "right") − 1``
        is its piece, the domain end included (no end break, so no clamp to the last piece)."""
        return self.piece_curve + 1j * self.piece_lo

    @cached_property
    def last_piece(self) -> np.ndarray:
        """(C,) global index of each curve's last piece."""
        return self.piece_start[1:] - 1

    def with_control_points(self, control_points: np.ndarray, curves: np.ndarray | None = None) -> CurveBatch:
        """The curves with stacked control points (N, 2) (m), rows ordered as ``cp_start``.

        With ``curves`` (indices), only those curves get polynomial coefficients (the
        others' stay NaN and must not be queried; compiled:
        :func:`bsslam.spline.kernels.piece_coefficients`): the filter queries the few splines near
        the robot of a map of hundreds, and the coefficients are recomputed whenever the
        state moves.
        """
        cp = np.asarray(control_points, dtype=float)
        if cp.shape != (self.cp_start[-1], 2):
            raise SplineError(f"control points must have shape ({self.cp_start[-1]}, 2), got {cp.shape}")
        # The searches read the coefficients as (p+1, 2, S) (see CurveBatch.coeffs_t): the
        # batch's (S, p+1, 2) coeffs are a transposed view of that array.
        curves = np.arange(self.n_curves) if curves is None else np.asarray(curves, dtype=np.intp)
        coeffs_t = kernels.piece_coefficients(self.power_basis, self.window, cp, curves, self.piece_start)
        return CurveBatch(self, cp, coeffs_t.transpose(2, 0, 1))

    def bboxes(self, control_points: np.ndarray) -> np.ndarray:
        """(C, 4) ``xmin, ymin, xmax, ymax`` of each control polygon (m), from stacked
        control points (N, 2); the box contains the curve."""
        # compiled (kernels.bboxes): the two reduceat and their stacking cost several
        # times the whole loop; a min or max does not round, so the boxes are the same
        return kernels.bboxes(np.asarray(control_points, dtype=float), self.cp_start)

    def locate(self, curve: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Global piece (m,), local parameter u = t − piece_lo (m,) and the clamped t (m,)
        of parameters ``t`` (m,) on curves ``curve`` (m,). As for one curve, ``t`` is
        clamped into its curve's domain and the domain end belongs to the last piece."""
        curve = np.asarray(curve, dtype=np.intp)
        # np.clip's result (NaN stays NaN) at a fraction of its call overhead
        t = np.minimum(np.maximum(t, self.lo.take(curve)), self.hi.take(curve))
        piece = _search(self.piece_keys, curve, t)
        # a NaN parameter sorts after every key: give it its own curve's last piece
        np.minimum(piece, self.last_piece.take(curve), out=piece)
        return piece, t - self.piece_lo.take(piece), t


@dataclass(frozen=True, eq=False)
class CurveBatch:
    """A :class:`CurveTable` with control points.

    Attributes:
        table: the knot structure.
        control_points: (N, 2) stacked control points (m).
        coeffs: (S, p+1, 2) Taylor coefficients of each piece at its start (m / mᵏ), as
            :class:`~bsslam.spline.pieces.PolynomialPieces` has them for one curve. From
            :meth:`CurveTable.with_control_points` it is a transposed view of the
            contiguous (p+1, 2, S) :attr:`coeffs_t` that the searches gather from.
    """

    table: CurveTable
    control_points: np.ndarray
    coeffs: np.ndarray

    @cached_property
    def coeffs_t(self) -> np.ndarray:
        """(p+1, 2, S) the coefficients with the piece axis last, contiguous: gathering
        pieces gives (p+1, 2, m) whose rows broadcast against (m,) parameters without
        strided views (a copy only when ``coeffs`` is not already such a view)."""
        return np.ascontiguousarray(self.coeffs.transpose(1, 2, 0))

    def evaluate(self, curve: np.ndarray, t: np.ndarray, nder: int = 0) -> np.ndarray:
        """Points and derivatives 0 … nder at parameters t (m,) (clamped) on curves (m,):
        (nder+1, m, 2)."""
        if nder == 0:
            # compiled point by point (kernels.evaluate_points): the piece found as _search
            # finds it, Horner as horner_with_derivatives does it; a NaN parameter gives a
            # NaN point
            table = self.table
            t = np.ascontiguousarray(t, dtype=float)
            curve = np.asarray(curve, dtype=np.intp)
            if curve.shape != t.shape:      # one curve for all parameters
                curve = np.full(t.shape, curve, dtype=np.intp)
            return kernels.evaluate_points(self.coeffs_t, table.piece_lo, table.piece_start, table.lo, table.hi,
                                           curve, t)[None]
        piece, u, _ = self.table.locate(curve, np.asarray(t, dtype=float))
        return horner_with_derivatives(self.coeffs.take(piece, axis=0), u, nder)

    def bboxes(self) -> np.ndarray:
        """(C, 4) ``xmin, ymin, xmax, ymax`` of each control polygon (m); contains the curve."""
        return self.table.bboxes(self.control_points)


def curve_table(knots: list[np.ndarray], degrees: list[int] | np.ndarray) -> CurveTable:
    """Build the table of C curves from their knot vectors and degrees.

    Args:
        knots: C valid knot vectors (m), curve c having ``len(knots[c]) − degree − 1``
            control points.
        degrees: (C,) polynomial degrees.
    """
    # Built for every scan's observed splines and every spline the map gains: the whole
    # table is one compiled call (kernels.curve_table_arrays), its 1-D fields packed by
    # dtype because each array a compiled function returns costs a Python call.
    degrees = np.array(degrees, dtype=np.intp, ndmin=1)
    n_knots = np.array([k.shape[0] for k in knots], dtype=np.intp)
    if degrees.shape != n_knots.shape or not knots:
        raise SplineError("curve_table needs one degree per knot vector, and at least one curve")
    # Spans degree … n_cp − 1 of each curve cover its domain; the non-empty ones are its pieces.
    ok, ints, floats, keys, window, real, power_basis = kernels.curve_table_arrays(
        np.concatenate(knots, dtype=float), n_knots, degrees)
    if not ok:
        raise SplineError("every curve needs a non-empty domain")
    C, S = n_knots.shape[0], window.shape[0]
    return _new_table(degree=degrees, p=window.shape[1] - 1, cp_start=ints[: C + 1],
                      piece_start=ints[C + 1: 2 * C + 2], lo=floats[:C], hi=floats[C: 2 * C],
                      piece_lo=floats[2 * C: 2 * C + S], width=floats[2 * C + S:],
                      piece_curve=ints[3 * C + 3: 3 * C + 3 + S], window=window, real=real,
                      power_basis=power_basis, keys=keys[: S + C], break_start=ints[2 * C + 2: 3 * C + 3],
                      piece_keys=keys[S + C:], last_piece=ints[3 * C + 3 + S:])


def _new_table(**fields: object) -> CurveTable:
    """A :class:`CurveTable` of the given fields, and of its cached ``piece_keys`` and
    ``last_piece`` (computed once where the table is made, not on first use), written
    straight into the instance: the frozen dataclass's __init__ sets its fourteen fields
    one ``object.__setattr__`` at a time, a quarter of the cost of an observed table."""
    table = object.__new__(CurveTable)
    table.__dict__.update(fields)
    return table


def concat_tables(a: CurveTable, b: CurveTable) -> CurveTable:
    """The table of a's curves followed by b's, field for field as :func:`curve_table` would
    build it from all their knot vectors (tables of one padded degree only)."""
    if a.p != b.p:
        raise SplineError(f"cannot concatenate tables of padded degrees {a.p} and {b.p}")
    C, N, S = a.n_curves, int(a.cp_start[-1]), a.piece_lo.shape[0]
    return _new_table(
        degree=np.concatenate([a.degree, b.degree]), p=a.p,
        cp_start=np.concatenate([a.cp_start, b.cp_start[1:] + N]),
        piece_start=np.concatenate([a.piece_start, b.piece_start[1:] + S]),
        lo=np.concatenate([a.lo, b.lo]), hi=np.concatenate([a.hi, b.hi]),
        piece_lo=np.concatenate([a.piece_lo, b.piece_lo]), width=np.concatenate([a.width, b.width]),
        piece_curve=np.concatenate([a.piece_curve, b.piece_curve + C]),
        window=np.concatenate([a.window, b.window + N]), real=np.concatenate([a.real, b.real]),
        power_basis=np.concatenate([a.power_basis, b.power_basis]),
        keys=np.concatenate([a.keys, b.keys + C]),
        break_start=np.concatenate([a.break_start, b.break_start[1:] + a.keys.shape[0]]),
        piece_keys=np.concatenate([a.piece_keys, b.piece_keys + C]),
        last_piece=np.concatenate([a.last_piece, b.last_piece + S]))


def kept_rows(start: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of the curves ``keep`` (sorted) in an array where curve c owns rows
    ``start[c] … start[c+1] − 1`` (control points, pieces, breaks): (the rows in order,
    their new (K+1,) starts, the (K,) row counts)."""
    counts = start[keep + 1] - start[keep]
    new_start = np.concatenate([[0], np.cumsum(counts)])
    rows = np.repeat(start[keep] - new_start[:-1], counts) + np.arange(new_start[-1])
    return rows, new_start, counts


def take_curves(table: CurveTable, keep: np.ndarray) -> CurveTable:
    """The table of the curves ``keep`` (sorted indices) of ``table``, field for field as
    :func:`curve_table` would build it from their knot vectors (the filter drops pruned map
    splines this way). The kept curves must have the table's padded degree as their largest."""
    keep = np.asarray(keep, dtype=np.intp)
    if keep.size == 0 or int(table.degree[keep].max()) != table.p:
        raise SplineError("take_curves keeps at least one curve, and one of the table's padded degree")
    C = keep.shape[0]
    pieces, piece_start, n_pieces = kept_rows(table.piece_start, keep)
    _, cp_start, _ = kept_rows(table.cp_start, keep)
    breaks, break_start, n_breaks = kept_rows(table.break_start, keep)
    owner = np.repeat(np.arange(C), n_pieces)
    piece_lo = table.piece_lo[pieces]
    # a piece's window rows move with its curve's first control point
    shift = (cp_start[:-1] - table.cp_start[keep])[owner]
    return _new_table(degree=table.degree[keep], p=table.p, cp_start=cp_start, piece_start=piece_start,
                      lo=table.lo[keep], hi=table.hi[keep], piece_lo=piece_lo, width=table.width[pieces],
                      piece_curve=owner, window=table.window[pieces] + shift[:, None], real=table.real[pieces],
                      power_basis=table.power_basis[pieces],
                      keys=np.repeat(np.arange(C), n_breaks) + 1j * table.keys.imag[breaks],
                      break_start=break_start, piece_keys=owner + 1j * piece_lo, last_piece=piece_start[1:] - 1)


def _search(keys: np.ndarray, curve: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(m,) global piece of parameters t (m,), each inside the domain of its curve (m,):
    one exact lexicographic search of the complex keys ``curve + 1j·t`` among
    :attr:`CurveTable.piece_keys`."""
    key = np.empty(t.shape, dtype=complex)
    key.real = curve
    key.imag = t
    piece = keys.searchsorted(key, side="right")
    piece -= 1
    return piece


# -- closest points --------------------------------------------------------------------------

def closest_points_batch(batch: CurveBatch, curve: np.ndarray, queries: np.ndarray,
                         t0: np.ndarray | None = None, *, sample_step_m: float = 0.1,
                         samples_per_span: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point of its own curve nearest to each query point, for queries that each name their
    curve: the search :func:`bsslam.spline.closest_point` describes (coarse sampling, Newton
    from the sampled minima and their neighbours).

    Args:
        batch: the curves.
        curve: (q,) curve index of each query.
        queries: (q, 2) query points (m).
        t0: optional (q,) starting parameters (m); NaN means sample the curve.
        sample_step_m: largest arc length between coarse samples (m).
        samples_per_span: fewest coarse samples per piece (≥ 2).

    Returns:
        ``(t, points, distance)``: (q,) parameters (m), (q, 2) points (m), (q,) distances (m).
    """
    table = batch.table
    curve = np.asarray(curve, dtype=np.intp)
    q = np.asarray(queries, dtype=float)
    if q.ndim != 2 or q.shape[1] != 2 or curve.shape != (q.shape[0],):
        raise SplineError(f"queries must be (q, 2) with one curve each, got {q.shape} and {curve.shape}")
    if samples_per_span < 2:
        raise SplineError(f"samples_per_span must be ≥ 2, got {samples_per_span}")
    if not sample_step_m > 0:
        raise SplineError(f"sample_step_m must be > 0, got {sample_step_m}")
    if t0 is None:                          # the filter's case
        t_start, owner = _sampled_minima(batch, curve, q, sample_step_m, samples_per_span)
    else:
        guess = np.asarray(t0, dtype=float)
        given = np.flatnonzero(np.isfinite(guess))
        unguessed = np.flatnonzero(~np.isfinite(guess))
        t_start = np.clip(guess[given], table.lo[curve[given]], table.hi[curve[given]])
        owner = given
        if unguessed.size:
            t_s, owner_s = _sampled_minima(batch, curve[unguessed], q[unguessed], sample_step_m,
                                           samples_per_span)
            t_start = np.concatenate([t_start, t_s])
            owner = np.concatenate([owner, unguessed[owner_s]])
    t, d2 = _closest_newton(batch, curve.take(owner), q.take(owner, axis=0), t_start)
    best = kernels.first_per_group(d2, owner, q.shape[0])    # each query's best start
    t_best = t.take(best)
    points = kernels.evaluate_points(batch.coeffs_t, table.piece_lo, table.piece_start, table.lo, table.hi,
                                     curve, t_best)
    return t_best, points, np.sqrt(d2.take(best))


def _sampled_minima(batch: CurveBatch, curve: np.ndarray, q: np.ndarray, sample_step_m: float,
                    samples_per_span: int) -> tuple[np.ndarray, np.ndarray]:
    """(K,) starts and their (K,) query index: discrete local minima of the distance along
    each query's curve sampled as one curve's ``closest_point`` samples it, and their
    neighbours (compiled: :func:`bsslam.spline.kernels.sampled_minima`)."""
    table = batch.table
    return kernels.sampled_minima(batch.coeffs_t, batch.control_points, table.window, table.piece_lo, table.width,
                                  table.piece_start, table.lo, table.hi, np.asarray(curve, dtype=np.intp),
                                  np.ascontiguousarray(q[:, 0]), np.ascontiguousarray(q[:, 1]),
                                  float(sample_step_m), int(samples_per_span), MAX_SAMPLES_PER_SPAN)


def _closest_newton(batch: CurveBatch, curve: np.ndarray, q: np.ndarray, t: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Clamped, downhill-safeguarded Newton on f(t) = (s(t) − q)·s'(t) for (K,) starts on
    their curves; the best parameter seen per start and its squared distance. Compiled
    (:func:`bsslam.spline.kernels.closest_newton`); every start is iterated until all have
    converged (as before: results depend on it)."""
    table = batch.table
    return kernels.closest_newton(batch.coeffs_t, table.piece_lo, table.piece_start, table.lo, table.hi,
                                  np.asarray(curve, dtype=np.intp), np.ascontiguousarray(q[:, 0]),
                                  np.ascontiguousarray(q[:, 1]), np.asarray(t, dtype=float),
                                  _CLOSEST_MAX_NEWTON, _CLOSEST_STEP_TOLERANCE)
