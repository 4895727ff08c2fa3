"""The widgets used the way a student uses them: JupyterLab in Chromium, dragged with a mouse.

Screenshots and the drag-to-redraw latencies go to `build/browser/` (measurements, not limits).
"""

import json
import shutil
import time
from pathlib import Path

import nbformat
import numpy as np
import pytest
from browser import (
    BROWSER_OUT,
    CHROMIUM_ARGS,
    POLL_MS,
    ROOT,
    chromium_path,
    drag,
    error_outputs,
    jupyter_lab,
    run_all,
    save,
    settled_view,
    shut_down_kernel,
    wait_for_idle_kernel,
)
from notebook_runs import COURSE, record_time, shared_dir
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
    BROWSER_OUT.mkdir(parents=True, exist_ok=True)
    with jupyter_lab(root) as (url, token), playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_ARGS)

        def open_notebook(name):
            page = browser.new_page(viewport={"width": 1400, "height": 1100})
            page.console_errors = []
            page.on("console", lambda m: m.type == "error" and page.console_errors.append(m))
            # A workspace of its own, reset: only this notebook is open.
            workspace = Path(name).stem
            page.goto(f"{url}/lab/workspaces/{workspace}/tree/{name}?reset&token={token}")
            page.on("close", lambda _: shut_down_kernel(url, token, name))
            return page

        yield open_notebook, root
        browser.close()


def run_cell(lab, name: str, source: str):
    """Open a new notebook `name` of one code cell, `source`, in JupyterLab and run it;
    return the page."""
    open_notebook, root = lab
    nb = dc.clean_notebook(nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(source)]))
    nbformat.write(nb, root / f"{name}.ipynb")
    page = open_notebook(f"{name}.ipynb")
    run_all(page, code_cells=1)
    return page


@pytest.fixture(scope="module")
def page(lab):
    page = run_cell(lab, "editor", EDITOR_CELL)
    try:
        page.locator(".dn-editor").wait_for(timeout=120_000)
    except playwright.Error:
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


def record_latencies(editor, title: str, name: str) -> np.ndarray:
    """Write the editor's drag-to-redraw times, and their parts, to
    `build/browser/latency_<name>.md`; return the drag-to-redraw times."""
    rows = {
        "pointer move -> redrawn curve": "data-latencies",
        "request -> drawing (kernel and transport)": "data-round-trips",
        "kernel: evaluation and message": "data-kernel-times",
        "redraw in the browser": "data-draw-times",
    }
    lines = [f"| {title} | count | min ms | median ms | p95 ms |", "|---|---|---|---|---|"]
    for row, attribute in rows.items():
        values = np.asarray(json.loads(editor.get_attribute(attribute)))
        lines.append(
            f"| {row} | {len(values)} | {values.min():.0f} | {np.median(values):.0f} | "
            f"{np.percentile(values, 95):.0f} |"
        )
    (BROWSER_OUT / f"latency_{name}.md").write_text("\n".join(lines) + "\n")
    return np.asarray(json.loads(editor.get_attribute("data-latencies")))


def test_dragging_a_control_point_redraws_the_curve(page):
    editor = page.locator(".dn-editor")
    editor.screenshot(path=BROWSER_OUT / "curve_editor_before.png")
    before, image_before = _curve_points(page), editor.screenshot()
    # Two seconds of dragging at 60 pointer events per second.
    drag(page, page.locator(".dn-point").nth(50), 72, -144, steps=120, pause_ms=16)
    _wait_until_settled(page)
    editor.screenshot(path=BROWSER_OUT / "curve_editor_after.png")
    assert _curve_points(page) != before
    assert editor.screenshot() != image_before
    latencies = record_latencies(
        editor, "CurveEditor, 100 control points, degree 3", "curve_editor"
    )
    assert len(latencies) == 120, "every pointer move must reach a redraw"
    assert not error_outputs(page)
    assert not page.console_errors, [m.text for m in page.console_errors]


def test_dragging_a_knot_and_the_parameter(page):
    before = _curve_points(page)
    drag(page, page.locator(".dn-knot.dn-inner").nth(40), 2, 0, steps=4)
    _wait_until_settled(page)
    assert _curve_points(page) != before
    on_curve = page.locator(".dn-on-curve").bounding_box()
    drag(page, page.locator(".dn-marker"), -150, 0)
    _wait_until_settled(page)
    assert page.locator(".dn-on-curve").bounding_box() != on_curve
    assert not error_outputs(page)


def _drawn_lines(editor) -> list:
    """The points of every line an editor draws from the kernel's answer."""
    return editor.locator(".dn-curve, .dn-line").evaluate_all(
        "lines => lines.map(line => line.getAttribute('points'))"
    )


