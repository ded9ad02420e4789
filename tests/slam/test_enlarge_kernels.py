"""The compiled enlargement blocks (bsslam.slam.enlarge_kernels) against their numpy form,
kept in ``enlarge_oracle``: bit for bit, on random poses, beams and maps."""

from __future__ import annotations

import enlarge_oracle
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bsslam.slam.enlarge import beam_points, extension_block, new_feature_block

SETTINGS = settings(max_examples=200, deadline=None)


def _same(a, b):
    assert a.shape == b.shape and a.dtype == b.dtype
    assert a.flags.c_contiguous == b.flags.c_contiguous
    np.testing.assert_array_equal(a.view(np.uint8), b.view(np.uint8))


def _beams(seed, k):
    rng = np.random.default_rng(seed)
    pose = rng.uniform(-20.0, 20.0, 3)
    offset = rng.uniform(-0.5, 0.5, 3)
    bearings = np.sort(rng.uniform(-np.pi, np.pi, k))
    ranges = rng.uniform(0.1, 30.0, k)
    return rng, pose, offset, bearings, ranges


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 60), q=st.integers(1, 12))
def test_beam_points_and_new_feature_block_match_the_numpy_form(seed, k, q):
    rng, pose, offset, bearings, ranges = _beams(seed, k)
    got = beam_points(pose, offset, bearings, ranges)
    want = enlarge_oracle.beam_points(pose, offset, bearings, ranges)
    for name in ("points", "d_dpose", "d_drange"):
        _same(getattr(got, name), getattr(want, name))
    phi = rng.normal(size=(q, k))
    got_block, want_block = new_feature_block(phi, got), enlarge_oracle.new_feature_block(phi, want)
    for name in ("mean", "cols", "J", "G_z"):
        _same(getattr(got_block, name), getattr(want_block, name))
    _same(got_block.noise(0.01), want_block.noise(0.01))
    # an error shared by the k ranges: G (r I + s 1 1ᵀ) Gᵀ
    k = got_block.G_z.shape[1]
    np.testing.assert_allclose(got_block.noise(0.01, 0.02),
                               got_block.G_z @ (0.01 * np.eye(k) + 0.02 * np.ones((k, k))) @ got_block.G_z.T,
                               rtol=1e-12, atol=1e-15)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 40), n_old=st.integers(1, 15), m=st.integers(1, 8))
def test_extension_block_matches_the_numpy_form(seed, k, n_old, m):
    rng, pose, offset, bearings, ranges = _beams(seed, k)
    psi_new = rng.normal(size=(m, n_old + k))
    idx = rng.permutation(1000)[: 2 * n_old] + 3
    idx_x, idx_y = idx[:n_old], idx[n_old:]
    cps = rng.uniform(-10.0, 10.0, (n_old, 2))
    got = extension_block(psi_new, n_old, idx_x, idx_y, cps, beam_points(pose, offset, bearings, ranges))
    want = enlarge_oracle.extension_block(psi_new, n_old, idx_x, idx_y, cps,
                                          enlarge_oracle.beam_points(pose, offset, bearings, ranges))
    for name in ("mean", "cols", "J", "G_z"):
        _same(getattr(got, name), getattr(want, name))
