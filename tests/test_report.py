"""Reports: figures, Table 1 and the HTML page, built from a tiny real run directory."""

from __future__ import annotations

import base64
import csv
import io
import json
import re
import shutil
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from topomatch.datasets.toy import icosphere
from topomatch.evaluation.rundir import RunDir
from topomatch.evaluation.tables import to_latex, to_markdown, track_rows
from topomatch.report.colors import GREY, position_colors, transfer_colors
from topomatch.report.render import View
from topomatch.report.results import RunResults, collect_series

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def report(report_run, tmp_path_factory):
    from topomatch.report import build_report

    out = tmp_path_factory.mktemp("out") / "report"
    html = build_report([report_run], out)
    return report_run, out, html


def _png(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB")).astype(int)


# -- plotting stays out of the library ------------------------------------------------------


def test_plotting_libraries_load_only_when_a_report_is_made(report_run, tmp_path):
    code = (
        "import sys, topomatch, topomatch.report, topomatch.evaluation.benchmark, topomatch.cli.main\n"
        "from topomatch.report import build_report\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('matplotlib', 'plotly', 'PIL')))\n"
        f"build_report([{str(report_run)!r}], {str(tmp_path / 'r')!r}, renderings=False, html=False)\n"
        "print('matplotlib' in sys.modules)\n"  # the first check could fail: making a report does import it
        "print('matplotlib.pyplot' in sys.modules)"  # but not pyplot: no global state, no backend switch
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env={"PYTHONPATH": str(ROOT / "src")})
    assert out.stdout.split("\n")[:3] == ["[]", "True", "False"]


# -- what gets written ------------------------------------------------------------------------


def test_build_report_writes_figures_tables_and_html(report):
    _, out, html = report
    assert html == out / "report.html"
    index = json.loads((out / "report.json").read_text())
    for name in ("curves_shrec16.png", "breakdown_shrec16.png", "curves_topkids25.png", "breakdown_topkids25.png", "pairs_builtin.png"):
        assert name in index["files"]["figures"]
        img = _png(out / name)
        assert img.shape[0] > 200 and img.shape[1] > 300
        assert len(np.unique(img.reshape(-1, 3), axis=0)) > 20  # not a blank canvas
    for name in ("table1.md", "table1.csv", "table1.tex", "report.html"):
        assert (out / name).stat().st_size > 100
    assert index["n_mesh_renderings"] == 6  # descriptor-nn best + worst, oracle best only (all pairs tie)
    assert index["seconds"]["per_mesh_rendering_median"] > 0
    assert index["viewer"]["pairs_embedded"] == 2 * 12


def test_table1_comes_from_the_summary(report):
    run, out, _ = report
    summary = RunDir(run).summary()
    rows = list(csv.DictReader(io.StringIO((out / "table1.csv").read_text())))
    assert [r["method"] for r in rows] == ["descriptor-nn", "oracle (uses ground truth)"]
    for r in rows:
        m = r["method"].split(" ")[0]
        s = summary["methods"][m]["shrec16"]
        assert r["AUC avg"] == f"{s['auc_mean']:.3f}"
        assert r["AUC worst"] == f"{s['auc_worst']:.3f}"
        assert r["area matched %"] == f"{100 * s['area_matched']:.2f}"
        assert r["best pair"] == s["auc_best_pair"]
        t = summary["methods"][m]["topkids25"]["mean_error"]
        assert r["topkids25 error x100"] == f"dijkstra {t['dijkstra']:.2f}; heat {t['heat']:.2f}"
        assert r["pairs"] == "12/12"
    assert rows[1]["AUC avg"] == "1.000"
    assert "\\toprule" in (out / "table1.tex").read_text()


def test_track_rows_bold_marks_the_best_method_without_ground_truth():
    def block(auc, area, err):
        return {
            "shrec16": {"auc_mean": auc, "auc_best": auc + 0.1, "auc_worst": auc - 0.1, "area_matched": area, "n_pairs": 90, "n_pairs_expected": 90},
            "topkids25": {"mean_error": {"dijkstra": err}, "primary_geodesic": "dijkstra"},
        }

    entries = [
        ("low res", "a", block(0.4, 0.3, 20.0), False),
        ("low res", "b", block(0.5, 0.2, 30.0), False),
        ("low res", "oracle", block(1.0, 0.9, 0.0), True),
        ("high res", "a", block(0.3, 0.3, 25.0), False),
    ]
    rows, bold = track_rows(entries)
    assert ("AUC avg" in rows[0]) and rows[1]["AUC avg"] == "0.500"
    assert (1, "AUC avg") in bold and (0, "AUC avg") not in bold
    assert (0, "area matched %") in bold and (0, "topkids25 error x100") in bold
    assert not any(i == 2 for i, _ in bold)  # the oracle is never bold
    assert not any(i == 3 for i, _ in bold)  # alone in its group
    assert "**0.500**" in to_markdown(rows, bold)
    assert r"\textbf{0.500}" in to_latex(rows, bold)


def test_curves_are_the_stored_ones(report_run):
    r = RunResults.load(report_run)
    summary = r.summary["methods"]["descriptor-nn"]["shrec16"]["geodesics"]["heat"]
    t, curves, pairs, aucs = r.curves("shrec16", "descriptor-nn")
    assert curves.shape == (12, 26) and len(pairs) == 12
    np.testing.assert_allclose(t, summary["thresholds"])
    np.testing.assert_allclose(curves.mean(axis=0), summary["curve_mean"], atol=1e-12)
    np.testing.assert_allclose(aucs.mean(), summary["auc_mean"], atol=1e-12)
    b, w = r.best_worst("shrec16", "descriptor-nn", pairs, aucs)
    assert pairs[b] == summary["auc_best_pair"] and pairs[w] == summary["auc_worst_pair"]


def test_report_never_matches_or_scores_again(report_run, tmp_path, monkeypatch):
    import topomatch.evaluation.scoring as scoring
    from topomatch.matching.base import Matcher
    from topomatch.report import build_report

    def boom(*a, **k):
        raise AssertionError("the report recomputed something")

    monkeypatch.setattr(scoring, "score_maps", boom)
    monkeypatch.setattr(Matcher, "match", boom)
    for cls in __import__("topomatch.matching", fromlist=["MATCHERS"]).MATCHERS.values():
        monkeypatch.setattr(cls, "match", boom)
    assert build_report([report_run], tmp_path / "r").is_file()


# -- the HTML page ----------------------------------------------------------------------------


def _viewer_data(html: Path) -> dict:
    text = html.read_text()
    m = re.search(r'<script type="application/json" id="topomatch-data">(.*?)</script>', text, re.S)
    assert m, "no embedded viewer data"
    return json.loads(m.group(1))


def _decode(blob: dict) -> np.ndarray:
    return np.frombuffer(zlib.decompress(base64.b64decode(blob["z"])), dtype="<" + blob["dtype"])


def test_html_is_self_contained(report):
    _, _, html = report
    text = html.read_text()
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", text)
    assert "url(http" not in text and "@import" not in text
    assert text.count("data:image/png;base64,") == 5
    assert "<canvas id=\"viewer-canvas\"" in text


def test_html_embeds_the_stored_maps_and_meshes(report):
    run, _, html = report
    data = _viewer_data(html)
    (group,) = data["groups"]
    assert group["name"] == "builtin" and group["protocol"] == "shrec16"
    assert len(group["pairs"]) == group["n_pairs_total"] == 12
    rd = RunDir(run)
    coll = RunResults.load(run).collection
    for m in group["methods"]:
        for pid, entry in m["pairs"].items():
            p2p = rd.load_map(m["method"], pid)["p2p_21"]
            got = _decode(entry["map"]).astype(np.int64)
            got[got == 65535] = -1
            np.testing.assert_array_equal(got, p2p)
            err = rd.load_score("shrec16", "heat", m["method"], pid, with_errors=True)["errors"]
            q = _decode(entry["errors"]).astype(float)
            ok = ~np.isnan(err)
            np.testing.assert_array_equal(q == 65535, ~ok)
            np.testing.assert_allclose(q[ok] * data["error_unit"], err[ok], atol=0.6 * data["error_unit"])
    for name, shp in group["shapes"].items():
        mesh = coll[name].mesh
        np.testing.assert_array_equal(_decode(shp["faces"]).reshape(-1, 3), mesh.faces)
        np.testing.assert_allclose(_decode(shp["vertices"]).reshape(-1, 3), mesh.vertices, rtol=1e-6, atol=1e-6)


def test_viewer_budget_keeps_best_and_worst_and_says_so(report_run, tmp_path):
    from topomatch.report import build_report

    html = build_report([report_run], tmp_path / "r", renderings=False, max_html_mb=0.05)
    data = _viewer_data(html)
    (group,) = data["groups"]
    assert 0 < len(group["pairs"]) < 12
    summary = RunDir(report_run).summary()["methods"]["descriptor-nn"]["shrec16"]
    assert {summary["auc_best_pair"], summary["auc_worst_pair"]} <= set(group["pairs"])
    assert "pairs not embedded" in html.read_text()


# -- several runs -----------------------------------------------------------------------------


def test_two_runs_get_panels_and_distinct_labels(report_run, tmp_path):
    from topomatch.report import build_report

    other = tmp_path / "other"
    shutil.copytree(report_run, other, ignore=shutil.ignore_patterns("report"))
    series = collect_series([RunResults.load(report_run), RunResults.load(other)])
    labels = [s.label for s in series]
    assert len(set(labels)) == 4 and any("[other]" in lab for lab in labels)
    # a "high res" copy: a second panel (its meshes are not there, so no renderings)
    m = json.loads((other / "manifest.json").read_text())
    m["config"].update(dataset="topkids", resolution="high", data_dir=str(tmp_path / "absent"))
    (other / "manifest.json").write_text(json.dumps(m))
    build_report([report_run, other], tmp_path / "both", html=False, renderings=False)
    img = _png(tmp_path / "both" / "curves_shrec16.png")
    assert img.shape[1] > 1.5 * img.shape[0]  # two panels side by side
    rows = list(csv.DictReader(io.StringIO((tmp_path / "both" / "table1.csv").read_text())))
    assert [r["data"] for r in rows] == ["builtin", "builtin", "high res", "high res"]


def test_missing_meshes_are_a_note_not_a_crash(report_run, tmp_path):
    from topomatch.report import build_report

    other = tmp_path / "moved"
    shutil.copytree(report_run, other, ignore=shutil.ignore_patterns("report"))
    m = json.loads((other / "manifest.json").read_text())
    m["config"].update(dataset="topkids", data_dir=str(tmp_path / "absent"))
    (other / "manifest.json").write_text(json.dumps(m))
    html = build_report([other], tmp_path / "r")
    text = html.read_text()
    assert "renderings of low res skipped" in text and "is not here" in text
    assert (tmp_path / "r" / "curves_shrec16.png").is_file()


# -- bad input --------------------------------------------------------------------------------


def test_bad_input(tmp_path, report_run):
    from topomatch.report import build_report

    with pytest.raises(ValueError, match="at least one"):
        build_report([], tmp_path)
    with pytest.raises(TypeError, match="list of run directories"):
        build_report(str(report_run), tmp_path)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="no such folder"):
        build_report([tmp_path / "nope"], tmp_path)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match=r"summary\.json"):
        build_report([tmp_path / "empty"], tmp_path)


