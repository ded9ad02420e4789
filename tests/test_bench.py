"""A bench run that fails costs its own figures only: it comes back as a BenchFailure
naming the log and the input variant, whatever the error."""

from __future__ import annotations

from pathlib import Path

import pytest

import bsslam.bench as bench
from bsslam.bench import BenchFailure, Perturbation, _bench_or_failure
from bsslam.config import SLAMConfig
from bsslam.errors import FilterError


@pytest.mark.parametrize("error, message", [(FilterError("the pose graph is ill-posed"), "the pose graph is ill-posed"),
                                            (RuntimeError("\nIndeterminate linear system\nnear 3"),
                                             "RuntimeError: Indeterminate linear system")])
def test_a_failed_run_is_a_failure_row_naming_log_and_variant(monkeypatch, error, message):
    def bench_log(*args, **kwargs):
        raise error
    monkeypatch.setattr(bench, "bench_log", bench_log)
    row = _bench_or_failure((Path("/data/campus.clf"), Perturbation(0.001, 2)), SLAMConfig(), None)
    assert isinstance(row, BenchFailure)
    assert row.log == f"campus.clf ({Perturbation(0.001, 2).label})" and row.message == message
    assert _bench_or_failure((Path("/data/campus.clf"), None), SLAMConfig(), None).log == "campus.clf"
