"""Put notebooks in their committed form: no outputs, no execution counts, no widget state,
the standard `python3` kernelspec. `make html` produces the executed versions.

    python tools/nbclean.py [--check] NOTEBOOK...     (default: course/ solutions/ exercises/)

With `--check` nothing is written: the exit status is 1 when a notebook would change.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import nbformat

import diffnurbs_course as dc

_LAYOUT = dc.CourseLayout(Path(__file__).resolve().parents[1])
_DEFAULT_DIRS = (_LAYOUT.course, _LAYOUT.solutions, _LAYOUT.exercises)


def main(argv: list[str] | None = None) -> int:
    """Clean (or check) the given notebooks; return the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("notebooks", nargs="*", type=Path)
    parser.add_argument("--check", action="store_true", help="only report unclean notebooks")
    args = parser.parse_args(argv)
    paths = args.notebooks or [p for d in _DEFAULT_DIRS for p in dc.notebooks(d)]
    dirty = []
    for path in paths:
        nb = dc.read_notebook(path)
        if not dc.policy_problems(nb):
            continue
        dirty.append(path)
        if not args.check:
            nbformat.write(dc.clean_notebook(nb), path)
    verb = "would clean" if args.check else "cleaned"
    for path in dirty:
        print(f"{verb} {path}")
    return 1 if args.check and dirty else 0


if __name__ == "__main__":
    sys.exit(main())
