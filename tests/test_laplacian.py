import numpy as np
import pytest
from scipy import sparse

from topomatch.datasets.toy import icosphere
from topomatch.mesh import (
    TriangleMesh,
    cotangent_laplacian,
    gradient_operator,
    laplacian_eigenbasis,
    robust_laplacian,
)


def test_right_triangle_cotan_exact():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    f = np.array([[0, 1, 2]])
    L, M = cotangent_laplacian(v, f)
    # angles: 90 at 0, 45 at 1 and 2 -> weights: edge(1,2) cot90/2 = 0, edges (0,1),(0,2): cot45/2 = 0.5
    expected = np.array([[1.0, -0.5, -0.5], [-0.5, 0.5, 0.0], [-0.5, 0.0, 0.5]])
    np.testing.assert_allclose(L.toarray(), expected, atol=1e-12)
    np.testing.assert_allclose(M.diagonal(), [1 / 6] * 3)


def test_cotan_equals_gradient_identity(sphere):
    L, _ = cotangent_laplacian(sphere.vertices, sphere.faces)
    G, area = gradient_operator(sphere.vertices, sphere.faces)
    L2 = G.T @ sparse.diags(np.repeat(area, 3)) @ G
    assert abs(L - L2).max() < 1e-10
    # gradient of a linear function is its constant gradient
    gx = (G @ sphere.vertices[:, 0]).reshape(-1, 3)
    n = sphere.face_normals
    np.testing.assert_allclose(gx, np.array([1.0, 0, 0]) - n[:, :1] * n, atol=1e-10)


@pytest.mark.parametrize("kind", ["robust", "cotan"])
def test_laplacian_properties(sphere, kind):
    L, M = sphere.laplacian(kind)
    assert abs(L - L.T).max() < 1e-10
    np.testing.assert_allclose(np.asarray(L.sum(axis=1)).ravel(), 0, atol=1e-10)
    assert np.all(M.diagonal() > 0)
    assert M.diagonal().sum() == pytest.approx(sphere.area, rel=1e-6)


def test_robust_matches_cotan_on_delaunay_mesh(sphere):
    Lr, _ = robust_laplacian(sphere.vertices, sphere.faces)
    Lc, _ = cotangent_laplacian(sphere.vertices, sphere.faces)
    assert sparse.linalg.norm(Lr - Lc) / sparse.linalg.norm(Lc) < 0.02


def test_sphere_spectrum():
    m = icosphere(4)
    b = m.eigenbasis(16)
    # unit sphere: l(l+1) with multiplicity 2l+1 -> 0, 2 (x3), 6 (x5), 12 (x7)
    expected = np.repeat([0, 2, 6, 12], [1, 3, 5, 7])
    np.testing.assert_allclose(b.evals, expected, rtol=0.02, atol=1e-6)
    gram = b.evecs.T @ (b.mass[:, None] * b.evecs)
    np.testing.assert_allclose(gram, np.eye(16), atol=1e-8)


def test_eigenbasis_is_deterministic_and_sliced(small_sphere):
    m = TriangleMesh(small_sphere.vertices, small_sphere.faces)
    b20 = m.eigenbasis(20)
    b10 = m.eigenbasis(10)
    np.testing.assert_array_equal(b10.evecs, b20.evecs[:, :10])
    fresh = TriangleMesh(small_sphere.vertices, small_sphere.faces).eigenbasis(20)
    np.testing.assert_array_equal(fresh.evals, b20.evals)
    np.testing.assert_array_equal(fresh.evecs, b20.evecs)
    with pytest.raises(ValueError, match="1 <= k"):
        laplacian_eigenbasis(*m.laplacian(), k=10_000)


def test_eigenbasis_disk_cache(tmp_path, small_sphere, monkeypatch):
    from topomatch import _cache

    monkeypatch.setattr(_cache, "_CACHE_DIR", tmp_path)
    m = TriangleMesh(small_sphere.vertices, small_sphere.faces)
    b = m.eigenbasis(12)
    files = list((tmp_path / "eigen").glob("*.npz"))
    assert len(files) == 1
    again = TriangleMesh(small_sphere.vertices, small_sphere.faces).eigenbasis(12)
    np.testing.assert_array_equal(again.evecs, b.evecs)
    files[0].write_bytes(b"corrupt")  # a corrupt entry is ignored and recomputed
    third = TriangleMesh(small_sphere.vertices, small_sphere.faces).eigenbasis(12)
    np.testing.assert_allclose(third.evals, b.evals)


def test_eigenbasis_disk_cache_never_serves_a_slice(tmp_path, small_sphere, monkeypatch):
    """A stored 20-eigenpair basis does not answer a request for 10: the answer is what a
    solve for 10 gives, cache or not (slicing a larger solve is not the same bits)."""
    from topomatch import _cache

    monkeypatch.setattr(_cache, "_CACHE_DIR", None)
    monkeypatch.delenv("TOPOMATCH_CACHE_DIR", raising=False)
    solved = TriangleMesh(small_sphere.vertices, small_sphere.faces).eigenbasis(10)
    monkeypatch.setattr(_cache, "_CACHE_DIR", tmp_path)
    TriangleMesh(small_sphere.vertices, small_sphere.faces).eigenbasis(20)
    got = TriangleMesh(small_sphere.vertices, small_sphere.faces).eigenbasis(10)
    np.testing.assert_array_equal(got.evecs, solved.evecs)
    assert len(list((tmp_path / "eigen").glob("*.npz"))) == 2  # one entry per k
    again = TriangleMesh(small_sphere.vertices, small_sphere.faces).eigenbasis(10)
    np.testing.assert_array_equal(again.evecs, solved.evecs)  # now from the disk


