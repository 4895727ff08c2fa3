"""The course website the way a reader meets it: every page in Chromium, every link followed.

Built from the committed notebooks, unexecuted (`make html` executes them first; the tests
execute every chapter elsewhere): what is checked here is the site itself — pages, table of
contents, search, math, links and anchors, check cells left out (their outputs kept when
the chapter is executed and they are not folded).
"""

import functools
import html
import http.server
import re
import threading
from pathlib import Path
from urllib.parse import unquote, urldefrag, urlparse

import nbformat
import pytest
from browser import CHROMIUM_ARGS, chromium_path
from notebook_runs import LAYOUT
from playwright import sync_api as playwright

import diffnurbs_course as dc
from diffnurbs_course._site import _stage_notebook

CHAPTERS = dc.notebooks(LAYOUT.course)
EXERCISES = dc.notebooks(LAYOUT.exercises)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The built site's folder."""
    work = tmp_path_factory.mktemp("site")
    return dc.build_site(dc.stage_site(LAYOUT, work / "source"), work)


@pytest.fixture(scope="module")
def served(site):
    """`(base URL, browser)`: the site on a local HTTP server, and Chromium."""
    handler = functools.partial(QuietHandler, directory=str(site))
    with http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler) as server:
        threading.Thread(target=server.serve_forever, daemon=True).start()
        with playwright.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_ARGS)
            yield f"http://127.0.0.1:{server.server_address[1]}/", browser
            browser.close()
        server.shutdown()


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


def pages(site: Path) -> list[str]:
    return sorted(
        str(p.relative_to(site)) for p in site.glob("**/*.html") if "_static" not in p.parts
    )


def test_every_chapter_and_exercise_has_a_page(site):
    built = set(pages(site))
    expected = {f"course/{p.stem}.html" for p in CHAPTERS}
    expected |= {f"exercises/{p.stem}.html" for p in EXERCISES}
    assert expected <= built, expected - built
    assert {"index.html", "search.html"} <= built
    assert (site / "searchindex.js").stat().st_size > 10_000


def test_check_cells_are_left_out_and_answers_folded(site):
    for path in CHAPTERS:
        text = (site / "course" / f"{path.stem}.html").read_text()
        cells = dc.read_notebook(path).cells
        code = [cell for cell in cells if cell.cell_type == "code"]
        shown = [cell for cell in code if dc.CHECK_TAG not in cell.metadata.get("tags", [])]
        rendered = re.findall(r'class="cell(?: tag_[\w-]+)* docutils container"', text)
        assert len(rendered) == len(shown), f"{path.stem}: {len(rendered)} code cells shown"
        assert "tag_check" not in text
        for cell in cells:
            if cell.cell_type == "markdown" and "answers" in cell.metadata.get("tags", []):
                lines = cell.source.splitlines()
                wordiest = max(lines, key=lambda line: len(re.findall(r"[A-Za-z]{3,}", line)))
                folded = re.findall(r"<details.*?</details>", text, flags=re.S)
                assert any(_shown(wordiest, block) for block in folded), f"{path.stem}: {wordiest}"


def test_an_executed_check_cell_shows_its_outputs_not_its_code():
    printed = nbformat.v4.new_output("stream", text="a table the prose cites\n")
    cells = [nbformat.v4.new_code_cell("print(1)", outputs=[printed]) for _ in range(3)]
    for cell in cells:
        cell.metadata["tags"] = [dc.CHECK_TAG]
    cells[1].metadata["jupyter"] = {"source_hidden": True, "outputs_hidden": True}
    cells[2].outputs = []
    staged = _stage_notebook(nbformat.v4.new_notebook(cells=cells))
    tags = [cell.metadata["tags"][-1] for cell in staged.cells]
    assert tags == ["remove-input", "remove-cell", "remove-cell"]


def test_a_widget_without_a_picture_is_replaced_by_a_note():
    view = {"application/vnd.jupyter.widget-view+json": {"model_id": "1"}, "text/plain": "w"}
    picture = {**view, "image/png": "iVBORw0KGgo="}
    cell = nbformat.v4.new_code_cell(
        "interact(...)",
        outputs=[nbformat.v4.new_output("display_data", data=d) for d in (view, picture)],
    )
    (staged,) = _stage_notebook(nbformat.v4.new_notebook(cells=[cell])).cells
    assert [o.data.get("image/png") for o in staged.outputs] == [picture["image/png"], None]
    assert "Interactive in JupyterLab" in staged.outputs[-1].data["text/html"]


def _shown(line: str, page: str) -> bool:
    """Whether the words of `line` (two letters or more: not numbers, not one-letter symbols
    that math and code markup split differently) appear in this order in the page's text."""
    words = re.findall(r"[A-Za-z]{2,}", line)[:8]
    if len(words) < 4:  # too short to tell apart from other text
        return False
    text = " ".join(re.findall(r"[A-Za-z]{2,}", html.unescape(re.sub(r"<[^>]+>", " ", page))))
    return " ".join(words) in text


def test_pages_load_without_errors_math_renders_and_every_link_resolves(served, site):
    base, browser = served
    page = browser.new_page()
    errors, failed = [], []
    page.on("console", lambda m: m.type == "error" and errors.append(f"{page.url}: {m.text}"))
    # A request the next navigation cancels (Chromium asks for the page icon after `load`)
    # is not a failure; a refused connection or an HTTP error is.
    page.on(
        "requestfailed",
        lambda r: r.failure != "net::ERR_ABORTED" and failed.append(f"{page.url}: {r.url}"),
    )
    page.on("response", lambda r: r.status >= 400 and failed.append(f"{r.status}: {r.url}"))
    ids: dict[str, set[str]] = {}
    links: list[tuple[str, str]] = []
    # The root page only redirects to the course's index (a meta refresh).
    assert "url=course/00_index.html" in (site / "index.html").read_text()
    for name in [name for name in pages(site) if name != "index.html"]:
        page.goto(base + name, wait_until="load")
        if name.startswith("course/") and name != "course/00_index.html":
            # MathJax, served from the site itself, typesets the page's formulas.
            page.wait_for_selector("mjx-container", state="attached", timeout=30_000)
        ids[name] = set(page.eval_on_selector_all("[id]", "nodes => nodes.map(n => n.id)"))
        hrefs = page.eval_on_selector_all("a[href]", "nodes => nodes.map(n => n.href)")
        links += [(name, href) for href in hrefs if href.startswith(base)]
    page.close()
    assert not errors, errors[:10]
    assert not failed, failed[:10]
    broken = []
    for source, href in links:
        url, anchor = urldefrag(href)
        target = unquote(urlparse(url).path).lstrip("/") or "index.html"
        if target.endswith("/"):
            target += "index.html"
        if not (site / target).exists():
            broken.append(f"{source} -> {href}")
        elif anchor and target in ids and unquote(anchor) not in ids[target]:
            broken.append(f"{source} -> {href} (no such anchor)")
    assert not broken, broken[:20]


def test_chapter_links_reach_chapters_and_exercises(site):
    # The Markdown links between notebooks became links between pages.
    text = (site / "course" / "13_surfaces_of_motion.html").read_text()
    hrefs = set(re.findall(r'href="([^"#]+\.html)', text))
    assert "08_nurbs_curves.html" in hrefs
    assert "../exercises/13_surfaces_of_motion.html" in hrefs
    # Only the page's source download links to a notebook.
    assert not re.search(r'href="(?![^"]*_sources/)[^"]*\.ipynb"', text), "a link left"
