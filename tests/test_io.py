import numpy as np
import pytest

from topomatch.io import (
    read_indmap,
    read_mesh,
    read_p2p,
    read_ref,
    read_shrec16_map,
    read_sym,
    read_vts,
    write_indmap,
    write_mesh,
    write_p2p,
    write_ref,
    write_shrec16_map,
    write_sym,
    write_vts,
)
from topomatch.io.meshes import write_ply

from .conftest import data_path


@pytest.mark.parametrize("suffix", [".off", ".ply", ".obj"])
def test_mesh_round_trip(tmp_path, sphere, suffix):
    p = tmp_path / f"m{suffix}"
    write_mesh(p, sphere.vertices, sphere.faces)
    v, f = read_mesh(p)
    np.testing.assert_allclose(v, sphere.vertices, rtol=1e-8, atol=1e-9)
    np.testing.assert_array_equal(f, sphere.faces)


def test_ply_ascii_and_big_endian(tmp_path, small_sphere):
    write_ply(tmp_path / "a.ply", small_sphere.vertices, small_sphere.faces, binary=False)
    v, f = read_mesh(tmp_path / "a.ply")
    np.testing.assert_allclose(v, small_sphere.vertices)
    np.testing.assert_array_equal(f, small_sphere.faces)
    # big-endian binary with float vertices and an extra property, written by hand
    V = small_sphere.vertices.astype(">f4")
    header = (
        f"ply\nformat binary_big_endian 1.0\ncomment hand made\nelement vertex {len(V)}\n"
        "property float x\nproperty float y\nproperty float z\nproperty uchar red\n"
        f"element face {len(small_sphere.faces)}\nproperty list uchar uint vertex_indices\nend_header\n"
    ).encode()
    vrec = np.zeros(len(V), dtype=[("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("r", "u1")])
    vrec["x"], vrec["y"], vrec["z"] = V[:, 0], V[:, 1], V[:, 2]
    frec = np.zeros(len(small_sphere.faces), dtype=[("n", "u1"), ("i", ">u4", (3,))])
    frec["n"] = 3
    frec["i"] = small_sphere.faces
    (tmp_path / "b.ply").write_bytes(header + vrec.tobytes() + frec.tobytes())
    v, f = read_mesh(tmp_path / "b.ply")
    np.testing.assert_allclose(v, small_sphere.vertices, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(f, small_sphere.faces)


def test_polygons_are_fanned(tmp_path):
    (tmp_path / "q.off").write_text("OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n")
    _, f = read_mesh(tmp_path / "q.off")
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3]])
    (tmp_path / "q.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1/1 2/2 3/3 -1\n")
    _, f = read_mesh(tmp_path / "q.obj")
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("OFX\n3 1 0\n", "expected an 'OFF' header"),
        ("OFF\n3 1 0\n0 0 0\n1 0 0\n", "unexpected end of file, expected vertex 2"),
        ("OFF\n3 1 0\n0 0 0\n1 0 x\n0 1 0\n3 0 1 2\n", r":4: expected three coordinates for vertex 1"),
        ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", "face 0 refers to vertex"),
        ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n", r":6: face 0 declares 4 corners"),
        ("OFF\nthree 1 0\n", r":2: expected 'n_vertices n_faces"),
    ],
)
def test_malformed_off_names_file_and_line(tmp_path, text, match):
    p = tmp_path / "bad.off"
    p.write_text(text)
    with pytest.raises(ValueError, match=match) as err:
        read_mesh(p)
    assert "bad.off" in str(err.value)


def test_a_file_without_faces_is_not_a_mesh(tmp_path):
    from topomatch.mesh import TriangleMesh

    p = tmp_path / "points.off"
    p.write_text("OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n")
    v, f = read_mesh(p)  # a point cloud is a valid file
    assert v.shape == (3, 3) and f.shape == (0, 3)
    with pytest.raises(ValueError, match=r"points\.off: no faces"):
        TriangleMesh.from_file(p)


def test_unknown_suffix_and_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such mesh"):
        read_mesh(tmp_path / "nope.off")
    (tmp_path / "x.stl").write_text("solid")
    with pytest.raises(ValueError, match="unknown mesh format"):
        read_mesh(tmp_path / "x.stl")


def test_truncated_binary_ply(tmp_path, small_sphere):
    write_ply(tmp_path / "t.ply", small_sphere.vertices, small_sphere.faces)
    data = (tmp_path / "t.ply").read_bytes()
    (tmp_path / "t.ply").write_bytes(data[:-10])
    with pytest.raises(ValueError, match=r"t\.ply"):
        read_mesh(tmp_path / "t.ply")


def test_ref_round_trip_many_to_many(tmp_path):
    pairs = np.array([[0, 5], [0, 6], [2, 5], [3, 0]])
    write_ref(tmp_path / "r.txt", pairs)
    np.testing.assert_array_equal(read_ref(tmp_path / "r.txt", 4, 7), pairs)
    with pytest.raises(ValueError, match=r"r.txt:\d+: second-column index 7 outside \[1, 6\]"):
        read_ref(tmp_path / "r.txt", 4, 6)


