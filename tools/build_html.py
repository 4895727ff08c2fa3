"""`make html`: execute every chapter headless and build the course website.

    python tools/build_html.py [--out build/site] [--jobs 2]

The site (Jupyter Book: table of contents, search, math, every chapter and exercise page,
the code of check cells left out (what they print kept), editors shown as pictures of their
first state) is written to `<out>/_build/html/index.html`. Exercises are shown unexecuted:
they are the student's starting point. A chapter that raises is still published, with its
traceback; the exit status is then 1.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import shutil
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import nbformat

import diffnurbs_course as dc

_LAYOUT = dc.CourseLayout(Path(__file__).resolve().parents[1])


def execute(notebook: Path) -> tuple[nbformat.NotebookNode, float, list[str]]:
    """Execute one chapter in a fresh kernel; return it with its wall time and its errors."""
    nb = dc.read_notebook(notebook)
    with tempfile.TemporaryDirectory(prefix="diffnurbs-html-") as tmp:
        seconds = dc.execute_notebook(nb, Path(tmp), timeout=900, allow_errors=True)
    return nb, seconds, [error.describe() for error in dc.cell_errors(nb)]


def main(argv: list[str] | None = None) -> int:
    """Build the site; return the exit status (1 when a chapter raised)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=_LAYOUT.build / "site")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1))
    args = parser.parse_args(argv)
    dc.use_headless_defaults()
    chapters = dc.notebooks(_LAYOUT.course)
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=max(1, args.jobs), mp_context=spawn) as pool:
        runs = list(pool.map(execute, chapters))
    for path, (_, seconds, errors) in zip(chapters, runs, strict=True):
        print(f"{path.stem}: {seconds:.1f} s" + "".join(f"\n  {e}" for e in errors))
    executed = {path.stem: nb for path, (nb, _, _) in zip(chapters, runs, strict=True)}
    staging = args.out / "source"
    shutil.rmtree(staging, ignore_errors=True)
    dc.stage_site(_LAYOUT, staging, executed)
    html = dc.build_site(staging, args.out)
    print(f"wrote {html / 'index.html'}")
    return 1 if any(errors for _, _, errors in runs) else 0


if __name__ == "__main__":
    sys.exit(main())