@pytest.fixture
def fork_ready(monkeypatch):
    """Forking for small meshes too (the test spheres are below the default size), and the
    disk cache off (other tests may have turned it on: a cached basis is loaded, not forked for)."""
    import topomatch.mesh.mesh as mesh_module
    from topomatch import _cache

    monkeypatch.setattr(_cache, "_CACHE_DIR", None)
    monkeypatch.delenv("TOPOMATCH_CACHE_DIR", raising=False)
    monkeypatch.setattr(mesh_module, "BACKGROUND_MIN_VERTICES", 0)


def test_eigenbasis_in_background_is_the_same_basis(small_sphere, fork_ready):
    here = TriangleMesh(small_sphere.vertices, small_sphere.faces).eigenbasis(15)
    m = TriangleMesh(small_sphere.vertices, small_sphere.faces)
    job = m.eigenbasis_in_background(15)
    assert job._process is not None  # a child computes it (Linux has fork)
    b = job.result()
    np.testing.assert_array_equal(b.evals, here.evals)
    np.testing.assert_array_equal(b.evecs, here.evecs)
    assert m._has_eigenbasis(15, "robust")  # adopted by the mesh: no second solve
    assert m.eigenbasis_in_background(10)._process is None  # already there: nothing forked
    np.testing.assert_array_equal(m.eigenbasis(10).evecs, here.evecs[:, :10])


def test_eigenbasis_in_background_not_beside_other_threads(small_sphere, fork_ready):
    import threading

    stop = threading.Event()
    other = threading.Thread(target=stop.wait)  # a caller's own (non-daemon) thread
    other.start()
    try:
        job = TriangleMesh(small_sphere.vertices, small_sphere.faces).eigenbasis_in_background(12)
        assert job._process is None  # computed in this process, at result()
        assert job.result().k == 12
    finally:
        stop.set()
        other.join()


def _background_job_in_daemon(vertices, faces, out):  # runs in a daemonic child process
    import topomatch.mesh.mesh as mesh_module

    mesh_module.BACKGROUND_MIN_VERTICES = 0
    job = TriangleMesh(vertices, faces).eigenbasis_in_background(8)
    out.put((job._process is None, job.result().k))


def test_eigenbasis_in_background_not_in_a_daemonic_process(small_sphere, fork_ready):
    # a daemonic multiprocessing child may not start processes (start() raises): computed there
    import multiprocessing

    ctx = multiprocessing.get_context("fork")
    out = ctx.Queue()
    p = ctx.Process(target=_background_job_in_daemon, args=(small_sphere.vertices, small_sphere.faces, out), daemon=True)
    p.start()
    try:
        assert out.get(timeout=60) == (True, 8)
    finally:
        p.join(timeout=60)
    assert p.exitcode == 0


def test_eigenbasis_in_background_loads_a_cached_basis(small_sphere, tmp_path, monkeypatch):
    import topomatch.mesh.mesh as mesh_module
    from topomatch import _cache

    monkeypatch.setattr(mesh_module, "BACKGROUND_MIN_VERTICES", 0)  # only the cache stops the fork
    monkeypatch.setattr(_cache, "_CACHE_DIR", tmp_path)
    first = TriangleMesh(small_sphere.vertices, small_sphere.faces).eigenbasis(12)  # stored
    job = TriangleMesh(small_sphere.vertices, small_sphere.faces).eigenbasis_in_background(12)
    assert job._process is None  # loading beats forking
    np.testing.assert_array_equal(job.result().evecs, first.evecs)


def test_eigenbasis_in_background_failure_recomputes_here(small_sphere, caplog, fork_ready):
    m = TriangleMesh(small_sphere.vertices, small_sphere.faces)
    job = m.eigenbasis_in_background(10_000)  # the child fails: too many eigenpairs
    with pytest.raises(ValueError, match="1 <= k"):  # the same error as computing it here
        job.result()
    assert "background eigenbasis failed" in caplog.text
    abandoned = m.eigenbasis_in_background(12)
    process = abandoned._process
    del abandoned  # an abandoned job leaves no child behind
    assert not process.is_alive()


def test_unreferenced_vertex_gets_zero(small_sphere):
    v = np.vstack([small_sphere.vertices, [[3.0, 3, 3]]])
    m = TriangleMesh(v, small_sphere.faces)
    b = m.eigenbasis(8)
    assert np.all(b.evecs[-1] == 0)
    assert b.evals[1] > 1e-3  # no spurious zero eigenvalue from the lone vertex


def test_projection_round_trip(sphere):
    b = sphere.eigenbasis(25)
    f = b.evecs @ np.arange(25.0)
    np.testing.assert_allclose(b.project(f), np.arange(25.0), atol=1e-8)
    np.testing.assert_allclose(b.reconstruct(b.project(f)), f, atol=1e-8)