def test_ref_errors(tmp_path):
    (tmp_path / "r.txt").write_text("1 2\n2 3 4\n")
    with pytest.raises(ValueError, match=r"r.txt:2: expected 2 column"):
        read_ref(tmp_path / "r.txt")
    (tmp_path / "r.txt").write_text("1 2\n2 x\n")
    with pytest.raises(ValueError, match=r"r.txt:2: expected a number"):
        read_ref(tmp_path / "r.txt")
    (tmp_path / "r.txt").write_text("1 2\n2 3.5\n")
    with pytest.raises(ValueError, match=r"r.txt:2: expected integer"):
        read_ref(tmp_path / "r.txt")


def test_sym_formats(tmp_path):
    sym = np.array([1, 0, -1, 4, 3])
    write_sym(tmp_path / "s.txt", sym)
    np.testing.assert_array_equal(read_sym(tmp_path / "s.txt", 5), sym)
    # one column (null shape), float formatted, written as one row with CRLF
    (tmp_path / "s0.txt").write_bytes(b"   2.0000000e+00   1.0000000e+00   0.0000000e+00   5.0000000e+00   4.0000000e+00\r\n")
    np.testing.assert_array_equal(read_sym(tmp_path / "s0.txt", 5), sym)
    (tmp_path / "s1.txt").write_bytes(b"2\r\n1\r\n0\r\n5\r\n4\r\n")
    np.testing.assert_array_equal(read_sym(tmp_path / "s1.txt", 5), sym)
    with pytest.raises(ValueError, match="one per vertex"):
        read_sym(tmp_path / "s1.txt", 6)


def test_indmap_vts_p2p(tmp_path):
    m = np.array([True, False, False, True])
    write_indmap(tmp_path / "i.txt", m)
    np.testing.assert_array_equal(read_indmap(tmp_path / "i.txt", 4), m)
    (tmp_path / "bad.txt").write_text("0\n2\n")
    with pytest.raises(ValueError, match=r"bad.txt:2: expected 0 or 1"):
        read_indmap(tmp_path / "bad.txt")
    write_vts(tmp_path / "v.vts", np.array([3, 0, 2]))
    np.testing.assert_array_equal(read_vts(tmp_path / "v.vts", 4), [3, 0, 2])
    p = np.array([2, -1, 0])
    write_p2p(tmp_path / "p.txt", p)
    np.testing.assert_array_equal(read_p2p(tmp_path / "p.txt", 3, 3), p)
    with pytest.raises(ValueError, match="expected one per vertex"):
        read_p2p(tmp_path / "p.txt", 4)


def test_shrec16_submission_round_trip(tmp_path, small_sphere):
    rng = np.random.default_rng(0)
    p = rng.integers(0, small_sphere.n_vertices, 50)
    p[::7] = -1
    write_shrec16_map(tmp_path / "s.txt", p, small_sphere.faces)
    np.testing.assert_array_equal(read_shrec16_map(tmp_path / "s.txt", small_sphere.faces, 50), p)
    # barycentric rows snap to the corner with the largest weight
    f = small_sphere.faces
    (tmp_path / "b.txt").write_text("3 0.2 0.7 0.1\n-1 0 0 0\n")
    out = read_shrec16_map(tmp_path / "b.txt", f, 2)
    assert out[0] == f[2, 1] and out[1] == -1
    (tmp_path / "w.txt").write_text("3 0.2 0.9 0.1\n")
    with pytest.raises(ValueError, match=r"w.txt:1: barycentric weights"):
        read_shrec16_map(tmp_path / "w.txt", f)
    (tmp_path / "t.txt").write_text(f"{len(f) + 1} 1 0 0\n")
    with pytest.raises(ValueError, match="triangle index"):
        read_shrec16_map(tmp_path / "t.txt", f)


@pytest.mark.data
def test_real_topkids_files():
    low = data_path("topkids", "low_res")
    sym0 = read_sym(low / "kid00_sym.txt", 12000)
    assert sym0.shape == (12000,) and sym0.min() >= -1
    ref = read_ref(low / "kid01_ref.txt", 8608, 12000)
    assert ref.shape == (8608, 2)
    np.testing.assert_array_equal(ref[:, 0], np.arange(8608))
    high = data_path("topkids", "high_res")
    sym_h = read_sym(high / "kid00_sym.txt", 59727)  # one CRLF-terminated row of floats
    assert (sym_h >= 0).mean() > 0.9
    refh = read_ref(high / "kid01_ref.txt", 57542, 59727)
    assert len(np.unique(refh[:, 0])) < len(refh)  # many-to-many at high res
    ind = read_indmap(high / "kid01_indmap.txt", 57542)
    assert 0 < ind.mean() < 0.3