def check_saved_run(saved: Path) -> None:
    """What `test_notebooks.py` checks of a headless run: every code cell ran, none raised,
    and the chapter draws."""
    nb = nbformat.read(saved, as_version=4)
    code = [cell for cell in nb.cells if cell.cell_type == "code"]
    missed = [k for k, cell in enumerate(code) if cell.execution_count is None]
    assert not missed, f"Run All stopped early: code cells {missed} of {len(code)} did not run"
    errors = [o for cell in code for o in cell.outputs if o.output_type == "error"]
    assert not errors, [f"{e.ename}: {e.evalue}" for e in errors]
    assert dc.count_figures(nb) >= 1, f"{saved.name} shows no figure"
    # The chapter template's measures (course/AUTHORING.md), outputs included: no warning text.
    assert not dc.chapter_metrics(ROOT / "course" / saved.name, nb).problems


CODE_CELL = "xpath=ancestor::div[contains(concat(' ', @class, ' '), ' jp-CodeCell ')][1]"
"""From a widget to the code cell whose output it is."""


def _drawings(cell) -> list:
    """What a code cell's outputs draw: its figures' images, its editors' lines and how many
    updates its 3D views have drawn."""
    images = cell.locator(".jp-OutputArea-output img").evaluate_all("xs => xs.map(x => x.src)")
    views = cell.locator(".dn-view").evaluate_all("xs => xs.map(x => x.dataset.updates)")
    return images + _drawn_lines(cell) + views


def _change(page, control) -> None:
    """Change an ipywidgets control as a student would: the last toggle button not selected
    is clicked (the first may draw the same: in chapter 10, a cardinal spline of tension 0 is
    the Catmull-Rom one); a slider's handle is focused and moved one step with the arrow keys."""
    if "widget-toggle-buttons" in control.get_attribute("class"):
        control.locator("button:not(.mod-active)").last.click()
        return
    readout = control.locator(".widget-readout")
    before = readout.inner_text()
    control.locator(".noUi-handle").focus()
    for key in ("ArrowRight", "ArrowLeft", "ArrowLeft"):  # at its maximum, step back
        page.keyboard.press(key)
        if readout.inner_text() != before:
            return
    raise AssertionError(f"the slider did not move from {before}")


def _answers(page, control) -> None:
    """Change `control`; assert that a drawing of its cell changes."""
    cell = control.locator(CODE_CELL)
    page.wait_for_function(
        "cell => cell.querySelector('.jp-OutputArea-output img, .dn-editor, .dn-view')",
        arg=cell.element_handle(),
        timeout=60_000,
        polling=POLL_MS,
    )
    before = _drawings(cell)
    _change(page, control)
    deadline = time.monotonic() + 60
    while _drawings(cell) == before:
        if time.monotonic() > deadline:
            cell.screenshot(path=BROWSER_OUT / "failure_control.png")
            raise AssertionError(f"{control.inner_text()!r}: nothing redrew")
        page.wait_for_timeout(200)


@pytest.mark.parametrize("chapter", COURSE, ids=lambda path: path.stem)
def test_chapter_runs_and_its_widgets_answer(lab, chapter, tmp_path_factory):
    """Every chapter, run as a student runs it: Run All in JupyterLab; then every editor is
    dragged and every slider and toggle moved, and what it drives must redraw.

    The chapters are run here only, not also headless: the saved notebook is checked as a
    headless run would be (`check_saved_run`)."""
    open_notebook, root = lab
    if not (root / "course").exists():
        shutil.copytree(ROOT / "course", root / "course")
    page = open_notebook(f"course/{chapter.name}")
    started = time.monotonic()
    code = [cell for cell in dc.read_notebook(chapter).cells if cell.cell_type == "code"]
    run_all(page, code_cells=len(code))
    record_time(shared_dir(tmp_path_factory), chapter, time.monotonic() - started, "browser")
    assert not error_outputs(page)
    save(page, root / "course" / chapter.name)
    check_saved_run(root / "course" / chapter.name)
    editors, views = page.locator(".dn-editor"), page.locator(".dn-view canvas")
    pictures = [views.nth(k).screenshot() for k in range(views.count())]
    for index in range(editors.count()):
        editor = editors.nth(index)
        before = _drawn_lines(editor)
        # One second of dragging at 60 pointer events per second.
        drag(page, editor.locator(".dn-point").nth(1), 30, -30, steps=60, pause_ms=16)
        page.wait_for_function(
            "e => e.dataset.pending === '0'",
            arg=editor.element_handle(),
            timeout=60_000,
            polling=POLL_MS,
        )
        editor.screenshot(path=BROWSER_OUT / f"{chapter.stem}_editor{index}.png")
        assert _drawn_lines(editor) != before
        name = f"{chapter.stem}_editor{index}"
        assert len(record_latencies(editor, f"{chapter.stem}, editor {index}", name)) == 60
    # A 3D view follows the editor that drives it.
    for k, before in enumerate(pictures):
        settled_view(page, page.locator(".dn-view").nth(k))
        views.nth(k).screenshot(path=BROWSER_OUT / f"{chapter.stem}_view{k}.png")
        assert views.nth(k).screenshot() != before, f"3D view {k} did not change"
    # Counted again at every step: a control may bring others (the motion editor's operation
    # shows the sliders of that operation and hides the rest).
    controls = page.locator(".widget-slider, .widget-toggle-buttons")
    index = 0
    while index < controls.count():
        if controls.nth(index).is_visible():
            _answers(page, controls.nth(index))
        index += 1
    if controls.count():
        page.screenshot(path=BROWSER_OUT / f"{chapter.stem}_controls.png")
    assert not error_outputs(page)
    assert not page.console_errors, [m.text for m in page.console_errors]
    page.close()


