import numpy as np
import pytest

from topomatch.datasets.base import Shape, ground_truth_21
from topomatch.datasets.topkids import load_topkids, locate_topkids
from topomatch.io import write_indmap, write_mesh, write_ref, write_sym, write_vts


def write_release(root, builtin, names, *, high=False, skip=()):
    """Write builtin shapes in the TOPKIDS release layout (kid00 = syn00, kid01.. = poses)."""
    d = root / ("high_res" if high else "low_res")
    d.mkdir(parents=True)
    ref0 = builtin["syn00"]
    write_mesh(d / "kid00.off", ref0.mesh.vertices, ref0.mesh.faces)
    (d / "kid00_sym.txt").write_text("".join(f"{i + 1}\n" for i in ref0.sym))
    for k, n in enumerate(names, start=1):
        s = builtin[n]
        name = f"kid{k:02d}"
        if "mesh" not in skip:
            write_mesh(d / f"{name}.off", s.mesh.vertices, s.mesh.faces)
        r = s.ref.tocoo()
        write_ref(d / f"{name}_ref.txt", np.c_[r.row, r.col])
        if "sym" not in skip:
            write_sym(d / f"{name}_sym.txt", s.sym)
        if high:
            write_indmap(d / f"{name}_indmap.txt", s.unreliable)
    return d


def test_release_layout_round_trip(tmp_path, builtin):
    write_release(tmp_path, builtin, ["syn01", "syn02"])
    c = load_topkids(tmp_path, "low")
    assert c.names == ["kid00", "kid01", "kid02"]
    assert c.splits["train"][0] == "kid01" and c.splits["test"][0] == "kid16"
    np.testing.assert_array_equal(c["kid02"].ref_p2p, builtin["syn02"].ref_p2p)
    np.testing.assert_array_equal(c["kid02"].sym, builtin["syn02"].sym)
    g1 = ground_truth_21(c["kid01"], c["kid02"])
    plain = {n: Shape(n, builtin[n].mesh, ref=builtin[n].ref, sym=builtin[n].sym) for n in ("syn01", "syn02")}
    g2 = ground_truth_21(plain["syn01"], plain["syn02"])  # low res has no _indmap
    assert (g1 != g2).nnz == 0
    # the missing shapes are reported precisely
    assert any(m.startswith("kid03: kid03.off, kid03_ref.txt missing") for m in c.missing)


def test_missing_files_are_reported(tmp_path, builtin):
    write_release(tmp_path, builtin, ["syn01", "syn02"], high=True, skip=("sym",))
    (tmp_path / "high_res" / "kid02.off").unlink()
    c = load_topkids(tmp_path, "high")
    assert c.names == ["kid00", "kid01"]
    assert "kid02: kid02.off missing; shape skipped" in c.missing
    assert any("kid01_sym.txt" in m for m in c.missing)
    assert c["kid01"].sym is None and c["kid01"].unreliable is not None


def test_learning_layout(tmp_path, builtin):
    (tmp_path / "off").mkdir()
    (tmp_path / "corres").mkdir()
    write_mesh(tmp_path / "off" / "kid00.off", builtin["syn00"].mesh.vertices, builtin["syn00"].mesh.faces)
    s = builtin["syn03"]
    write_mesh(tmp_path / "off" / "kid01.off", s.mesh.vertices, s.mesh.faces)
    write_vts(tmp_path / "corres" / "kid01_ref.vts", s.ref_p2p)
    loc = locate_topkids(tmp_path, "low")
    assert loc is not None and loc.layout == "learning"
    c = load_topkids(tmp_path, "low")
    np.testing.assert_array_equal(c["kid01"].ref_p2p, s.ref_p2p)
    assert c["kid01"].sym is None


def test_errors(tmp_path, monkeypatch):
    monkeypatch.delenv("TOPOMATCH_DATA", raising=False)
    with pytest.raises(FileNotFoundError, match="no data directory"):
        load_topkids(None)
    with pytest.raises(FileNotFoundError, match="no TOPKIDS low-res data"):
        load_topkids(tmp_path, "low")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_topkids(tmp_path / "nope")
    (tmp_path / "low_res").mkdir()
    (tmp_path / "low_res" / "kid01.off").write_text("OFF\n0 0 0\n")
    with pytest.raises(FileNotFoundError, match="null shape is missing"):
        load_topkids(tmp_path)


def test_corrupt_ground_truth_names_the_file(tmp_path, builtin):
    d = write_release(tmp_path, builtin, ["syn01"])
    (d / "kid01_ref.txt").write_text("1 2\n2 99999\n")
    c = load_topkids(tmp_path)
    with pytest.raises(ValueError, match=r"kid01_ref.txt:2: second-column index 99999 outside"):
        c["kid01"]


def test_builtin_is_deterministic_and_has_shortcuts(builtin):
    from topomatch.datasets.builtin import builtin_benchmark

    again = builtin_benchmark()
    for n in builtin.names:
        np.testing.assert_array_equal(builtin[n].mesh.vertices, again[n].mesh.vertices)
    genus = [builtin[n].mesh.genus for n in builtin.names]
    assert max(genus) >= 1 and builtin["syn00"].mesh.genus == 0
    assert all(builtin[n].mesh.is_manifold for n in builtin.names)
