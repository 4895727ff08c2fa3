"""The course website: Jupyter Book (Sphinx, MyST-NB and the book theme) over the chapters
and the exercises, with a table of contents, search and math rendered without a network.

Jupyter Book 2 (mystmd) is the newer tool, but it downloads its page theme from
api.mystmd.org at every build, which a classroom or CI machine without internet cannot
reach; Jupyter Book 1 builds from what pip installed.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import nbformat

from ._layout import CourseLayout
from ._notebooks import notebooks, read_notebook
from ._report import CHECK_TAG

_ANSWERS_TAG = "answers"
"""Answers of *Check yourself*: folded on the site."""
_WIDGET_VIEW = "application/vnd.jupyter.widget-view+json"

_CONFIG = """\
title: Curves and surfaces with diffnurbs
author: the diffnurbs authors
copyright: ""
only_build_toc_files: true
execute:
  execute_notebooks: "off"
parse:
  myst_enable_extensions: [dollarmath, amsmath, colon_fence]
html:
  home_page_in_navbar: true
  use_repository_button: false
  # A page icon of its own, else the browser asks the server for /favicon.ico (a 404).
  favicon: favicon.png
sphinx:
  extra_extensions: [sphinx-mathjax-offline]  # MathJax 3 shipped in the wheel, no CDN
  config:
    html_show_copyright: false
    html_last_updated_fmt: ""
    # Light unless the reader chose otherwise (an unset mode logs a console error).
    html_context: {default_mode: light}
    # Links between chapters use JupyterLab's heading anchors ("#05.2-Knot-vectors").
    myst_heading_anchors: 3
    myst_heading_slug_func: diffnurbs_course.jupyter_anchor
    # A widget's live view needs a kernel; its display also carries a PNG of its state.
    nb_mime_priority_overrides: [["html", "application/vnd.jupyter.widget-view+json", null]]
"""


def _stage_notebook(nb: nbformat.NotebookNode) -> nbformat.NotebookNode:
    """The notebook as the site shows it (in place): the code of check cells removed (their
    outputs kept, as JupyterLab shows them, unless folded too), answers folded, outputs that
    are only a live widget (no picture) dropped."""
    for cell in nb.cells:
        tags = cell.metadata.get("tags", [])
        if CHECK_TAG in tags:
            # The prose may cite what a check prints (a table, a timing figure).
            shown = cell.outputs and not cell.metadata.get("jupyter", {}).get("outputs_hidden")
            cell.metadata["tags"] = [*tags, "remove-input" if shown else "remove-cell"]
        elif _ANSWERS_TAG in tags and cell.cell_type == "code":
            cell.metadata["tags"] = [*tags, "hide-cell"]
        elif _ANSWERS_TAG in tags:  # MyST folds Markdown with a directive, not a tag
            cell.source = f":::{{dropdown}} Answers\n{cell.source}\n:::"
        if cell.cell_type == "code":
            outputs = [output for output in cell.outputs if not _live_only(output)]
            if len(outputs) < len(cell.outputs):
                outputs.append(_LIVE_NOTE)
            cell.outputs = outputs
    return nb


def _live_only(output: nbformat.NotebookNode) -> bool:
    """Whether an output is a widget with no picture of its state (sliders, `interact`)."""
    data = output.get("data", {})
    return _WIDGET_VIEW in data and "image/png" not in data


_LIVE_NOTE = nbformat.v4.new_output(
    "display_data",
    data={
        "text/html": "<p><em>Interactive in JupyterLab: open this chapter there (make lab) and "
        "run it to use the controls.</em></p>",
        "text/plain": "Interactive in JupyterLab.",
    },
)
"""Where a widget without a picture was: the site cannot run it."""


def _favicon(path: Path) -> None:
    """A 32 x 32 icon: a blue Bezier-like arc on white."""
    from PIL import Image, ImageDraw

    image = Image.new("RGB", (32, 32), "white")
    ImageDraw.Draw(image).arc((2, 6, 30, 46), 200, 340, fill="#1f6fb4", width=4)
    image.save(path)


def _toc(chapters: list[str], exercises: list[str]) -> str:
    lines = ["format: jb-book", f"root: course/{chapters[0]}", "parts:"]
    for caption, folder, names in (
        ("Chapters", "course", chapters[1:]),
        ("Exercises", "exercises", exercises),
    ):
        lines += [f"  - caption: {caption}", "    chapters:"]
        lines += [f"      - file: {folder}/{name}" for name in names]
    return "\n".join(lines) + "\n"


def stage_site(
    layout: CourseLayout,
    staging: Path,
    executed: dict[str, nbformat.NotebookNode] | None = None,
) -> Path:
    """Write the Jupyter Book sources of the site.

    **Arguments:**

    - `layout`: the course's folders; `course/00_index.ipynb` is the home page.
    - `staging`: an empty folder to write into.
    - `executed`: executed chapters by stem; the others are shown as committed (no outputs).

    **Returns:**

    `staging`, holding `_config.yml`, `_toc.yml`, `course/` and `exercises/` (the relative
    links between chapters and exercises keep working).
    """
    executed = executed or {}
    chapters = notebooks(layout.course)
    exercises = notebooks(layout.exercises)
    if not chapters or chapters[0].stem != "00_index":
        raise ValueError(f"{layout.course} must hold 00_index.ipynb, the site's home page")
    for folder, paths in (("course", chapters), ("exercises", exercises)):
        (staging / folder).mkdir(parents=True, exist_ok=True)
        for path in paths:
            nb = executed.get(path.stem) if folder == "course" else None
            nb = _stage_notebook(nb if nb is not None else read_notebook(path))
            nbformat.write(nb, staging / folder / path.name)
    (staging / "_config.yml").write_text(_CONFIG)
    _favicon(staging / "favicon.png")
    (staging / "_toc.yml").write_text(_toc([p.stem for p in chapters], [p.stem for p in exercises]))
    return staging


def build_site(staging: Path, out: Path) -> Path:
    """Build the site from `stage_site`'s folder with Jupyter Book.

    **Arguments:**

    - `staging`: the staged sources.
    - `out`: where Jupyter Book writes (`out/_build/html`).

    **Returns:**

    The folder of the HTML site; `ValueError` with Jupyter Book's log if the build fails.
    """
    cli = "from jupyter_book.cli.main import main; main()"  # its module has no __main__
    command = [sys.executable, "-c", cli, "build", str(staging), "--path-output", str(out)]
    result = subprocess.run(
        [*command, "--warningiserror", "--keep-going"], capture_output=True, text=True, check=False
    )
    if result.returncode != 0:
        raise ValueError(f"jupyter-book build failed:\n{result.stdout}\n{result.stderr}")
    return out / "_build" / "html"
