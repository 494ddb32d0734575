"""The HTML report in a real headless browser (the system's Chromium driven by Playwright).

Opens ``report.html`` from disk, fails on any console error or page error, checks the
3D canvas is drawn by reading pixels from screenshots, clicks a point of the target and
checks that the page shows the stored map's match (and draws its marker), rotates and
zooms with the mouse and switches method.

Needs Chromium (Debian: ``apt-get install chromium``; or set ``TOPOMATCH_CHROMIUM``) and
the ``playwright`` Python package; no browser is downloaded. ``.ci/browser-setup.sh``
installs both. Without them the test skips and says which is missing.
"""

from __future__ import annotations

import io
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
BACKGROUND = np.array([247, 247, 250])  # the viewer's clear colour (0.97, 0.97, 0.98)
MATCH_RGB = np.array([255, 0, 230])  # the viewer's match marker (1.0, 0.0, 0.9)


def _chromium() -> str:
    env = os.environ.get("TOPOMATCH_CHROMIUM")
    if env:
        if not Path(env).is_file():
            pytest.skip(f"TOPOMATCH_CHROMIUM={env} does not exist")
        return env
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("no Chromium on this machine (apt-get install chromium, or set TOPOMATCH_CHROMIUM; see .ci/browser-setup.sh)")
    raise AssertionError  # unreachable


@pytest.fixture(scope="module")
def html(report_run, tmp_path_factory):
    from topomatch.report import build_report

    return build_report([report_run], tmp_path_factory.mktemp("browser") / "report", renderings=False)


@pytest.fixture(scope="module")
def browser_page(request, tmp_path_factory):
    exe = _chromium()  # skip before building anything when there is no browser
    sync_api = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed (pip install playwright)")
    html = request.getfixturevalue("html")
    run = request.getfixturevalue("report_run")
    profile = tmp_path_factory.mktemp("chromium-profile")
    problems: list[str] = []
    with sync_api.sync_playwright() as p:
        try:
            ctx = p.chromium.launch_persistent_context(
                str(profile), executable_path=exe, headless=True, args=CHROMIUM_FLAGS, viewport={"width": 1200, "height": 900}
            )
        except Exception as err:  # the binary is there but cannot start: say so, do not hide it
            pytest.fail(f"Chromium at {exe} did not start: {err}")
        page = ctx.new_page()
        page.on("console", lambda m: problems.append(f"console.{m.type}: {m.text}") if m.type == "error" else None)
        page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
        page.goto(html.resolve().as_uri())
        page.wait_for_function("window.topomatchViewer && (window.topomatchViewer.ready || window.topomatchViewer.error)", timeout=60_000)
        page.locator("#viewer-canvas").scroll_into_view_if_needed()
        yield page, problems, run
        ctx.close()


def _shot(page) -> np.ndarray:
    from PIL import Image

    png = page.locator("#viewer-canvas").screenshot()
    with Image.open(io.BytesIO(png)) as im:
        return np.asarray(im.convert("RGB")).astype(int)


def _mesh_mask(img: np.ndarray) -> np.ndarray:
    return np.abs(img - BACKGROUND).max(axis=2) > 30


def test_report_opens_draws_and_shows_the_match(browser_page):
    # the run is reached through browser_page so that nothing is built when the test skips
    from topomatch.evaluation.rundir import RunDir

    page, problems, report_run = browser_page
    assert page.evaluate("window.topomatchViewer.error") is None
    assert page.title().startswith("topomatch report")

    # 1. the canvas is drawn: both halves hold a shaded, coloured mesh
    img = _shot(page)
    h, w, _ = img.shape
    mask = _mesh_mask(img)
    for half in (mask[:, : w // 2], mask[:, w // 2 :]):
        assert half.mean() > 0.05, f"a viewport is (nearly) blank: {half.mean():.3f} of its pixels differ from the background"
    assert len(np.unique(img[mask].reshape(-1, 3), axis=0)) > 200

    # 2. click the target where it is drawn (the mesh pixel nearest the centre of the target's pixels)
    ys, xs = np.nonzero(mask[:, w // 2 :])
    xs = xs + w // 2
    k = int(np.argmin((ys - ys.mean()) ** 2 + (xs - xs.mean()) ** 2))
    box = page.locator("#viewer-canvas").bounding_box()
    sx, sy = box["width"] / w, box["height"] / h  # screenshot pixels -> CSS pixels
    cx, cy = box["x"] + (xs[k] + 0.5) * sx, box["y"] + (ys[k] + 0.5) * sy
    page.mouse.click(cx, cy)
    page.wait_for_function("document.getElementById('pick-info').dataset.side !== ''", timeout=10_000)
    info = page.locator("#pick-info")
    assert info.get_attribute("data-side") == "target"
    vertex = int(info.get_attribute("data-vertex"))
    state = page.evaluate("({method: window.topomatchViewer.state.method, pair: window.topomatchViewer.state.pair})")
    p2p = RunDir(report_run).load_map(state["method"], state["pair"])["p2p_21"]
    expected = int(p2p[vertex])
    assert info.get_attribute("data-match") == ("" if expected < 0 else str(expected))
    assert f"vertex {vertex}" in info.text_content()
    # the picked vertex is drawn where we clicked (it is a corner of the triangle under the cursor)
    at = page.evaluate(f"window.topomatchViewer.project('target', {vertex})")
    assert np.hypot(at["x"] - cx, at["y"] - cy) < 25, (at, cx, cy)

    # 3. the match is marked on the source, at the projected position of the mapped vertex
    if expected >= 0:
        page.evaluate("window.topomatchViewer.redraw()")
        img2 = _shot(page)
        m = page.evaluate(f"window.topomatchViewer.project('source', {expected})")
        px, py = int((m["x"] - box["x"]) / sx), int((m["y"] - box["y"]) / sy)
        patch = img2[max(py - 3, 0) : py + 4, max(px - 3, 0) : px + 4]
        close = np.abs(patch - MATCH_RGB).max(axis=2) < 60
        assert close.any(), f"no match marker drawn at ({px}, {py}): {patch.reshape(-1, 3)[:5]}"
        assert not (np.abs(img - MATCH_RGB).max(axis=2) < 60)[max(py - 3, 0) : py + 4, max(px - 3, 0) : px + 4].any()

    # 4. drag rotates and the wheel zooms: the picture changes
    before = _shot(page)
    page.mouse.move(box["x"] + box["width"] * 0.25, box["y"] + box["height"] * 0.5)
    page.mouse.down()
    page.mouse.move(box["x"] + box["width"] * 0.25 + 120, box["y"] + box["height"] * 0.5 + 30, steps=6)
    page.mouse.up()
    page.evaluate("window.topomatchViewer.redraw()")
    rotated = _shot(page)
    assert np.abs(rotated - before).max(axis=2).mean() > 2
    page.mouse.wheel(0, -400)
    page.evaluate("window.topomatchViewer.redraw()")
    zoomed = _shot(page)
    assert _mesh_mask(zoomed).mean() > _mesh_mask(rotated).mean()

    # 5. switching method and colour mode works and redraws
    page.select_option("#sel-method", index=1)
    page.wait_for_function("window.topomatchViewer.state.method === 'oracle'", timeout=10_000)
    page.select_option("#sel-colour", "error")
    page.evaluate("window.topomatchViewer.redraw()")
    assert _mesh_mask(_shot(page)).mean() > 0.05

    assert problems == [], "\n".join(problems)