def test_cli_report(report_run, tmp_path, capsys):
    from topomatch.cli.main import main

    assert main(["report", str(report_run), "--out", str(tmp_path / "r"), "--no-render"]) == 0
    out = capsys.readouterr()
    assert "| data" in out.out and "report written" in out.err
    assert (tmp_path / "r" / "report.html").is_file() and not (tmp_path / "r" / "pairs_builtin.png").exists()
    assert main(["report", str(tmp_path / "nope")]) == 2
    assert "not a run directory" in capsys.readouterr().err


# -- colours and rendering --------------------------------------------------------------------


def test_transfer_colors_follow_the_map():
    src = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    c = position_colors(src)
    assert c.min() >= 0.1 - 1e-12 and c.max() <= 0.95 + 1e-12
    p2p = np.array([2, -1, 0, 2, 3])
    s_rgb, t_rgb = transfer_colors(p2p, c)
    np.testing.assert_allclose(t_rgb[[0, 2, 3, 4]], c[[2, 0, 2, 3]])
    np.testing.assert_allclose(t_rgb[1], GREY)
    np.testing.assert_allclose(s_rgb[[0, 2, 3]], c[[0, 2, 3]])
    assert not np.allclose(s_rgb[1], c[1])  # vertex 1 is reached by nothing: faded
    _, plain = transfer_colors(p2p, c, fade_unhit=False)
    np.testing.assert_allclose(plain, t_rgb)
    with pytest.raises(ValueError, match=r"\[-1, 3\]"):
        transfer_colors(np.array([4]), c)
    with pytest.raises(ValueError, match="shape"):
        position_colors(np.zeros((3, 2)))


