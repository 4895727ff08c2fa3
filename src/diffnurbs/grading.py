"""`diffnurbs-grade`: batch-grade exercise notebooks without Docker, hidden tests included.

```
diffnurbs-grade SUBMISSIONS_DIR -o scores.csv [--timeout 300] [--solutions DIR] [--jobs N]
```

Every `*.ipynb` under `SUBMISSIONS_DIR` is matched to its master in `solutions/` (by the
assignment name otter stores in the notebook, else by file name), executed top to bottom in a
fresh kernel with errors allowed, and scored with the master's public and hidden tests through
otter's own test runner (`otter.Notebook` grading mode, the mechanism `otter run` uses). The
result is one CSV row per notebook: `file, q1, q2, ..., total, max`.

How a submission is run:

1. otter's grading mode is switched on in the kernel, with the master's tests (hidden ones
   included) in a private folder; the student's own `grader.check("qN")` cells then record
   results with all tests, and every result is written to disk at once.
2. The student's cells run in order; a cell that raises does not stop the run.
3. After the last cell every question not checked yet is checked (its own time limit).
4. `--timeout` bounds the student's cells together. When it runs out the kernel is interrupted
   and the questions are checked; a kernel that ignores the interrupt (or dies) is killed, and
   the questions checked so far keep their marks.

Submissions run with the grader's privileges: grade untrusted work in a throwaway account or
container. As with `otter run`, the tests run inside the submission's own kernel, so a
submission written to attack the grader could forge its results: read the code of suspicious
scores (`--report` lists every cell error and test result).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import multiprocessing
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from pprint import pformat
from typing import Any

import nbformat
from nbclient import NotebookClient
from nbclient.exceptions import DeadKernelError

from . import _course

DEFAULT_TIMEOUT = 300
"""Seconds a submission's own cells may run, all together."""

CHECK_TIMEOUT = 60
"""Seconds the tests of one question may run."""

INIT_TIMEOUT = 120
"""Seconds for starting the grading session in the kernel."""

RECOVERY_TIMEOUT = 5
"""Seconds an interrupted kernel gets to answer again before it is killed."""


# ----------------------------------------------------------------------------------------------
# Kernel side


class KernelSession:
    """Grading session inside the submission's kernel (created by the injected first cell).

    Switches otter to grading mode with the master's tests and keeps a JSON file with the
    result of every question checked so far, so nothing is lost if the kernel has to be killed.

    **Arguments:**

    - `tests_dir`: folder with one OK-format test file per question (`q1.py`, ...).
    - `results_path`: the JSON file to keep up to date.
    """

    def __init__(self, tests_dir: str, results_path: str):
        from otter import Notebook
        from otter.execute import Checker

        self._tests_dir = tests_dir
        self._results_path = results_path
        self._checker = Checker
        Notebook.init_grading_mode(tests_dir)
        original = Checker.check.__func__
        session = self

        def check_and_save(cls, *args, **kwargs):
            result = original(cls, *args, **kwargs)
            session.save()
            return result

        Checker.check = classmethod(check_and_save)
        self.save()

    def check(self, question: str, global_env: dict[str, Any]) -> None:
        """Run a question's tests against `global_env` unless the student's cells already did.

        **Arguments:**

        - `question`: the question name, e.g. `"q1"`.
        - `global_env`: the notebook's globals.
        """
        path = os.path.join(self._tests_dir, f"{question}.py")
        self._checker.check_if_not_already_checked(path, global_env)

    def save(self) -> None:
        """Write the latest result of every question checked so far (atomically)."""
        results = {}
        for test_file in self._checker.get_results():
            results[test_file.name] = {
                "score": float(test_file.score),
                "possible": float(test_file.possible),
                "cases": [
                    {
                        "hidden": r.test_case.hidden,
                        "passed": r.passed,
                        "points": r.test_case.points,
                        "message": r.message,
                    }
                    for r in test_file.test_case_results
                ],
            }
        tmp = self._results_path + ".tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(results, f)
        os.replace(tmp, self._results_path)


