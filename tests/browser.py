"""JupyterLab in a real Chromium, for the tests that use the course the way a student does.

A `jupyter lab` server on 127.0.0.1 (started by the test, token-protected) and the system's
Chromium driven by Playwright: Playwright's own browser download is not used, the browser is
Debian's (`make install` adds it with apt where it is missing).
"""

import contextlib
import json
import os
import secrets
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import nbformat
import pytest
from playwright.sync_api import TimeoutError as PlaywrightTimeout

ROOT = Path(__file__).resolve().parents[1]
BROWSER_OUT = ROOT / "build" / "browser"
"""Screenshots and latency tables of the browser tests."""

# Without the networking switches Chromium keeps calling out to Google's services, which
# this machine's closed network refuses, many connections at a time.
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    # WebGL (the 3D views) without a GPU: Chromium's software renderer, which it no longer
    # falls back to by itself.
    "--enable-unsafe-swiftshader",
    # `window.gc()`, so that the memory test measures what is live, not what awaits collection.
    "--js-flags=--expose-gc",
]


POLL_MS = 200
"""How often a waiting test re-evaluates its condition in the page. Playwright's default
polls on every animation frame, which keeps the page redrawing at 60 frames a second for as
long as a chapter runs (chapter 15: 33 s of Chromium CPU beside 35 s of its kernel's, 18 s
with this)."""


