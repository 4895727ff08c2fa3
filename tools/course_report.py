"""`build/course_report.md`: every chapter measured against the template of `course/AUTHORING.md`.

    python tools/course_report.py [--out build/course_report.md]

Static measures (prose and visible code lines, visible asserts, the longest visible code
cell, links and anchors, Markdown tables) from the committed chapters; outputs are checked by
the notebook tests, which execute the chapters.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import diffnurbs_course as dc

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    """Write the report; return 0."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    layout = dc.CourseLayout(ROOT)
    parser.add_argument("--out", type=Path, default=layout.build / "course_report.md")
    args = parser.parse_args(argv)
    chapters = [p for p in dc.notebooks(layout.course) if p.stem != "00_index"]
    report = dc.course_report([dc.chapter_metrics(path) for path in chapters])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(report)
    print(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