# ----------------------------------------------------------------------------------------------
# Masters


@dataclass(frozen=True)
class Master:
    """The grading view of one master notebook.

    **Arguments:**

    - `name`: the master's stem, e.g. `"02_bezier_curves"`.
    - `tests`: OK-format test specs by question (public and hidden cases), in question order.
    - `possible`: the points of each question.
    """

    name: str
    tests: dict[str, dict[str, Any]]
    possible: dict[str, float]

    @property
    def questions(self) -> list[str]:
        """The question names in notebook order."""
        return list(self.tests)

    @property
    def max_points(self) -> float:
        """The total points of the assignment."""
        return sum(self.possible.values())

    def write_tests(self, directory: Path) -> None:
        """Write one otter test file per question into `directory`."""
        directory.mkdir(parents=True, exist_ok=True)
        for question, spec in self.tests.items():
            text = f"OK_FORMAT = True\n\ntest = {pformat(spec, width=100)}\n"
            (directory / f"{question}.py").write_text(text, encoding="utf-8")


def load_master(path: Path) -> Master:
    """Build a `Master` from `solutions/NN_topic.ipynb` by running otter assign on it.

    **Arguments:**

    - `path`: the master notebook.

    **Returns:**

    The master's tests (hidden included) and point values.
    """
    from otter.test_files import OKTestFile

    with tempfile.TemporaryDirectory(prefix="diffnurbs-master-") as tmp:
        assigned = _course.assign(Path(path), Path(tmp))
        tests = _course.otter_tests(_course.read_notebook(assigned.autograder))
    possible = {q: float(OKTestFile.from_spec(spec).possible) for q, spec in tests.items()}
    return Master(Path(path).stem, tests, possible)


def load_masters(solutions: Path, names: Iterable[str] | None = None) -> dict[str, Master]:
    """Load the masters in a folder.

    **Arguments:**

    - `solutions`: the folder of masters.
    - `names`: only these stems (default: all).

    **Returns:**

    The masters by stem.
    """
    wanted = None if names is None else set(names)
    return {
        p.stem: load_master(p)
        for p in _course.notebooks(solutions)
        if wanted is None or p.stem in wanted
    }


def match_master(path: Path, nb: nbformat.NotebookNode | None, names: Iterable[str]) -> str | None:
    """Which master a submitted notebook answers.

    Tried in order: the assignment name otter stores in the notebook's metadata, the file stem,
    then the longest master name contained in the file name (`alice_02_bezier_curves.ipynb`).

    **Arguments:**

    - `path`: the submitted file.
    - `nb`: its content, if it could be read.
    - `names`: the available master stems.

    **Returns:**

    The master's stem, or `None`.
    """
    names = set(names)
    if nb is not None:
        assignment = nb.metadata.get("otter", {}).get("assignment_name")
        if assignment in names:
            return assignment
    if path.stem in names:
        return path.stem
    contained = [name for name in names if name in path.name]
    return max(contained, key=len) if contained else None


# ----------------------------------------------------------------------------------------------
# Grading one notebook


