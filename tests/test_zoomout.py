"""ZoomOut spectral upsampling and the zoomout matcher."""

from __future__ import annotations

import numpy as np
import pytest

from topomatch.maps import fmap_from_p2p, zoomout, zoomout_schedule
from topomatch.matching import make_matcher
from topomatch.mesh import farthest_point_sampling

from ._fmap_shapes import bumpy, shuffled


def test_schedule():
    assert zoomout_schedule(10, 20, 5) == [10, 15, 20]
    assert zoomout_schedule(10, 22, 5) == [10, 15, 20, 22]
    assert zoomout_schedule(7, 7) == [7]
    with pytest.raises(ValueError, match="k_start"):
        zoomout_schedule(10, 5)
    with pytest.raises(ValueError, match="step"):
        zoomout_schedule(1, 5, 0)


@pytest.fixture(scope="module")
def pair():
    shape = bumpy(3, mirror_symmetric=False)
    tgt, perm = shuffled(shape, seed=11)
    return shape, tgt, perm


def test_zoomout_recovers_a_permutation_from_a_noisy_small_map(pair):
    shape, tgt, perm = pair
    b1, b2 = shape.eigenbasis(60), tgt.eigenbasis(60)
    C_true = fmap_from_p2p(perm, b1.truncate(8), b2.truncate(8))
    C0 = C_true + 0.15 * np.random.default_rng(0).standard_normal(C_true.shape)
    C, p2p = zoomout(C0, b1, b2, k_final=60, step=4)
    assert C.shape == (60, 60)
    assert np.mean(p2p == perm) > 0.97
    # the initial map alone is much worse
    from topomatch.maps import p2p_from_fmap

    assert np.mean(p2p_from_fmap(C0, b1.truncate(8), b2.truncate(8)) == perm) < 0.8


def test_zoomout_on_samples_matches_dense(pair):
    shape, tgt, perm = pair
    b1, b2 = shape.eigenbasis(40), tgt.eigenbasis(40)
    C0 = fmap_from_p2p(perm, b1.truncate(10), b2.truncate(10))
    s1 = farthest_point_sampling(300, points=shape.vertices, first=0)
    s2 = farthest_point_sampling(300, points=tgt.vertices, first=0)
    _, p_dense = zoomout(C0, b1, b2, k_final=40, step=5)
    _, p_sub = zoomout(C0, b1, b2, k_final=40, step=5, samples_1=s1, samples_2=s2)
    assert np.mean(p_dense == perm) > 0.97
    assert np.mean(p_sub == perm) > 0.95


def test_zoomout_input_checks(pair):
    shape, tgt, _ = pair
    b1, b2 = shape.eigenbasis(20), tgt.eigenbasis(20)
    with pytest.raises(ValueError, match="exceeds the bases"):
        zoomout(np.eye(10), b1, b2, k_final=30)
    with pytest.raises(ValueError, match="2-D"):
        zoomout(np.ones(10), b1, b2, k_final=20)


def test_zoomout_matcher_beats_plain_fmap_on_builtin_pair(builtin):
    src = builtin["syn00"]
    tgt = builtin["syn01"]
    gt = tgt.ref_p2p
    ok = gt >= 0

    def err(p):
        return float(np.linalg.norm(src.mesh.vertices[p[ok]] - src.mesh.vertices[gt[ok]], axis=1).mean())

    fm = make_matcher("fmap", k=20).match(src.mesh, tgt.mesh)
    zo = make_matcher("zoomout", k=20, k_final=60, step=5).match(src.mesh, tgt.mesh)
    assert zo.fmap_12.shape == (60, 60)
    assert err(zo.p2p_21) < err(fm.p2p_21)
    with pytest.raises(ValueError, match="k_final"):
        make_matcher("zoomout", k=30, k_final=20).match(src.mesh, tgt.mesh)
