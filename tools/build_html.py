"""`make html`: execute every `course/*.ipynb` headless and write a static site.

    python tools/build_html.py [--out build/html] [--jobs 2] [NOTEBOOK...]

Writes `build/html/NN_topic.html` per chapter (figures embedded as data URIs), the exercises
unexecuted under `build/html/exercises/`, and `build/html/index.html` linking to everything.
Links between notebooks (`02_bezier_curves.ipynb`, `../exercises/02_bezier_curves.ipynb`) are
rewritten to the HTML pages. A chapter that raises is still written, with its traceback; the
exit status is then 1.
"""

from __future__ import annotations

import argparse
import html
import multiprocessing
import os
import re
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import nbformat
from nbconvert import HTMLExporter

import diffnurbs_course as dc

_LAYOUT = dc.CourseLayout(Path(__file__).resolve().parents[1])
_LINK = re.compile(r"(\]\(|href=[\"'])([^)\"'\s]*?)([\w.-]+)\.ipynb(#[^)\"'\s]*)?")


@dataclass(frozen=True)
class Page:
    """One written page.

    **Arguments:**

    - `name`: the notebook's stem.
    - `title`: its first Markdown heading.
    - `seconds`: execution wall time (0 for pages that are not executed).
    - `errors`: descriptions of the cells that raised.
    """

    name: str
    title: str
    seconds: float
    errors: tuple[str, ...]


def _title(nb: nbformat.NotebookNode, default: str) -> str:
    for cell in nb.cells:
        if cell.cell_type == "markdown":
            for line in cell.source.splitlines():
                if line.startswith("#"):
                    return line.lstrip("#").strip()
    return default


def rewrite_links(nb: nbformat.NotebookNode, in_exercises: bool) -> None:
    """Point Markdown links to notebooks at the HTML pages of the site (in place).

    **Arguments:**

    - `nb`: a course or exercise notebook.
    - `in_exercises`: whether the page is written under `exercises/`.
    """

    def target(match: re.Match[str]) -> str:
        opening, folder, stem, anchor = match.groups()
        anchor = anchor or ""
        if "://" in folder:
            return match.group(0)
        if "exercises/" in folder or (in_exercises and not folder):
            page = f"{stem}.html" if in_exercises else f"exercises/{stem}.html"
        elif "solutions/" in folder:
            return match.group(0)
        else:
            page = f"../{stem}.html" if in_exercises else f"{stem}.html"
        return f"{opening}{page}{anchor}"

    for cell in nb.cells:
        if cell.cell_type == "markdown":
            cell.source = _LINK.sub(target, cell.source)


def _export(nb: nbformat.NotebookNode, path: Path, source_dir: Path) -> None:
    exporter = HTMLExporter(template_name="lab", embed_images=True)
    body, _ = exporter.from_notebook_node(nb, resources={"metadata": {"path": str(source_dir)}})
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(body, encoding="utf-8")


def build_chapter(notebook: Path, out: Path) -> Page:
    """Execute one course notebook in a fresh kernel and write its page.

    **Arguments:**

    - `notebook`: `course/NN_topic.ipynb`.
    - `out`: the site folder.

    **Returns:**

    The `Page` written.
    """
    nb = dc.read_notebook(notebook)
    with tempfile.TemporaryDirectory(prefix="diffnurbs-html-") as tmp:
        seconds = dc.execute_notebook(nb, Path(tmp), allow_errors=True)
    errors = tuple(error.describe() for error in dc.cell_errors(nb))
    rewrite_links(nb, in_exercises=False)
    _export(nb, out / f"{notebook.stem}.html", notebook.parent)
    return Page(notebook.stem, _title(nb, notebook.stem), seconds, errors)


def build_exercise(notebook: Path, out: Path) -> Page:
    """Write the page of one exercise notebook, unexecuted (it is the student's starting point)."""
    nb = dc.read_notebook(notebook)
    rewrite_links(nb, in_exercises=True)
    _export(nb, out / "exercises" / f"{notebook.stem}.html", notebook.parent)
    return Page(notebook.stem, _title(nb, notebook.stem), 0.0, ())


def _row(page: Page, exercises: dict[str, Page]) -> str:
    exercise = exercises.get(page.name)
    link = f'<a href="exercises/{page.name}.html">exercises</a>' if exercise else ""
    status = "ok" if not page.errors else f"{len(page.errors)} error(s)"
    return (
        f'<tr><td><a href="{page.name}.html">{html.escape(page.title)}</a></td>'
        f"<td>{link}</td><td>{page.seconds:.0f} s</td><td>{status}</td></tr>"
    )


def write_index(chapters: list[Page], exercises: list[Page], out: Path) -> Path:
    """Write `index.html` with a table of the chapters.

    **Arguments:**

    - `chapters`: the chapter pages, in order.
    - `exercises`: the exercise pages.
    - `out`: the site folder.

    **Returns:**

    The index's path.
    """
    by_name = {page.name: page for page in exercises}
    rows = "\n".join(_row(page, by_name) for page in chapters)
    stamp = time.strftime("%Y-%m-%d %H:%M")
    text = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>diffnurbs course</title>
<style>body{{font-family:sans-serif;max-width:60em;margin:2em auto}}
td,th{{padding:.3em 1em;text-align:left}}tr:nth-child(even){{background:#f3f3f3}}</style>
</head><body>
<h1>Curves and surfaces with diffnurbs</h1>
<p>The course notebooks, executed on {stamp}. Run them yourself with <code>make lab</code>.</p>
<table><tr><th>Chapter</th><th>Exercises</th><th>Run time</th><th>Status</th></tr>
{rows}
</table></body></html>
"""
    path = out / "index.html"
    path.write_text(text, encoding="utf-8")
    return path


def main(argv: list[str] | None = None) -> int:
    """Build the site; return the exit status (1 when a chapter raised)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("notebooks", nargs="*", type=Path, help="default: course/*.ipynb")
    parser.add_argument("--out", type=Path, default=Path("build/html"))
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    args = parser.parse_args(argv)
    dc.use_headless_defaults()
    chapters = args.notebooks or dc.notebooks(_LAYOUT.course)
    args.out.mkdir(parents=True, exist_ok=True)
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=max(1, args.jobs), mp_context=spawn) as pool:
        pages = list(pool.map(build_chapter, chapters, [args.out] * len(chapters)))
    for page in pages:
        print(f"{page.name}: {page.seconds:.1f} s" + "".join(f"\n  {e}" for e in page.errors))
    exercises = [build_exercise(p, args.out) for p in dc.notebooks(_LAYOUT.exercises)]
    index = write_index(pages, exercises, args.out)
    print(f"wrote {index} ({len(pages)} chapter(s), {len(exercises)} exercise notebook(s))")
    return 1 if any(page.errors for page in pages) else 0


if __name__ == "__main__":
    sys.exit(main())