@dataclass
class GradeResult:
    """The grade of one submitted notebook.

    **Arguments:**

    - `file`: the submission's path (as given in the CSV).
    - `master`: the matched master's stem, or `None`.
    - `scores`: points earned per question.
    - `possible`: points available per question.
    - `notes`: what went wrong (errors, time-outs), for the teacher.
    - `errors`: the cells that raised, as `CellError` descriptions.
    - `seconds`: wall time of the grading run.
    - `details`: per-question test case results from otter (hidden ones included).
    - `executed`: the executed notebook (not serialised).
    """

    file: str
    master: str | None
    scores: dict[str, float] = field(default_factory=dict)
    possible: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    errors: list[dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0
    details: dict[str, Any] = field(default_factory=dict)
    executed: nbformat.NotebookNode | None = field(default=None, repr=False, compare=False)

    @property
    def total(self) -> float:
        """Points earned."""
        return sum(self.scores.values())

    @property
    def max_points(self) -> float:
        """Points available."""
        return sum(self.possible.values())

    def to_json(self) -> dict[str, Any]:
        """A JSON-serialisable dictionary (without the executed notebook)."""
        data = asdict(self)
        data.pop("executed")
        return data

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> GradeResult:
        """Inverse of `to_json`."""
        return cls(**data)


_TIMEOUT_ENAME = "DiffnurbsGradingTimeout"


class _Run:
    """Executes cells one by one in one kernel, noticing time-outs and a dead kernel.

    On a time-out nbclient interrupts the kernel and reports a synthetic error (with
    `_TIMEOUT_ENAME`) instead of raising, and stops waiting for the interrupted cell's output
    after its `iopub_timeout`, so the next cell starts cleanly.

    **Arguments:**

    - `client`: the nbclient client of the notebook to run.
    """

    def __init__(self, client: NotebookClient):
        self.client = client
        self.notes: list[str] = []
        self.alive = True
        self._timed_out = False
        client.interrupt_on_timeout = True
        client.error_on_timeout = {"ename": _TIMEOUT_ENAME, "evalue": "", "traceback": []}
        client.on_cell_error = self._on_cell_error

    def _on_cell_error(self, cell, cell_index, execute_reply) -> None:
        if execute_reply["content"].get("ename") == _TIMEOUT_ENAME:
            self._timed_out = True

    def run(self, index: int, timeout: float) -> bool:
        """Execute cell `index` within `timeout` seconds.

        **Arguments:**

        - `index`: the cell's index in the client's notebook.
        - `timeout`: the time limit in seconds.

        **Returns:**

        `False` when the cell timed out (the kernel was interrupted) or the kernel died.
        """
        self._timed_out = False
        self.client.timeout = max(1, math.ceil(timeout))
        try:
            self.client.execute_cell(self.client.nb.cells[index], index)
        except DeadKernelError:
            self.notes.append("the kernel died")
            self.alive = False
            return False
        return not self._timed_out

    def responsive(self) -> bool:
        """Whether the kernel answers a trivial cell; if not, it is given up (and killed)."""
        if not self.alive:
            return False
        self.client.nb.cells.append(nbformat.v4.new_code_cell("pass"))
        answered = self.run(len(self.client.nb.cells) - 1, RECOVERY_TIMEOUT)
        self.client.nb.cells.pop()
        if not answered and self.alive:
            self.notes.append("the kernel ignored the interrupt and was killed")
            self.alive = False
        return answered


def _session_cells(tests_dir: Path, results: Path, questions: Sequence[str]):
    init = nbformat.v4.new_code_cell(
        "from diffnurbs.grading import KernelSession as _DiffnurbsKernelSession\n"
        f"_diffnurbs_session = _DiffnurbsKernelSession({str(tests_dir)!r}, {str(results)!r})"
    )
    checks = [
        nbformat.v4.new_code_cell(f"_diffnurbs_session.check({q!r}, globals())") for q in questions
    ]
    return init, checks


def _run_submission(
    nb: nbformat.NotebookNode, master: Master, workdir: Path, timeout: float
) -> tuple[nbformat.NotebookNode, list[str]]:
    """Execute a submission with the grading session around it; return it and the notes."""
    tests_dir, results = workdir / "grading" / "tests", workdir / "grading" / "results.json"
    master.write_tests(tests_dir)
    init, checks = _session_cells(tests_dir, results, master.questions)
    student = [cell for cell in nb.cells if cell.cell_type == "code"]
    run_nb = nbformat.v4.new_notebook(cells=[init, *student, *checks], metadata=nb.metadata)
    cwd = workdir / "run"
    client = _course.make_client(run_nb, cwd, timeout=INIT_TIMEOUT, allow_errors=True)
    run = _Run(client)
    with client.setup_kernel(stderr=subprocess.DEVNULL):
        if not run.run(0, INIT_TIMEOUT) or any(o.output_type == "error" for o in init.outputs):
            raise RuntimeError(f"could not start the grading session: {init.outputs}")
        _run_student_cells(run, 1, len(student), timeout)
        _run_checks(run, 1 + len(student), master.questions)
    return run_nb, run.notes


def _run_student_cells(run: _Run, first: int, count: int, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    for index in range(first, first + count):
        remaining = deadline - time.monotonic()
        if remaining <= 0 or not run.run(index, remaining):
            if run.alive:
                run.notes.append(f"timed out after {timeout:g} s in code cell {index - first + 1}")
                run.responsive()
            return


def _run_checks(run: _Run, first: int, questions: Sequence[str]) -> None:
    for offset, question in enumerate(questions):
        if not run.alive:
            return
        if not run.run(first + offset, CHECK_TIMEOUT):
            run.notes.append(f"{question}: tests timed out after {CHECK_TIMEOUT} s")
            run.responsive()


def _read_results(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def grade_notebook(
    path: Path, master: Master, *, timeout: float = DEFAULT_TIMEOUT, label: str | None = None
) -> GradeResult:
    """Grade one submitted notebook against its master.

    **Arguments:**

    - `path`: the submitted notebook.
    - `master`: the master it answers.
    - `timeout`: seconds the submission's cells may run together.
    - `label`: the name used in the CSV (default: `path`).

    **Returns:**

    The `GradeResult`; a notebook that cannot be read scores 0 with a note.
    """
    start = time.perf_counter()
    result = GradeResult(label or str(path), master.name, possible=dict(master.possible))
    result.scores = dict.fromkeys(master.questions, 0.0)
    try:
        nb = _course.read_notebook(path)
    except Exception as error:
        result.notes.append(f"unreadable notebook: {type(error).__name__}: {error}")
        return result
    with tempfile.TemporaryDirectory(prefix="diffnurbs-grade-") as tmp:
        workdir = Path(tmp)
        (workdir / "run").mkdir()
        shutil.copyfile(path, workdir / "run" / f"{master.name}.ipynb")
        executed, notes = _run_submission(nb, master, workdir, timeout)
        details = _read_results(workdir / "grading" / "results.json")
    result.notes += notes
    result.executed = executed
    result.details = details
    result.errors = [asdict(e) for e in _course.cell_errors(executed)]
    for question in master.questions:
        result.scores[question] = float(details.get(question, {}).get("score", 0.0))
    result.seconds = time.perf_counter() - start
    return result


# ----------------------------------------------------------------------------------------------
# Batches and the CSV


def find_submissions(directory: Path) -> list[Path]:
    """Every notebook under `directory` (recursively), skipping checkpoints and hidden folders."""
    found = []
    for path in sorted(directory.rglob("*.ipynb")):
        parts = path.relative_to(directory).parts
        if not any(part.startswith(".") for part in parts):
            found.append(path)
    return found


def _peek(path: Path) -> nbformat.NotebookNode | None:
    try:
        return _course.read_notebook(path)
    except Exception:
        return None


def _grade_one(path: Path, label: str, master: Master | None, timeout: float) -> GradeResult:
    if master is None:
        return GradeResult(label, None, notes=["no master in the solutions folder matches it"])
    try:
        result = grade_notebook(path, master, timeout=timeout, label=label)
    except Exception as error:  # the grader's own failure: report it, grade the rest
        result = GradeResult(label, master.name, dict.fromkeys(master.questions, 0.0))
        result.possible = dict(master.possible)
        result.notes.append(f"grading failed: {type(error).__name__}: {error}")
    result.executed = None
    return result


def grade_directory(
    submissions: Path,
    solutions: Path,
    *,
    timeout: float = DEFAULT_TIMEOUT,
    jobs: int = 1,
    progress: Callable[[int, int, GradeResult], None] | None = None,
) -> list[GradeResult]:
    """Grade every notebook under a folder.

    **Arguments:**

    - `submissions`: the folder of submitted notebooks (searched recursively).
    - `solutions`: the folder of masters.
    - `timeout`: seconds each submission's cells may run together.
    - `jobs`: how many notebooks to grade at once.
    - `progress`: called as `progress(done, total, result)` after each notebook.

    **Returns:**

    One `GradeResult` per notebook, in file order.
    """
    paths = find_submissions(submissions)
    names = [p.stem for p in _course.notebooks(solutions)]
    matched = {p: match_master(p, _peek(p), names) for p in paths}
    masters = load_masters(solutions, {m for m in matched.values() if m})
    tasks = [
        (p, str(p.relative_to(submissions)), masters.get(matched[p] or ""), timeout) for p in paths
    ]
    results: dict[int, GradeResult] = {}
    if jobs <= 1:
        for index, task in enumerate(tasks):
            results[index] = _grade_one(*task)
            if progress:
                progress(len(results), len(tasks), results[index])
    else:
        spawn = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=jobs, mp_context=spawn) as pool:
            futures = {pool.submit(_grade_one, *task): i for i, task in enumerate(tasks)}
            for future in as_completed(futures):
                results[futures[future]] = future.result()
                if progress:
                    progress(len(results), len(tasks), results[futures[future]])
    return [results[i] for i in range(len(tasks))]


def _number(value: float) -> str:
    return f"{round(value, 4):g}"


def question_columns(results: Sequence[GradeResult]) -> list[str]:
    """The question columns of a batch: every question of every matched master, first seen first."""
    columns: list[str] = []
    for result in results:
        columns += [q for q in result.possible if q not in columns]
    return columns


def write_csv(results: Sequence[GradeResult], path: Path) -> None:
    """Write the scores table `file, q1, ..., total, max` (blank where a question does not apply).

    **Arguments:**

    - `results`: the graded notebooks.
    - `path`: the CSV file to write.
    """
    questions = question_columns(results)
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(["file", *questions, "total", "max"])
        for r in results:
            cells = [_number(r.scores[q]) if q in r.scores else "" for q in questions]
            maximum = _number(r.max_points) if r.master else ""
            writer.writerow([r.file, *cells, _number(r.total), maximum])


def _print_progress(done: int, total: int, result: GradeResult) -> None:
    score = f"{_number(result.total)}/{_number(result.max_points)}" if result.master else "-"
    notes = f"  [{'; '.join(result.notes)}]" if result.notes else ""
    print(f"[{done}/{total}] {result.file}: {score} ({result.seconds:.0f} s){notes}", flush=True)


def _default_solutions() -> Path:
    local = Path("solutions")
    return local if local.is_dir() else _course.SOLUTIONS_DIR


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
    parser.add_argument(
        "--solutions",
        type=Path,
        default=None,
        help="folder of master notebooks (default: ./solutions, else the course's solutions/)",
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
    solutions = args.solutions or _default_solutions()
    if not args.submissions.is_dir():
        print(f"error: {args.submissions} is not a folder", file=sys.stderr)
        return 2
    if not _course.notebooks(solutions):
        print(f"error: no master notebooks in {solutions}", file=sys.stderr)
        return 2
    _course.use_headless_defaults()
    print(f"Grading {args.submissions} against {solutions} (timeout {args.timeout:g} s)")
    results = grade_directory(
        args.submissions,
        solutions,
        timeout=args.timeout,
        jobs=args.jobs,
        progress=_print_progress,
    )
    write_csv(results, args.output)
    if args.report:
        args.report.write_text(json.dumps([r.to_json() for r in results], indent=1))
    unmatched = [r.file for r in results if r.master is None]
    if unmatched:
        print(f"warning: {len(unmatched)} notebook(s) matched no master: {', '.join(unmatched)}")
    print(f"Wrote {len(results)} row(s) to {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