def chromium_path() -> str:
    """The system Chromium; the test fails (not skips) without it, `make install` adds it."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    pytest.fail("no Chromium on PATH: run `make install` (it installs Debian's chromium)")


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextlib.contextmanager
def jupyter_lab(root: Path):
    """A JupyterLab server serving `root`; yields its base URL with the token."""
    port, token = _free_port(), secrets.token_hex(16)
    command = [
        sys.executable, "-m", "jupyter", "lab", "--no-browser", "--ServerApp.ip=127.0.0.1",
        f"--ServerApp.port={port}", f"--IdentityProvider.token={token}",
        f"--ServerApp.root_dir={root}", "--LabApp.news_url=", "--LabApp.check_for_updates_class=",
        "--ServerApp.kernel_websocket_connection_class=diffnurbs_course.lab.NoDelayConnection",
    ]  # fmt: skip
    if hasattr(os, "getuid") and os.getuid() == 0:
        command.append("--allow-root")
    # Settings and workspaces of this server only; no question about Jupyter's news.
    settings = root / ".lab-settings" / "@jupyterlab" / "apputils-extension"
    settings.mkdir(parents=True)
    (settings / "notification.jupyterlab-settings").write_text('{"fetchNews": "false"}')
    # Every cell in the page: with windowing, cells out of view are not rendered, and
    # `run_all` would judge a long notebook by its first screenful of prompts.
    tracker = root / ".lab-settings" / "@jupyterlab" / "notebook-extension"
    tracker.mkdir(parents=True)
    (tracker / "tracker.jupyterlab-settings").write_text('{"windowingMode": "none"}')
    env = {
        **os.environ,
        "JUPYTER_CONFIG_DIR": str(root / ".jupyter-config"),
        "JUPYTERLAB_SETTINGS_DIR": str(root / ".lab-settings"),
        "JUPYTERLAB_WORKSPACES_DIR": str(root / ".lab-workspaces"),
        # As `make lab` runs it (pyvista then still draws PNGs: `viz.use_notebook_backend`).
        "PYVISTA_OFF_SCREEN": "false",
    }
    log = open(root / "jupyter.log", "w")  # noqa: SIM115 (closed below)
    server = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                with urllib.request.urlopen(f"{url}/api/status?token={token}", timeout=2) as r:
                    json.load(r)
                break
            except OSError:
                if server.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError((root / "jupyter.log").read_text()) from None
                time.sleep(0.3)
        yield url, token
    finally:
        server.terminate()
        try:
            server.wait(20)
        except subprocess.TimeoutExpired:
            server.kill()
        log.close()


def shut_down_kernel(url: str, token: str, path: str) -> None:
    """Shut down the kernel of notebook `path` (relative to the server's root) on the server at
    `url`: closing its page leaves it running, and a chapter's kernel holds about a gigabyte."""
    with urllib.request.urlopen(f"{url}/api/sessions?token={token}", timeout=10) as response:
        sessions = json.load(response)
    for session in sessions:
        if session["path"] == path:
            request = urllib.request.Request(
                f"{url}/api/sessions/{session['id']}?token={token}", method="DELETE"
            )
            urllib.request.urlopen(request, timeout=60).close()


def wait_for_idle_kernel(page) -> None:
    """Until the open notebook's kernel has started and is idle."""
    page.locator(".jp-Notebook").first.wait_for()
    # JupyterLab may ask which kernel to start (it does when the server is busy starting
    # the notebook's own): take the one it proposes, the notebook's kernelspec. Whichever
    # comes first, the question or the idle kernel, is answered at once (waiting a fixed
    # time for a question that mostly never comes cost seconds per notebook).
    dialog = page.locator(".jp-Dialog").get_by_role("button", name="Select")
    idle = page.locator(".jp-Notebook-ExecutionIndicator[data-status='idle']")
    dialog.or_(idle).first.wait_for(timeout=120_000)
    if dialog.is_visible():
        dialog.click()
    # The kernel must be idle before the cells are sent.
    idle.wait_for(timeout=120_000)


def run_all(page, code_cells: int) -> None:
    """Run every cell of the open notebook, as Run > Run All Cells does, and wait until each
    of its `code_cells` code cells has run (or one raised)."""
    wait_for_idle_kernel(page)
    # The kernel may be idle before JupyterLab has laid out every cell: wait for all of them.
    with contextlib.suppress(PlaywrightTimeout):  # a shortfall is reported below, counted
        page.wait_for_function(
            "count => document.querySelectorAll('.jp-Notebook .jp-CodeCell').length >= count",
            arg=code_cells,
            timeout=60_000,
            polling=POLL_MS,
        )
    shown = page.locator(".jp-Notebook .jp-CodeCell").count()
    assert shown == code_cells, f"{shown} of {code_cells} code cells are in the page (windowing?)"
    # A cell whose code is folded (the chapters' checks) shows no prompt, so its execution
    # count could not be seen: unfold every cell's code first (it changes nothing else).
    page.locator("#jp-MainMenu").get_by_text("View", exact=True).click()
    page.get_by_text("Expand All Code", exact=True).click()
    page.locator("#jp-MainMenu").get_by_text("Run", exact=True).click()
    page.get_by_text("Run All Cells", exact=True).click()
    # Done when no cell is queued or running and every code cell has its execution count, or
    # when a cell raised (Run All stops there). Checking only for "no [*]" could pass before
    # the first cell was even queued.
    page.wait_for_function(
        """count => {
            const prompts = [...document.querySelectorAll('.jp-CodeCell .jp-InputArea-prompt')];
            if (prompts.length !== count || prompts.some(e => e.textContent.includes('*')))
                return false;
            const raised = [...document.querySelectorAll(
                '[data-mime-type="application/vnd.jupyter.stderr"]')].some(
                e => e.textContent.includes('Traceback'));
            return raised || prompts.every(e => /\\[\\d+\\]/.test(e.textContent));
        }""",
        arg=code_cells,
        timeout=300_000,
        polling=POLL_MS,
    )


def executed_prompts(page) -> int:
    """How many code cells of the open notebook show an execution count."""
    return page.eval_on_selector_all(
        ".jp-CodeCell .jp-InputArea-prompt",
        "prompts => prompts.filter(e => /\\[\\d+\\]/.test(e.textContent)).length",
    )


def save(page, path: Path) -> None:
    """Save the open notebook (File > Save Notebook) to `path`; wait until the tab is clean
    and the file holds every execution count the page shows."""
    shown = executed_prompts(page)
    page.locator("#jp-MainMenu").get_by_text("File", exact=True).click()
    page.get_by_text("Save Notebook", exact=True).first.click()
    page.wait_for_function(
        "() => !document.querySelector('.lm-TabBar-tab.jp-mod-current.jp-mod-dirty')",
        timeout=60_000,
        polling=POLL_MS,
    )
    deadline = time.monotonic() + 30
    while (saved := _executed_cells(path)) < shown:
        assert time.monotonic() < deadline, (
            f"{path.name}: the page shows {shown} run, the file {saved}"
        )
        page.wait_for_timeout(500)


def _executed_cells(path: Path) -> int:
    cells = nbformat.read(path, as_version=4).cells
    return sum(cell.get("execution_count") is not None for cell in cells)


def error_outputs(page) -> list[str]:
    """Texts of error and warning (stderr) outputs shown in the notebook."""
    return page.eval_on_selector_all(
        ".jp-OutputArea-output[data-mime-type='application/vnd.jupyter.stderr'], "
        ".jp-RenderedText[data-mime-type='application/vnd.jupyter.stderr']",
        "nodes => nodes.map(n => n.textContent)",
    )


def settled_view(page, view, timeout_s: float = 60) -> int:
    """Wait until a 3D view (`.dn-view` locator) has drawn no new update for half a second;
    return how many updates it has drawn."""
    deadline = time.monotonic() + timeout_s
    last = view.get_attribute("data-updates")
    while time.monotonic() < deadline:
        page.wait_for_timeout(500)
        now = view.get_attribute("data-updates")
        if now == last:
            return int(now)
        last = now
    raise PlaywrightTimeout(f"the 3D view kept redrawing for {timeout_s} s")


def drag(page, handle, dx: float, dy: float, steps: int = 5, pause_ms: float = 0) -> None:
    """Press the mouse on the centre of `handle` (a locator), move it by `(dx, dy)` pixels in
    `steps` pointer events `pause_ms` apart, and release it. The centre is measured after
    hovering, which scrolls the handle into view, so a page still laying out does not move
    it from under the pointer."""
    handle.hover()
    box = handle.bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    for step in range(1, steps + 1):
        page.mouse.move(x + dx * step / steps, y + dy * step / steps)
        if pause_ms:
            page.wait_for_timeout(pause_ms)
    page.mouse.up()
