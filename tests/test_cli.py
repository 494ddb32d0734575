import json

import numpy as np
import pytest

from topomatch.cli import main
from topomatch.io import read_p2p, write_mesh, write_p2p

from .conftest import DATA, data_path


def test_bench_builtin_prints_table(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("TOPOMATCH_DATA", raising=False)
    monkeypatch.setenv("TOPOMATCH_CACHE_DIR", str(tmp_path / "cache"))
    rc = main(["bench", "--out", str(tmp_path / "run"), "--method", "oracle", "--protocol", "shrec16", "--quiet"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "oracle (uses ground truth)" in out and "1.000" in out
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["methods"]["oracle"]["shrec16"]["auc_mean"] == 1.0
    assert (tmp_path / "run" / "report" / "table1.tex").is_file()
    assert (tmp_path / "run" / "report" / "report.html").is_file()


def test_bench_rejects_bad_data_dir(tmp_path, capsys):
    rc = main(["bench", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "r"), "--quiet"])
    assert rc == 2
    assert "does not exist" in capsys.readouterr().err


def test_match_writes_a_map(tmp_path, small_sphere):
    write_mesh(tmp_path / "a.off", small_sphere.vertices, small_sphere.faces)
    write_mesh(tmp_path / "b.ply", small_sphere.vertices, small_sphere.faces)
    rc = main(["match", str(tmp_path / "a.off"), str(tmp_path / "b.ply"), "--out", str(tmp_path / "m.txt"),
               "--method", "descriptor-nn", "--param", "k=30", "--param", "n_descriptors=20"])
    assert rc == 0
    p = read_p2p(tmp_path / "m.txt", small_sphere.n_vertices, small_sphere.n_vertices)
    assert p.min() >= 0
    assert main(["match", str(tmp_path / "a.off"), str(tmp_path / "b.ply"), "--out", str(tmp_path / "m.npy"), "--method", "descriptor-nn"]) == 0
    assert np.load(tmp_path / "m.npy").shape == (small_sphere.n_vertices,)
    assert main(["match", str(tmp_path / "a.off"), str(tmp_path / "missing.off"), "--out", str(tmp_path / "x.txt")]) == 2


@pytest.mark.data
def test_evaluate_a_submission_folder(tmp_path, topkids_low, capsys):
    """Write the ground truth for two pairs as files, score them; the rest are reported missing."""
    from topomatch.datasets.base import ground_truth_21
    from topomatch.evaluation.protocols import get_protocol

    sub = tmp_path / "sub"
    sub.mkdir()
    for pr in get_protocol("topkids25").pairs(topkids_low, "test")[:2]:
        g = ground_truth_21(topkids_low[pr.target], topkids_low[pr.source])
        write_p2p(sub / f"{pr.target}_{pr.source}.txt", g.indices[g.indptr[:-1]])
    rc = main(["evaluate", str(sub), "--protocol", "topkids25", "--split", "test", "--data", str(DATA), "--out", str(tmp_path / "ev"), "--geodesic", "heat", "--quiet"])
    assert rc == 0
    s = json.loads((tmp_path / "ev" / "summary.json").read_text())["methods"]["submission"]["topkids25"]
    assert s["n_pairs"] == 2 and s["n_failed"] == 8 and s["mean_error"]["heat"] == 0.0


@pytest.mark.data
def test_data_info(capsys):
    data_path("topkids", "low_res", "kid25.off")
    rc = main(["data", "info", "--data", str(DATA), "--resolution", "low"])
    out = capsys.readouterr().out
    assert rc == 0 and "kid25" in out and "low res" in out


@pytest.mark.data
def test_evaluate_rescores_a_run_directory_maps(tmp_path, topkids_low, capsys):
    """``.npz`` map files of a run directory (their ``p2p_21``) are read; other ``.npz`` are refused."""
    from topomatch.datasets.base import ground_truth_21
    from topomatch.evaluation.protocols import get_protocol

    sub = tmp_path / "maps"
    sub.mkdir()
    pr = get_protocol("topkids25").pairs(topkids_low, "test")[0]
    g = ground_truth_21(topkids_low[pr.target], topkids_low[pr.source])
    np.savez(sub / f"{pr.id}.npz", p2p_21=g.indices[g.indptr[:-1]], seconds=1.0)
    rc = main(["evaluate", str(sub), "--protocol", "topkids25", "--split", "test", "--data", str(DATA), "--out", str(tmp_path / "ev"), "--geodesic", "heat", "--quiet"])
    assert rc == 0
    s = json.loads((tmp_path / "ev" / "summary.json").read_text())["methods"]["submission"]["topkids25"]
    assert s["n_pairs"] == 1 and s["mean_error"]["heat"] == 0.0
    np.savez(sub / f"{pr.id}.npz", other=np.zeros(3))
    rc = main(["evaluate", str(sub), "--protocol", "topkids25", "--split", "test", "--data", str(DATA), "--out", str(tmp_path / "ev2"), "--geodesic", "heat", "--quiet"])
    assert rc == 2 and "p2p_21" in capsys.readouterr().err


def test_match_without_a_template_defaults_to_the_flagship_s_registration(tmp_path, capsys):
    # a shape without symmetry matched to a shuffled copy of itself: deform finds the identity
    from ._fmap_shapes import bumpy, shuffled

    src = bumpy(3, mirror_symmetric=False)
    tgt, perm = shuffled(src, seed=1)
    write_mesh(tmp_path / "a.off", src.vertices, src.faces)
    write_mesh(tmp_path / "b.off", tgt.vertices, tgt.faces)
    assert main(["match", str(tmp_path / "a.off"), str(tmp_path / "b.off"), "--out", str(tmp_path / "m.npy")]) == 0
    assert "deform:" in capsys.readouterr().err
    assert np.mean(np.load(tmp_path / "m.npy") == perm) > 0.95


def test_match_through_a_template(tmp_path, capsys):
    # template = a shape without symmetry; source and target = two shuffled copies of it:
    # both registrations are exact, so the composed map is the copies' relative permutation
    from ._fmap_shapes import bumpy, shuffled

    tmpl = bumpy(3, mirror_symmetric=False)
    src, perm_s = shuffled(tmpl, seed=1)
    tgt, perm_t = shuffled(tmpl, seed=2)
    for name, m in (("t.off", tmpl), ("a.off", src), ("b.off", tgt)):
        write_mesh(tmp_path / name, m.vertices, m.faces)
    # one sampling start instead of the five of a template without poses: the plumbing is under test here
    one = ["--param", 'template.deform={"n_starts": 1}']
    args = ["match", str(tmp_path / "a.off"), str(tmp_path / "b.off"), "--out", str(tmp_path / "m.npy")]
    assert main([*args, "--method", "template"]) == 2
    assert "--template PATH" in capsys.readouterr().err
    # --template: the default method is then template (the flagship)
    assert main([*args, *one, "--template", str(tmp_path / "t.off")]) == 0
    assert "template through t (0 training poses)" in capsys.readouterr().err
    # target vertex i is template vertex perm_t[i]; source vertex j is template vertex perm_s[j]
    expected = np.argsort(perm_s)[perm_t]
    got = np.load(tmp_path / "m.npy")
    assert np.mean(got == expected) > 0.95
    # the same through --param template.model=PATH
    assert main([*args, *one, "--method", "template", "--param", f"template.model={tmp_path / 't.off'}"]) == 0
    np.testing.assert_array_equal(np.load(tmp_path / "m.npy"), got)
    # a template for another method, or two templates: refused before any work
    assert main([*args, "--template", str(tmp_path / "t.off"), "--method", "deform"]) == 2
    assert "--template is the template of method 'template'" in capsys.readouterr().err
    assert main([*args, "--template", str(tmp_path / "t.off"), "--param", f"template.model={tmp_path / 'a.off'}"]) == 2
    assert "two templates" in capsys.readouterr().err
    assert main([*args, "--template", str(tmp_path / "none.off")]) == 2
    assert "none.off" in capsys.readouterr().err


def test_param_values_parse_like_python_and_shell_booleans():
    from topomatch.cli.main import _parse_params

    p = _parse_params(["deform.background_eigenbasis=false", "deform.k_zoomout=80", "n_threads=1", "fmap.note=abc"], ["deform", "fmap"])
    assert p["deform"] == {"background_eigenbasis": False, "k_zoomout": 80, "n_threads": 1}
    assert p["fmap"] == {"n_threads": 1, "note": "abc"}
    assert _parse_params(["x.flag=True"])["x"]["flag"] is True
    # a dict typed as JSON (null, true) parses too, and the same dict typed as Python
    js = _parse_params(['template.deform={"pose_sources": 4, "refine_runs": null, "limb": true}'])["template"]["deform"]
    assert js == {"pose_sources": 4, "refine_runs": None, "limb": True}
    assert _parse_params(["template.deform={'pose_sources': 4, 'refine_runs': None, 'limb': True}"])["template"]["deform"] == js


@pytest.mark.parametrize("flags, cached", [([], True), (["--no-cache"], False)])
def test_evaluate_keeps_geodesic_matrices_in_the_disk_cache(tmp_path, monkeypatch, flags, cached):
    # the exact all-pairs matrix of kid00 takes the better part of an hour: a second
    # evaluation must find it (as bench does), unless --no-cache
    from topomatch import _cache

    monkeypatch.setattr(_cache, "_CACHE_DIR", None)
    monkeypatch.setenv("TOPOMATCH_CACHE_DIR", "")  # off, and restored afterwards
    monkeypatch.setattr(_cache, "default_cache_dir", lambda: tmp_path / "cache")
    main(["evaluate", str(tmp_path / "none"), "--protocol", "topkids25", "--data", str(tmp_path), "--out", str(tmp_path / "ev"), "--quiet", *flags])
    assert (_cache.cache_dir() == tmp_path / "cache") is cached
