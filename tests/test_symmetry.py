"""Repairing a map's patches: left-right exchanges (``flip_mirror_patches``) and small islands (``fill_small_patches``)."""

from __future__ import annotations

import numpy as np
import pytest

from topomatch.maps.patches import fill_small_patches
from topomatch.maps.symmetry import flip_mirror_patches


def _grid(nx: int = 40, ny: int = 20) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flat grid over x in [-1, 1], y in [0, 1], mirror-symmetric about x = 0; (vertices, faces, sym)."""
    xs = np.linspace(-1.0, 1.0, nx)
    ys = np.linspace(0.0, 1.0, ny)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    V = np.c_[X.ravel(), Y.ravel(), np.zeros(X.size)]
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.r_[np.c_[a, b, c], np.c_[a, c, d]]
    sym = idx[::-1, :].ravel()  # (i, j) -> (nx - 1 - i, j)
    return V, F, sym


def test_a_small_mirrored_patch_is_mirrored_back():
    V, F, sym = _grid()
    truth = np.arange(len(V))
    patch = np.flatnonzero(np.hypot(V[:, 0] - 0.6, V[:, 1] - 0.5) < 0.15)
    p2p = truth.copy()
    p2p[patch] = sym[patch]  # those vertices mapped onto the other side
    out, n = flip_mirror_patches(p2p, F, V, F, sym)
    np.testing.assert_array_equal(out, truth)
    assert n == len(patch) > 3
    # the input is not modified; a correct map is left alone
    assert (p2p[patch] != truth[patch]).all()
    same, n0 = flip_mirror_patches(truth, F, V, F, sym)
    np.testing.assert_array_equal(same, truth)
    assert n0 == 0


def test_large_patches_whole_mirror_images_and_vertices_without_mirror_are_kept():
    V, F, sym = _grid()
    truth = np.arange(len(V))
    # the whole map mirrored is one continuous patch: a symmetric solution, kept
    out, n = flip_mirror_patches(sym.copy(), F, V, F, sym)
    np.testing.assert_array_equal(out, sym)
    assert n == 0
    # a patch above max_fraction of the vertices is kept
    big = np.flatnonzero(V[:, 0] > 0.3)
    p2p = truth.copy()
    p2p[big] = sym[big]
    assert len(big) > 0.05 * len(V)
    assert flip_mirror_patches(p2p, F, V, F, sym)[1] == 0
    assert flip_mirror_patches(p2p, F, V, F, sym, max_fraction=0.5)[1] == len(big)
    # a patch whose image has a vertex without a mirror is kept
    patch = np.flatnonzero(np.hypot(V[:, 0] - 0.6, V[:, 1] - 0.5) < 0.15)
    p2p = truth.copy()
    p2p[patch] = sym[patch]
    no_mirror = sym.copy()
    no_mirror[p2p[patch[0]]] = -1
    assert flip_mirror_patches(p2p, F, V, F, no_mirror)[1] == 0
    # unmatched vertices stay unmatched
    p2p[patch[:2]] = -1
    out, n = flip_mirror_patches(p2p, F, V, F, sym)
    assert (out[patch[:2]] == -1).all() and n == len(patch) - 2
    np.testing.assert_array_equal(out[patch[2:]], truth[patch[2:]])


def test_flip_mirror_patches_errors():
    V, F, sym = _grid(6, 4)
    p2p = np.arange(len(V))
    with pytest.raises(ValueError, match="1-D integer"):
        flip_mirror_patches(p2p.astype(float), F, V, F, sym)
    with pytest.raises(ValueError, match="outside"):
        flip_mirror_patches(p2p + 1, F, V, F, sym)
    with pytest.raises(ValueError, match="sym_1"):
        flip_mirror_patches(p2p, F, V, F, sym[:-1])
    with pytest.raises(ValueError, match="faces_2"):
        flip_mirror_patches(p2p[:-3], F, V, F, sym)
    with pytest.raises(ValueError, match="faces_1"):
        flip_mirror_patches(p2p, F, V, np.r_[F, [[0, 1, len(V)]]], sym)
    with pytest.raises(ValueError, match="vertices_1"):
        flip_mirror_patches(p2p, F, V[:, :2], F, sym)
    with pytest.raises(ValueError, match="zero area"):
        flip_mirror_patches(p2p, F, np.zeros_like(V), F, sym)
    with pytest.raises(ValueError, match="jump"):
        flip_mirror_patches(p2p, F, V, F, sym, jump=0.0)
    with pytest.raises(ValueError, match="sweeps"):
        flip_mirror_patches(p2p, F, V, F, sym, sweeps=1.5)


def test_a_small_island_takes_the_image_of_the_nearest_large_patch():
    V, F, sym = _grid()
    truth = np.arange(len(V))
    island = np.flatnonzero(np.hypot(V[:, 0] - 0.6, V[:, 1] - 0.5) < 0.1)
    p2p = truth.copy()
    p2p[island] = np.argmin(np.hypot(V[:, 0] + 0.05, V[:, 1] - 0.95))  # all sent to one far vertex near the plane
    out, n = flip_mirror_patches(p2p, F, V, F, sym)
    assert n == 0  # not a mirror image: left to the filling
    out, n = fill_small_patches(p2p, V, F, V, F)
    assert n == len(island) > 3
    # each island vertex now maps to the image of its nearest outside vertex: next to its own truth
    assert np.all(np.linalg.norm(V[out[island]] - V[island], axis=1) < 0.1 + 0.06)  # the island radius and a grid step
    np.testing.assert_array_equal(np.delete(out, island), np.delete(truth, island))
    # a correct map, a map without any large piece, and unmatched vertices are left alone
    assert fill_small_patches(truth, V, F, V, F)[1] == 0
    noisy = np.random.default_rng(0).permutation(len(V))
    np.testing.assert_array_equal(fill_small_patches(noisy, V, F, V, F)[0], noisy)
    p2p[island[:2]] = -1
    out, n = fill_small_patches(p2p, V, F, V, F)
    assert (out[island[:2]] == -1).all() and n == len(island) - 2
    with pytest.raises(ValueError, match="vertices_2"):
        fill_small_patches(p2p, V[:-1], F, V, F)
    with pytest.raises(ValueError, match="jump"):
        fill_small_patches(p2p, V, F, V, F, jump=-1.0)
    with pytest.raises(ValueError, match="duplicate"):
        fill_small_patches(p2p, V, F, V, F, duplicate=1.5)
    with pytest.raises(ValueError, match="faces_2"):
        fill_small_patches(p2p[:-5], V[:-5], F, V, F)


def test_a_correct_piece_cut_off_by_wrong_surroundings_is_kept():
    # a disc mapped right, inside a ring mapped to one far vertex: both are small pieces, but only
    # the ring is a second copy of a region the rest already covers; the disc is its region's only cover
    V, F, _ = _grid(80, 40)
    truth = np.arange(len(V))
    r = np.hypot(V[:, 0] - 0.5, V[:, 1] - 0.5)
    disc, ring = np.flatnonzero(r < 0.08), np.flatnonzero((r >= 0.08) & (r < 0.17))
    p2p = truth.copy()
    p2p[ring] = np.argmin(np.hypot(V[:, 0] + 0.5, V[:, 1] - 0.9))
    out, n = fill_small_patches(p2p, V, F, V, F)
    np.testing.assert_array_equal(out[disc], truth[disc])
    assert n == len(ring)
    assert np.all(np.linalg.norm(V[out[ring]] - V[ring], axis=1) < 0.1 + 0.05)  # the ring's width and a grid step
    # without the duplicate test the disc takes the images of the outside too
    out0, n0 = fill_small_patches(p2p, V, F, V, F, duplicate=0.0)
    assert n0 == len(ring) + len(disc) and (out0[disc] != truth[disc]).all()
