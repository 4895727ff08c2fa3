"""`diffnurbs-grade`: batch-grade exercise notebooks in a sandbox, hidden tests included.

```
diffnurbs-grade SUBMISSIONS_DIR -o scores.csv [--solutions DIR | --course DIR] [--jobs N]
                [--timeout 300] [--cell-timeout 120] [--check-timeout 60]
                [--memory-mb 4096] [--max-processes 512] [--file-mb 256] [--no-sandbox]
                [--report report.json] [--feedback DIR [--feedback-format md|html]]
```

Every `*.ipynb` under `SUBMISSIONS_DIR` is matched to its master (by the assignment name otter
stores in the notebook, else by file name), graded (see `grade_notebook`: the student's code in
a bubblewrap sandbox, the tests in the grader), and written as one CSV row:
`file, q1, q2, ..., total, max, flags`. The masters are `--solutions DIR`, else `--course DIR`'s
`solutions/`, else `./solutions`. Where no sandbox can be made the grader refuses to run unless
`--no-sandbox` says the submissions are trusted.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from pathlib import Path

import jax

from ._batch import grade_directory
from ._grading import CELL_TIMEOUT, CHECK_TIMEOUT, DEFAULT_TIMEOUT, SANDBOX_LIMITS
from ._handback import write_feedback
from ._layout import find_solutions
from ._notebooks import notebooks, use_headless_defaults
from ._sandbox import SandboxLimits, sandbox_problem
from ._scores import print_progress, write_csv


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="diffnurbs-grade",
        description="Grade exercise notebooks with their masters' public and hidden tests: "
        "each notebook runs in a sandbox (bubblewrap), the tests run in the grader. "
        "Writes a CSV: file, q1, q2, ..., total, max, flags.",
    )
    parser.add_argument("submissions", type=Path, help="folder of submitted notebooks")
    parser.add_argument("-o", "--output", type=Path, required=True, help="CSV file to write")
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
    times = parser.add_argument_group("time limits (seconds)")
    limits = [
        (times, "--timeout", float, DEFAULT_TIMEOUT, "a notebook's cells all together"),
        (times, "--cell-timeout", float, CELL_TIMEOUT, "one cell, then interrupted and skipped"),
        (times, "--check-timeout", float, CHECK_TIMEOUT, "the tests of one question"),
    ]
    sandbox = parser.add_argument_group("sandbox")
    limits += [
        (sandbox, "--memory-mb", int, SANDBOX_LIMITS.memory_mb, "address space per process, MiB"),
        (sandbox, "--max-processes", int, SANDBOX_LIMITS.processes, "tasks, threads included"),
        (sandbox, "--file-mb", int, SANDBOX_LIMITS.file_mb, "largest file, and /tmp's size, MiB"),
    ]
    for group, flag, kind, default, what in limits:
        group.add_argument(flag, type=kind, default=default, help=f"{what} (default {default})")
    sandbox.add_argument(
        "--no-sandbox",
        action="store_true",
        help="run the notebooks unconfined, with your privileges: only for notebooks you trust",
    )
    out = parser.add_argument_group("reports")
    out.add_argument(
        "--report", type=Path, default=None, help="also write per-test results to this JSON file"
    )
    out.add_argument(
        "--feedback",
        type=Path,
        default=None,
        help="write one page per student into this folder: scores and what failed, "
        "without the code of hidden tests",
    )
    out.add_argument(
        "--feedback-format",
        choices=("md", "html"),
        default="md",
        help="the pages' format (default md)",
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
    if args.no_sandbox:
        limits = None
    else:
        problem = sandbox_problem()
        if problem is not None:
            print(
                f"error: no sandbox on this machine: {problem} Student code would run with your "
                "privileges; pass --no-sandbox only if you trust every notebook.",
                file=sys.stderr,
            )
            return 2
        try:
            limits = SandboxLimits(args.memory_mb, args.max_processes, args.file_mb)
        except ValueError as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
    use_headless_defaults()
    # The tests run in the grader and compile the library's programs: keep them between runs
    # (the teacher's own cache; the sandboxed kernels never see it).
    if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
        cache = str(Path.home() / ".cache" / "diffnurbs-grade" / "jax")
        os.environ["JAX_COMPILATION_CACHE_DIR"] = cache  # for the --jobs workers
        os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
        jax.config.update("jax_compilation_cache_dir", cache)  # jax is imported already
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    where = "unconfined (--no-sandbox)" if limits is None else "in a sandbox"
    print(f"Grading {args.submissions} against {solutions}, {where} (timeout {args.timeout:g} s)")
    results = grade_directory(
        args.submissions,
        solutions,
        jobs=args.jobs,
        progress=print_progress,
        timeout=args.timeout,
        cell_timeout=args.cell_timeout,
        check_timeout=args.check_timeout,
        limits=limits,
    )
    write_csv(results, args.output)
    if args.report:
        args.report.write_text(json.dumps([r.to_json() for r in results], indent=1))
    if args.feedback:
        pages = write_feedback(results, args.feedback, format=args.feedback_format)
        print(f"Wrote {len(pages)} feedback page(s) to {args.feedback}")
    unmatched = [r.file for r in results if r.master is None]
    if unmatched:
        print(f"warning: {len(unmatched)} notebook(s) matched no master: {', '.join(unmatched)}")
    print(f"Wrote {len(results)} row(s) to {args.output}")
    return 0