MOTION_CELL = """\
import jax
import numpy as np

jax.config.update("jax_enable_x64", True)
import diffnurbs as dn

vase = np.array([[0.9, 0.0], [1.4, 0.4], [1.5, 1.2], [0.7, 1.8], [0.8, 2.6], [1.1, 3.0]])
motion = dn.widgets.MotionEditor(dn.NURBSCurve(vase, 3))
motion"""


def js_heap_mb(page) -> float:
    return page.evaluate("() => { window.gc(); return performance.memory.usedJSHeapSize / 2**20; }")


def test_motion_editor_keeps_its_camera_and_its_memory_over_200_updates(lab):
    page = run_cell(lab, "motion", MOTION_CELL)
    view, canvas = page.locator(".dn-view"), page.locator(".dn-view canvas")
    view.wait_for(timeout=120_000)
    assert view.get_attribute("data-error") is None, "no WebGL"
    settled_view(page, view)
    # Turn the camera by hand: the updates that follow must leave it there.
    camera = view.get_attribute("data-camera")
    drag(page, canvas, 120, 40, steps=10)
    turned = view.get_attribute("data-camera")
    assert turned != camera
    geometries, heap = view.get_attribute("data-geometries"), js_heap_mb(page)
    drawn = settled_view(page, view)
    # Profile edits, back and forth, 50 at a time (60 pointer events per second); the
    # memory is read after each fifty.
    point = page.locator(".dn-editor .dn-point").nth(2)
    rows = [("before the edits", 0, geometries, heap)]
    for fifty in range(1, 5):
        drag(page, point, 40 * (-1) ** fifty, -30 * (-1) ** fifty, steps=50, pause_ms=16)
        page.wait_for_selector(".dn-editor[data-pending='0']", timeout=60_000)
        updates = settled_view(page, view) - drawn
        rows.append(
            (
                f"after {50 * fifty} edits",
                updates,
                view.get_attribute("data-geometries"),
                js_heap_mb(page),
            )
        )
    canvas.screenshot(path=BROWSER_OUT / "motion_editor_after_200_edits.png")
    page.screenshot(path=BROWSER_OUT / "motion_editor.png")
    assert view.get_attribute("data-camera") == turned
    (BROWSER_OUT / "memory_motion_editor_browser.md").write_text(
        "| MotionEditor, browser | updates drawn | three.js geometries | JS heap MB (after GC) |\n"
        "|---|---|---|---|\n"
        + "".join(f"| {name} | {count} | {kept} | {mb:.1f} |\n" for name, count, kept, mb in rows)
    )
    assert all(kept == geometries for _, _, kept, _ in rows), rows
    assert rows[-1][1] >= 50, "the 3D view must follow the drag"
    # Flat: the last 100 edits leave the heap where the first 100 brought it.
    assert rows[-1][3] - rows[2][3] < 5, rows
    assert not error_outputs(page)
    assert not page.console_errors, [m.text for m in page.console_errors]
    page.close()


POINTS_CELL = """\
import numpy as np
import diffnurbs as dn

def draw(points, weights):
    # The weighted centroid, drawn as a short cross, and the polygon through the points.
    c = (weights[:, None] * points).sum(axis=0) / weights.sum()
    return {"polygon": points, "centroid": np.array([c - 0.1, c + 0.1])}

editor = dn.widgets.PointsEditor(np.eye(4, 2) + [[0, 0], [0, 0], [1, 1], [2, 0]], draw,
                                 weights=np.ones(4), min_points=3)
editor"""


def test_points_editor_weights_adds_and_deletes_points(lab):
    page = run_cell(lab, "points", POINTS_CELL)
    editor = page.locator(".dn-editor")
    editor.wait_for(timeout=120_000)
    points = editor.locator(".dn-point")
    assert points.count() == 4
    before = _drawn_lines(editor)
    points.nth(2).hover()
    page.mouse.wheel(0, -300)  # heavier: the centroid moves towards the point
    _wait_until_settled(page)
    assert _drawn_lines(editor) != before
    assert float(editor.locator(".dn-weight").input_value()) > 1
    box = editor.locator(".dn-plot").bounding_box()
    page.mouse.dblclick(box["x"] + 0.3 * box["width"], box["y"] + 0.5 * box["height"])
    _wait_until_settled(page)
    assert points.count() == 5
    for _ in range(3):  # down to three points, and not below
        points.nth(0).click(button="right")
        _wait_until_settled(page)
    assert points.count() == 3
    assert "at least 3 points" in editor.locator(".dn-message").text_content()
    assert not error_outputs(page)
    assert not page.console_errors, [m.text for m in page.console_errors]
    page.close()
