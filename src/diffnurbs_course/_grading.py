"""Grading one submitted notebook without Docker, hidden tests included.

The submission is executed top to bottom in a fresh kernel with errors allowed and scored with
its master's public and hidden tests through otter's own test runner (`otter.Notebook` grading
mode, the mechanism `otter run` uses):

1. otter's grading mode is switched on in the kernel, with the master's tests (hidden ones
   included) in a private folder; the student's own `grader.check("qN")` cells then record
   results with all tests, and every result is written to disk at once.
2. The student's cells run in order; a cell that raises does not stop the run.
3. After the last cell every question not checked yet is checked (its own time limit).
4. The time limit bounds the student's cells together. When it runs out the kernel is
   interrupted and the questions are checked; a kernel that ignores the interrupt (or dies) is
   killed, and the questions checked so far keep their marks.

Submissions run with the grader's privileges: grade untrusted work in a throwaway account or
container. As with `otter run`, the tests run inside the submission's own kernel, so a
submission written to attack the grader could forge its results: read the code of suspicious
scores (`--report` lists every cell error and test result).
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import nbformat
from nbclient import NotebookClient
from nbclient.exceptions import DeadKernelError

from ._masters import Master
from ._notebooks import cell_errors, make_client, read_notebook

DEFAULT_TIMEOUT = 300
"""Seconds a submission's own cells may run, all together."""

CHECK_TIMEOUT = 60
"""Seconds the tests of one question may run."""

INIT_TIMEOUT = 120
"""Seconds for starting the grading session in the kernel."""

RECOVERY_TIMEOUT = 5
"""Seconds an interrupted kernel gets to answer again before it is killed."""


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
        "from diffnurbs_course import KernelSession as _DiffnurbsKernelSession\n"
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
    client = make_client(run_nb, cwd, timeout=INIT_TIMEOUT, allow_errors=True)
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
        nb = read_notebook(path)
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
    result.errors = [asdict(e) for e in cell_errors(executed)]
    for question in master.questions:
        result.scores[question] = float(details.get(question, {}).get("score", 0.0))
    result.seconds = time.perf_counter() - start
    return result
