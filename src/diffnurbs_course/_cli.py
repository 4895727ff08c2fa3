"""`diffnurbs-grade`: batch-grade exercise notebooks without Docker, hidden tests included.

```
diffnurbs-grade SUBMISSIONS_DIR -o scores.csv [--timeout 300] [--solutions DIR | --course DIR]
                [--jobs N] [--report report.json]
```

Every `*.ipynb` under `SUBMISSIONS_DIR` is matched to its master (by the assignment name otter
stores in the notebook, else by file name), graded (see `grade_notebook`), and written as one
CSV row: `file, q1, q2, ..., total, max`. The masters are `--solutions DIR`, else
`--course DIR`'s `solutions/`, else `./solutions`.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from ._batch import grade_directory
from ._grading import DEFAULT_TIMEOUT
from ._layout import find_solutions
from ._notebooks import notebooks, use_headless_defaults
from ._scores import print_progress, write_csv


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="diffnurbs-grade",
        description="Grade exercise notebooks with their masters' public and hidden tests "
        "(no Docker). Writes a CSV: file, q1, q2, ..., total, max.",
    )
    parser.add_argument("submissions", type=Path, help="folder of submitted notebooks")
    parser.add_argument("-o", "--output", type=Path, required=True, help="CSV file to write")
    parser.add_argument(
        "--timeout",
        type=float,
        default=DEFAULT_TIMEOUT,
        help=f"seconds each notebook's cells may run together (default {DEFAULT_TIMEOUT})",
    )
    masters = parser.add_mutually_exclusive_group()
    masters.add_argument(
        "--solutions",
        type=Path,
        default=None,
        help="folder of master notebooks (default: ./solutions)",
    )
    masters.add_argument(
        "--course",
        type=Path,
        default=None,
        help="instead of --solutions: a course folder (a clone of diffnurbs) holding solutions/",
    )
    parser.add_argument("--jobs", type=int, default=1, help="notebooks graded at once (default 1)")
    parser.add_argument(
        "--report", type=Path, default=None, help="also write per-test results to this JSON file"
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `diffnurbs-grade`.

    **Arguments:**

    - `argv`: command-line arguments (default: `sys.argv[1:]`).

    **Returns:**

    The exit status: 0 when the batch was graded, 2 on a usage error.
    """
    args = _parser().parse_args(argv)
    if not args.submissions.is_dir():
        print(f"error: {args.submissions} is not a folder", file=sys.stderr)
        return 2
    try:
        solutions = args.solutions or find_solutions(args.course)
    except FileNotFoundError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if not notebooks(solutions):
        print(f"error: no master notebooks in {solutions}", file=sys.stderr)
        return 2
    use_headless_defaults()
    print(f"Grading {args.submissions} against {solutions} (timeout {args.timeout:g} s)")
    results = grade_directory(
        args.submissions,
        solutions,
        timeout=args.timeout,
        jobs=args.jobs,
        progress=print_progress,
    )
    write_csv(results, args.output)
    if args.report:
        args.report.write_text(json.dumps([r.to_json() for r in results], indent=1))
    unmatched = [r.file for r in results if r.master is None]
    if unmatched:
        print(f"warning: {len(unmatched)} notebook(s) matched no master: {', '.join(unmatched)}")
    print(f"Wrote {len(results)} row(s) to {args.output}")
    return 0
