"""The map: its spline features and the batch table of their curves the per-scan searches use.

:class:`SplineMap` owns the features (:class:`~bsslam.slam.features.SplineFeature`: knots,
where their control points live in the estimator's state) and keeps their
:class:`~bsslam.slam.map_curves.MapCurves` table up to date as splines are added, extended
and removed; the compiled searches on the curves (association, the range model) are the
table's methods. It also keeps which splines no update has confirmed yet (for pruning).
"""

from __future__ import annotations

import numpy as np

from bsslam.errors import FilterError
from bsslam.slam.features import SplineFeature
from bsslam.slam.map_curves import MapCurves
from bsslam.spline.batch import CurveTable


class SplineMap:
    """The map splines by id, in insertion order, with their batch table.

    Attributes:
        features: id → feature (the insertion order is the table's curve order).
    """

    def __init__(self) -> None:
        self.features: dict[int, SplineFeature] = {}
        self._next_id = 0
        self._table: MapCurves | None = None      # batch table of the splines, see curves()
        self._added: list[SplineFeature] = []     # features added since it was brought up to date
        self._unconfirmed: list[int] = []         # splines no update has used yet, oldest first

    def new_id(self) -> int:
        """A fresh feature id."""
        self._next_id += 1
        return self._next_id - 1

    def __bool__(self) -> bool:
        return bool(self.features)

    def curves(self) -> MapCurves | None:
        """The map splines' batch table (None without splines). It is built once and then
        kept up to date: splines added join it at the next use, an extended spline's rows
        are replaced (:meth:`extended`), removed splines' rows taken out (:meth:`remove`),
        each the table a rebuild would give, bit for bit."""
        if not self.features:
            return None
        if self._table is None:
            self._table = MapCurves(list(self.features.values()))
            self._added.clear()
        self._merge_added()
        return self._table

    @property
    def table(self) -> MapCurves | None:
        """The table as the last :meth:`curves` gave it (the one this scan's matches index)."""
        return self._table

    def _merge_added(self) -> None:
        """The splines added since the table was last brought up to date join it."""
        if self._table is not None and self._added:
            self._table = self._table.with_added(self._added)
        self._added.clear()

    def add(self, feature: SplineFeature) -> None:
        """A new spline, after all others; unconfirmed until an update uses it."""
        self.features[feature.id] = feature
        self._unconfirmed.append(feature.id)
        if self._table is not None:
            self._added.append(feature)

    def extended(self, feature: SplineFeature, table: CurveTable) -> None:
        """``feature`` was extended (new knots, state rows): its rows of the map table are
        replaced by ``table``, its own one-curve table."""
        if self._table is not None:
            self._merge_added()
            self._table = self._table.with_replaced(feature, table)

    def stale(self, step: int, after: int) -> list[int]:
        """The ids of splines no update has used within ``after`` scans of their creation, at
        scan ``step``; they are forgotten here (the caller removes them).

        A spline once used stays, so the candidates are the splines of the last ``after``
        scans that no update has used yet: a pass over the whole map each scan cost 0.1 ms
        at 150 splines."""
        waiting = [self.features[i] for i in self._unconfirmed if i in self.features]
        waiting = [f for f in waiting if f.observations == 0]
        self._unconfirmed = [f.id for f in waiting if step - f.created < after]
        return [f.id for f in waiting if step - f.created >= after]

    def state_indices(self, feature_ids) -> np.ndarray | None:
        """The state indices of the control points of ``feature_ids`` (None when none is
        in the state)."""
        idx = [self.features[i].state_indices for i in feature_ids if self.features[i].in_state]
        return np.concatenate(idx) if idx else None

    def remove(self, feature_ids, mapping: np.ndarray | None) -> None:
        """Forget the splines ``feature_ids``; ``mapping`` (old state index → new, from the
        estimator's removal of their rows, or None when it removed none) renumbers the others."""
        removed = [self.features.pop(fid) for fid in feature_ids]
        if not removed:
            return
        if self._table is not None:   # the table, with the splines added since, drops their rows
            self._merge_added()
            self._table = self._table.without([f.id for f in removed], mapping)
        if mapping is None:
            return
        kept = [g for g in self.features.values() if g.in_state]
        for g in kept:
            g.idx_x, g.idx_y = mapping[g.idx_x], mapping[g.idx_y]
        # one check for all: a per-feature test cost more than the whole removal
        if kept and np.concatenate([g.idx_x for g in kept] + [g.idx_y for g in kept]).min() < 0:  # pragma: no cover - disjoint
            raise FilterError("feature indices overlapped")
