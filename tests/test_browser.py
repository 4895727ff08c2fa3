"""The widgets used the way a student uses them: JupyterLab in Chromium, dragged with a mouse.

Screenshots and the drag-to-redraw latencies go to `build/browser/` (measurements, not limits).
"""

import json
import shutil
from pathlib import Path

import nbformat
import numpy as np
import pytest
from browser import (
    BROWSER_OUT,
    CHROMIUM_ARGS,
    ROOT,
    chromium_path,
    error_outputs,
    jupyter_lab,
    run_all,
    wait_for_idle_kernel,
)
from playwright import sync_api as playwright

import diffnurbs_course as dc

EDITOR_CELL = """\
import jax
import numpy as np

jax.config.update("jax_enable_x64", True)
import diffnurbs as dn

rng = np.random.default_rng(0)
points = np.column_stack([np.linspace(0.0, 10.0, 100), rng.normal(size=100)])
editor = dn.widgets.CurveEditor(dn.NURBSCurve(points, 3), construction=True, comb=True)
editor"""


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """`(open, root)`: `open(name)` opens a notebook of `root` in JupyterLab in Chromium."""
    root = tmp_path_factory.mktemp("lab")
    with jupyter_lab(root) as (url, token), playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_ARGS)

        def open_notebook(name):
            page = browser.new_page(viewport={"width": 1400, "height": 1100})
            page.console_errors = []
            page.on("console", lambda m: m.type == "error" and page.console_errors.append(m))
            # A workspace of its own, reset: only this notebook is open.
            workspace = Path(name).stem
            page.goto(f"{url}/lab/workspaces/{workspace}/tree/{name}?reset&token={token}")
            return page

        yield open_notebook, root
        browser.close()


@pytest.fixture(scope="module")
def page(lab):
    open_notebook, root = lab
    nb = dc.clean_notebook(nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(EDITOR_CELL)]))
    nbformat.write(nb, root / "editor.ipynb")
    page = open_notebook("editor.ipynb")
    try:
        run_all(page)
        page.locator(".dn-editor").wait_for(timeout=120_000)
    except playwright.Error:
        BROWSER_OUT.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=BROWSER_OUT / "failure.png")
        raise
    yield page
    page.close()


def test_opening_a_chapter_leaves_it_unmodified(lab):
    # JupyterLab writes the kernel's language_info into the notebook when it connects:
    # the committed metadata must already be exactly that, or autosave rewrites the file.
    open_notebook, root = lab
    chapter = ROOT / "course" / "02_bezier_curves.ipynb"
    shutil.copyfile(chapter, root / chapter.name)
    page = open_notebook(chapter.name)
    wait_for_idle_kernel(page)
    page.wait_for_timeout(2_000)
    tab = page.locator(".lm-TabBar-tab.jp-mod-current")
    assert "jp-mod-dirty" not in (tab.get_attribute("class") or "")
    page.close()
    assert (root / chapter.name).read_bytes() == chapter.read_bytes()


def _curve_points(page) -> str:
    return page.locator(".dn-curve").get_attribute("points")


def _wait_until_settled(page):
    """Until the kernel has answered every edit."""
    page.wait_for_selector(".dn-editor[data-pending='0']", timeout=60_000)


def test_dragging_a_control_point_redraws_the_curve(page):
    BROWSER_OUT.mkdir(parents=True, exist_ok=True)
    editor = page.locator(".dn-editor")
    editor.screenshot(path=BROWSER_OUT / "curve_editor_before.png")
    before, image_before = _curve_points(page), editor.screenshot()
    point = page.locator(".dn-point").nth(50).bounding_box()
    x, y = point["x"] + point["width"] / 2, point["y"] + point["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    for step in range(1, 121):  # two seconds of dragging at 60 pointer events per second
        page.mouse.move(x + 0.6 * step, y - 1.2 * step)
        page.wait_for_timeout(16)
    page.mouse.up()
    _wait_until_settled(page)
    editor.screenshot(path=BROWSER_OUT / "curve_editor_after.png")
    assert _curve_points(page) != before
    assert editor.screenshot() != image_before
    latencies = np.asarray(json.loads(editor.get_attribute("data-latencies")))
    assert len(latencies) == 120, "every pointer move must reach a redraw"
    rows = {
        "pointer move -> redrawn curve": latencies,
        "request -> drawing (kernel and transport)": editor.get_attribute("data-round-trips"),
        "kernel: evaluation and message": editor.get_attribute("data-kernel-times"),
        "redraw in the browser": editor.get_attribute("data-draw-times"),
    }
    lines = ["| CurveEditor, 100 control points, degree 3 | count | min ms | median ms | p95 ms |"]
    lines.append("|---|---|---|---|---|")
    for name, values in rows.items():
        values = np.asarray(json.loads(values) if isinstance(values, str) else values)
        lines.append(
            f"| {name} | {len(values)} | {values.min():.0f} | {np.median(values):.0f} | "
            f"{np.percentile(values, 95):.0f} |"
        )
    (BROWSER_OUT / "latency.md").write_text("\n".join(lines) + "\n")
    assert not error_outputs(page)
    assert not page.console_errors, [m.text for m in page.console_errors]


def test_dragging_a_knot_and_the_parameter(page):
    before = _curve_points(page)
    knot = page.locator(".dn-knot.dn-inner").nth(40).bounding_box()
    x, y = knot["x"] + knot["width"] / 2, knot["y"] + knot["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + 2, y, steps=4)
    page.mouse.up()
    _wait_until_settled(page)
    assert _curve_points(page) != before
    on_curve = page.locator(".dn-on-curve").bounding_box()
    marker = page.locator(".dn-marker").bounding_box()
    mx, my = marker["x"] + marker["width"] / 2, marker["y"] + marker["height"] / 2
    page.mouse.move(mx, my)
    page.mouse.down()
    page.mouse.move(mx - 150, my, steps=5)
    page.mouse.up()
    _wait_until_settled(page)
    assert page.locator(".dn-on-curve").bounding_box() != on_curve
    assert not error_outputs(page)