def test_view_basis_and_front_view():
    right, up, cam = View(elev=0).basis()
    np.testing.assert_allclose(np.array([right, up, cam]) @ np.array([right, up, cam]).T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(right, [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(up, [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(cam, [0, -1, 0], atol=1e-12)
    with pytest.raises(ValueError, match="up"):
        View(up="w").basis()


def test_render_mesh_puts_the_top_at_the_top(tmp_path):
    from topomatch.report.render import save_rendering

    mesh = icosphere(3)
    z = mesh.vertices[:, 2]
    colors = np.zeros((mesh.n_vertices, 3))
    colors[z > 0, 0] = 1.0  # red upper half
    colors[z <= 0, 2] = 1.0  # blue lower half
    assert save_rendering(tmp_path / "s.png", mesh.vertices, mesh.faces, colors, View(elev=0), size=(3, 3), dpi=80) > 0
    img = _png(tmp_path / "s.png")
    h = img.shape[0]
    top, bottom = img[h // 2 - 40 : h // 2 - 10], img[h // 2 + 10 : h // 2 + 40]
    assert top[..., 0].mean() > top[..., 2].mean() + 40
    assert bottom[..., 2].mean() > bottom[..., 0].mean() + 40
    with pytest.raises(ValueError, match="vertex_colors"):
        save_rendering(tmp_path / "t.png", mesh.vertices, mesh.faces, colors[:5])


def test_runs_with_different_protocols_combine(report_run, tmp_path):
    """A run that scored only topkids25 beside one that scored both: no crash, both tables."""
    from topomatch.report import build_report

    only = tmp_path / "tk25"
    shutil.copytree(report_run, only, ignore=shutil.ignore_patterns("report"))
    shutil.rmtree(only / "scores" / "shrec16")
    m = json.loads((only / "manifest.json").read_text())
    m["protocols"].pop("shrec16")
    (only / "manifest.json").write_text(json.dumps(m))
    summary = json.loads((only / "summary.json").read_text())
    for blocks in summary["methods"].values():
        blocks.pop("shrec16", None)
    (only / "summary.json").write_text(json.dumps(summary))
    build_report([only, report_run], tmp_path / "mixed")
    assert (tmp_path / "mixed" / "curves_shrec16.png").exists()
    assert (tmp_path / "mixed" / "curves_topkids25.png").exists()
