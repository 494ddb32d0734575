"""RF (random forest, Rodolà et al. 2014 as modified for SHREC'16): forest, model cache, end-to-end."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse

from topomatch import _cache
from topomatch.matching import MATCHERS, NotFittedError
from topomatch.matching._forest import Forest, grow_tree, predict_distributions
from topomatch.matching.rf import RandomForestMatcher, compose_lowpass

SMALL = {"n_trees": 4, "k": 60, "n_times": 32, "n_tests": 20, "n_jobs": 1}


def _blobs(rng, n_classes=200, per_class=5, dim=6):
    centres = rng.standard_normal((n_classes, dim)) * 10
    y = np.repeat(np.arange(n_classes), per_class)
    X = centres[y] + 0.01 * rng.standard_normal((len(y), dim))
    return X.astype(np.float32), y, centres


def test_forest_fits_separable_classes(rng):
    X, y, centres = _blobs(rng)
    tree = grow_tree(X, y, 200, n_tests=10, p_pair=0.5, min_samples_split=2, min_samples_leaf=1, max_depth=100, seed=1)
    forest = Forest([tree], 200)
    P = predict_distributions(forest, X)
    assert P.shape == (len(y), 200)
    assert np.allclose(np.asarray(P.sum(1)).ravel(), 1.0)
    assert np.mean(np.asarray(P.argmax(1)).ravel() == y) == 1.0  # grown to purity
    # unseen points near the class centres are classified correctly
    Pc = predict_distributions(forest, centres.astype(np.float32))
    assert np.mean(np.asarray(Pc.argmax(1)).ravel() == np.arange(200)) > 0.9
    # every training sample sits in exactly one leaf
    leaves = tree.left < 0
    assert (tree.leaf_end[leaves] - tree.leaf_start[leaves]).sum() == len(y)


def test_forest_is_deterministic_and_round_trips(rng):
    X, y, _ = _blobs(rng, n_classes=50)
    kw = {"n_tests": 5, "p_pair": 0.5, "min_samples_split": 2, "min_samples_leaf": 1, "max_depth": 100}
    a = grow_tree(X, y, 50, seed=7, **kw)
    b = grow_tree(X, y, 50, seed=7, **kw)
    c = grow_tree(X, y, 50, seed=8, **kw)
    assert np.array_equal(a.thr, b.thr) and np.array_equal(a.labels, b.labels)
    assert not (len(a.thr) == len(c.thr) and np.array_equal(a.thr, c.thr))
    f = Forest([a, c], 50)
    g = Forest.from_arrays(f.to_arrays())
    assert (predict_distributions(f, X) != predict_distributions(g, X)).nnz == 0


def test_compose_lowpass_with_perfect_labels(small_sphere):
    """Labels = vertex identity on a permuted copy: the composed map is the permutation."""
    from topomatch.matching._spectral import unit_basis
    from topomatch.mesh import TriangleMesh

    rng = np.random.default_rng(0)
    n = small_sphere.n_vertices
    orig = rng.permutation(n)
    inv = np.empty_like(orig)
    inv[orig] = np.arange(n)
    target = TriangleMesh(small_sphere.vertices[orig], inv[small_sphere.faces])
    P_s = sparse.identity(n, format="csr")
    P_t = sparse.csr_matrix((np.ones(n), (np.arange(n), orig)), shape=(n, n))
    k = 40
    p2p, info = compose_lowpass(P_t, P_s, unit_basis(small_sphere, k), unit_basis(target, k), adjoint=False)
    assert np.mean(p2p == orig) > 0.95
    assert info["C_12"].shape == (k, k)
    assert info["unsupported_fraction"] == 0.0


@pytest.fixture(scope="module")
def builtin_fitted(tmp_path_factory):
    from topomatch.datasets.builtin import builtin_benchmark

    coll = builtin_benchmark()
    shapes = [coll[n] for n in [coll.reference, *coll.splits["train"]]]
    return coll, shapes, RandomForestMatcher(**SMALL).fit(shapes)


def test_registered():
    assert MATCHERS["rf"] is RandomForestMatcher
    assert RandomForestMatcher.requires_fit
    assert not RandomForestMatcher.uses_ground_truth


def test_beats_descriptor_baseline_on_builtin(builtin_fitted):
    from topomatch.evaluation.protocols import get_protocol
    from topomatch.evaluation.scoring import score_maps
    from topomatch.matching.descriptor_nn import DescriptorNNMatcher

    coll, _, rf = builtin_fitted
    maps = {}
    for t, s in [("syn05", "syn06"), ("syn07", "syn08")]:
        maps[("rf", f"{t}-{s}")] = rf.match(coll[s].mesh, coll[t].mesh).p2p_21
        maps[("nn", f"{t}-{s}")] = DescriptorNNMatcher().match(coll[s].mesh, coll[t].mesh).p2p_21
    scores = score_maps(coll, get_protocol("shrec16"), maps)
    auc = {m: np.mean([x.auc for x in scores if x.method == m]) for m in ("rf", "nn")}
    assert auc["rf"] > 0.45
    assert auc["rf"] > auc["nn"] + 0.08


def test_training_uses_one_point_per_label_and_shape(builtin_fitted):
    coll, shapes, rf = builtin_fitted
    n_max = sum(int((np.diff(s.ref.tocsc().indptr) > 0).sum()) for s in shapes[1:])
    assert 0 < rf.n_train_samples_ <= n_max
    assert rf.training_shapes_ == [s.name for s in shapes[1:]]
    assert rf.forest_.n_classes == coll[coll.reference].n_vertices
    assert len(rf.forest_.trees) == SMALL["n_trees"]


def test_deterministic_and_model_file(builtin_fitted, tmp_path):
    coll, shapes, rf = builtin_fitted
    again = RandomForestMatcher(**SMALL).fit(shapes)
    src, tgt = coll["syn06"].mesh, coll["syn05"].mesh
    a = rf.match(src, tgt).p2p_21
    assert np.array_equal(a, again.match(src, tgt).p2p_21)
    path = rf.save_model(tmp_path / "rf_model")
    assert path.suffix == ".npz" and path.is_file()
    loaded = RandomForestMatcher(model=str(path)).fit([])
    assert np.array_equal(a, loaded.match(src, tgt).p2p_21)
    with pytest.raises(FileNotFoundError):
        RandomForestMatcher(model=str(tmp_path / "missing.npz")).fit([])


def test_model_cache(builtin_fitted, tmp_path, monkeypatch):
    _, shapes, _ = builtin_fitted
    monkeypatch.setattr(_cache, "_CACHE_DIR", tmp_path)
    first = RandomForestMatcher(**SMALL).fit(shapes)
    assert not first.from_cache_
    assert len(list((tmp_path / "rf-model").glob("*.npz"))) == 1
    second = RandomForestMatcher(**SMALL).fit(shapes)
    assert second.from_cache_
    assert (predict_distributions(first.forest_, np.zeros((3, 32), np.float32)) != predict_distributions(second.forest_, np.zeros((3, 32), np.float32))).nnz == 0
    # another hyperparameter or training set is another model
    third = RandomForestMatcher(**{**SMALL, "n_tests": 21}).fit(shapes)
    assert not third.from_cache_
    fourth = RandomForestMatcher(**SMALL, training_shapes=["syn01", "syn02"]).fit(shapes)
    assert not fourth.from_cache_
    assert len(list((tmp_path / "rf-model").glob("*.npz"))) == 3


def test_errors(builtin_fitted):
    coll, shapes, _ = builtin_fitted
    with pytest.raises(NotFittedError):
        RandomForestMatcher().match(coll["syn05"].mesh, coll["syn06"].mesh)
    with pytest.raises(ValueError, match="reference"):
        RandomForestMatcher(**SMALL).fit(shapes[1:])
    with pytest.raises(ValueError, match="not among"):
        RandomForestMatcher(**SMALL, training_shapes=["kid99"]).fit(shapes)
    with pytest.raises(ValueError, match="p_pair"):
        RandomForestMatcher(p_pair=2.0).fit(shapes)
    with pytest.raises(ValueError, match="n_trees"):
        RandomForestMatcher(n_trees=0).fit(shapes)
    with pytest.raises(TypeError, match="random_state"):
        RandomForestMatcher(random_state=np.random.default_rng(0)).fit(shapes)


def test_cli_fit_writes_a_model(tmp_path, monkeypatch, capsys):
    from topomatch.cli.main import main

    monkeypatch.setattr(_cache, "_CACHE_DIR", tmp_path / "cache")
    out = tmp_path / "model.npz"
    args = ["fit", "rf", "--dataset", "builtin", "--out", str(out)]
    for k, v in SMALL.items():
        args += ["--param", f"{k}={v}"]
    assert main(args) == 0
    assert out.is_file()
    assert "trained" in capsys.readouterr().err
    assert main(args) == 0  # second time: from the cache
    assert "loaded from the cache" in capsys.readouterr().err


@pytest.mark.data
@pytest.mark.slow
def test_topkids_smoke(topkids_low):
    names = ["kid00", "kid01", "kid02", "kid03"]
    rf = RandomForestMatcher(n_trees=2, n_tests=10, k=60, n_times=16).fit([topkids_low[n] for n in names])
    assert rf.forest_.n_classes == 12000
    corr = rf.match(topkids_low["kid11"].mesh, topkids_low["kid10"].mesh)
    assert corr.p2p_21.shape == (topkids_low["kid10"].n_vertices,)
    assert corr.p2p_21.min() >= 0
