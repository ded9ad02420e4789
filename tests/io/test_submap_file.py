"""A frozen submap written to ``.npz`` and read back is the same submap, bit for bit:
splines (knots, control points, degree, ids, surfaces), their covariance, the shape used
for loop closure, and the robot's final pose with its covariance."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bsslam.config import SLAMConfig, SubmapConfig
from bsslam.errors import InputError
from bsslam.experiments.consistency import simulation_config
from bsslam.io.submap_file import read_submap, write_submap
from bsslam.mapper import Mapper
from bsslam.sim import SimConfig, get_world, simulate
from bsslam.submaps.loop_closure import SubmapShape


@pytest.fixture(scope="module")
def frozen():
    config = simulation_config(SLAMConfig(), SimConfig()).replace(
        backend="submaps", relocalize=False,
        submaps=dataclasses.replace(SubmapConfig(), max_distance_m=4.0))
    mapper = Mapper(config)
    for frame in simulate(get_world("rounded-room"), SimConfig(), seed=3, steps=60):
        mapper.add_frame(frame)
    result = mapper.finish()
    assert len(result.submaps.frozen) >= 2
    return result.submaps.frozen


def test_a_frozen_submap_reloaded_is_the_same_bit_for_bit(frozen, tmp_path):
    for submap in frozen:
        path = tmp_path / f"{submap.index:03d}.npz"
        write_submap(path, submap)
        back = read_submap(path)
        assert back.index == submap.index and back.filter_steps == submap.filter_steps
        np.testing.assert_array_equal(back.end_pose, submap.end_pose)
        np.testing.assert_array_equal(back.end_covariance, submap.end_covariance)
        assert len(back.splines) == len(submap.splines) > 0
        for a, b in zip(back.splines, submap.splines):
            assert (a.id, a.submap, a.surface, a.curve.degree) == (b.id, b.submap, b.surface, b.curve.degree)
            np.testing.assert_array_equal(a.curve.knots, b.curve.knots)
            np.testing.assert_array_equal(a.curve.control_points, b.curve.control_points)
            np.testing.assert_array_equal(a.covariance, b.covariance)
        for f in dataclasses.fields(SubmapShape):
            np.testing.assert_array_equal(getattr(back.shape, f.name), getattr(submap.shape, f.name))


def test_a_file_that_is_not_a_submap_is_an_input_error_naming_it(tmp_path):
    path = tmp_path / "garbage.npz"
    path.write_bytes(b"not a zip file")
    with pytest.raises(InputError, match="garbage.npz"):
        read_submap(path)
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(InputError, match="other.npz"):
        read_submap(tmp_path / "other.npz")


def test_a_file_written_before_the_walls_sigma_reads_it_as_unknown(frozen, tmp_path):
    """Submap files from before the shape carried each point's wall σ: σ = 0, the rest as
    written (a loop closure against it then counts only the other submap's walls)."""
    path = tmp_path / "old.npz"
    write_submap(path, frozen[0])
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files if k != "shape_sigma"}
    np.savez(path, **arrays)
    back = read_submap(path)
    assert back.shape.sigma.shape == frozen[0].shape.points.shape[:1] and not back.shape.sigma.any()
    assert frozen[0].shape.sigma.any()     # what was dropped was there
    np.testing.assert_array_equal(back.shape.points, frozen[0].shape.points)
