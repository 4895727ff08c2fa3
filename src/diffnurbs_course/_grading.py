"""Grading one submitted notebook: the student's code in a sandbox, the tests out of its reach.

1. The submission's code cells run in a fresh kernel inside a bubblewrap sandbox (`_sandbox`):
   its own PID and network namespaces, a read-only view of the system and the Python
   environment, a private scratch folder holding only the notebook, a cleared environment, and
   memory, process and file-size limits. A cell that raises does not stop the run. A cell that
   runs past its limit is interrupted and skipped; a kernel that ignores the interrupt, or dies,
   is restarted and the cells before it run again (the hung ones skipped), so the questions
   after a hang keep their marks. The whole sandbox, daemons included, ends with the grading.
2. The master's tests, hidden ones included, then run in the grader's own process
   (`_scoring.Scorer`), in a namespace built from the master's init cell: the student's values
   are fetched, and the student's functions called, through a channel that carries only data.
   Nothing the submission does in its kernel changes how it is scored.
3. Outputs are kept up to `OUTPUT_LIMIT` bytes per notebook, error messages up to
   `MESSAGE_LIMIT` characters; the executed notebook, the test results, the notes and the flags
   make the `GradeResult`.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import time
from collections import deque
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import nbformat
from jupyter_client.utils import run_sync
from nbclient.exceptions import DeadKernelError

from ._flags import submission_flags
from ._masters import Master
from ._notebooks import PollingNotebookClient, cell_errors, make_client, read_notebook
from ._sandbox import AsyncSandboxKernelManager, SandboxLimits
from ._scoring import KernelLost, Scorer

DEFAULT_TIMEOUT = 300
"""Seconds a submission's own cells may run, all together (re-runs after a restart included)."""

CELL_TIMEOUT = 120
"""Seconds one code cell may run before it is interrupted and skipped."""

CHECK_TIMEOUT = 60
"""Seconds the tests of one question may run."""

RECOVERY_TIMEOUT = 5
"""Seconds an interrupted kernel gets to answer again before it is restarted."""

MAX_RESTARTS = 3
"""Kernel restarts allowed per submission; after that the remaining cells are not run."""

OUTPUT_LIMIT = 1_000_000
"""Bytes of cell output kept per notebook (in memory and in the report)."""

MESSAGE_LIMIT = 2_000
"""Characters kept of an error message or a test's failure message."""

SANDBOX_LIMITS = SandboxLimits()
"""The sandbox's default limits (memory, processes, file size)."""


@dataclass
class GradeResult:
    """The grade of one submitted notebook.

    **Arguments:**

    - `file`: the submission's path (as given in the CSV).
    - `master`: the matched master's stem, or `None`.
    - `scores`: points earned per question.
    - `possible`: points available per question.
    - `notes`: what went wrong (errors, time-outs, restarts), for the teacher.
    - `flags`: why the teacher should read this submission's code (see `submission_flags`).
    - `errors`: the cells that raised, as `CellError` descriptions.
    - `seconds`: wall time of the grading run.
    - `details`: per question, the score and the result of every test case (hidden ones
      included): `{"score", "possible", "cases": [{"hidden", "passed", "points", "message"}],
      "notes"}`.
    - `executed`: the executed notebook (not serialised).
    """

    file: str
    master: str | None
    scores: dict[str, float] = field(default_factory=dict)
    possible: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    flags: list[str] = field(default_factory=list)
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


def _clip(text: str, limit: int = MESSAGE_LIMIT) -> str:
    return (
        text if len(text) <= limit else f"{text[:limit]} [... {len(text) - limit} more characters]"
    )


class _BoundedClient(PollingNotebookClient):
    """Keeps at most `OUTPUT_LIMIT` bytes of output per notebook, then one note saying so.

    nbclient keeps every output message in memory; a submission printing without end would
    otherwise grow the grader (and the report) without bound. Errors are always kept, their
    message and traceback clipped, since the report names them.
    """

    kept = 0
    _TRACEBACK_LINES = 20

    def output(self, outs, msg, display_id, cell_index):
        content = msg.get("content", {})
        if msg.get("msg_type") == "error":
            content["evalue"] = _clip(str(content.get("evalue", "")))
            lines = content.get("traceback", [])[-self._TRACEBACK_LINES :]
            content["traceback"] = [_clip(str(line)) for line in lines]
            return super().output(outs, msg, display_id, cell_index)
        size = len(str(content.get("text", ""))) + sum(
            len(str(value)) for value in content.get("data", {}).values()
        )
        self.kept += size
        if self.kept <= OUTPUT_LIMIT:
            return super().output(outs, msg, display_id, cell_index)
        if self.kept - size <= OUTPUT_LIMIT:  # the first output over the limit leaves a note
            outs.append(
                nbformat.v4.new_output(
                    "stream", name="stderr", text=f"[output truncated at {OUTPUT_LIMIT} bytes]\n"
                )
            )
        return None


_TIMEOUT_ENAME = "DiffnurbsGradingTimeout"


class _Run:
    """Executes cells one by one in one kernel, noticing time-outs and a dead kernel.

    On a time-out nbclient interrupts the kernel and reports a synthetic error (with
    `_TIMEOUT_ENAME`) instead of raising, and stops waiting for the interrupted cell's output
    after its `iopub_timeout`, so the next cell starts cleanly.

    **Arguments:**

    - `client`: the nbclient client of the notebook to run, its kernel started.
    """

    def __init__(self, client: PollingNotebookClient):
        self.client = client
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
            self.alive = False
            return False
        return not self._timed_out

    def responsive(self) -> bool:
        """Whether the kernel answers a trivial cell within `RECOVERY_TIMEOUT` seconds."""
        if not self.alive:
            return False
        self.client.nb.cells.append(nbformat.v4.new_code_cell("pass"))
        answered = self.run(len(self.client.nb.cells) - 1, RECOVERY_TIMEOUT)
        self.client.nb.cells.pop()
        return answered

    def restart(self) -> None:
        """A fresh kernel (in a fresh sandbox) on the same connection."""
        run_sync(self.client.km.restart_kernel)(now=True)
        run_sync(self.client.kc.wait_for_ready)(timeout=self.client.startup_timeout)
        self.alive = True


class _Session:
    """One submission's kernel: runs its cells, restarts it when it hangs, and scores it.

    **Arguments:**

    - `run`: the cell runner on the submission's started kernel.
    - `master`: the master whose tests score it.
    - `timeout`, `cell_timeout`, `check_timeout`: see `grade_notebook`.
    """

    def __init__(
        self, run: _Run, master: Master, timeout: float, cell_timeout: float, check_timeout: float
    ):
        self.run = run
        self.master = master
        self.cell_timeout = cell_timeout
        self.check_timeout = check_timeout
        self.deadline = time.monotonic() + timeout
        self.timeout = timeout
        self.done: list[int] = []  # the cells run to the end in the current kernel
        self.restarts = 0
        self.notes: list[str] = []
        self.kc = None

    def _restart(self, why: str) -> bool:
        """Restart the kernel; `False` when the restarts are used up."""
        if self.restarts >= MAX_RESTARTS:
            self.notes.append(f"{why}; no restart left ({MAX_RESTARTS} used)")
            return False
        self.restarts += 1
        self.notes.append(f"{why}: the kernel was restarted and the cells before it run again")
        self.run.restart()
        return True

    def run_cells(self, indices: list[int]) -> bool:
        """Run code cells in order, skipping a hung one; `False` if the run had to stop.

        After a restart the cells run so far (hung ones excepted) run again first, since the
        cells after them may use what they defined.
        """
        queue = deque(indices)
        while queue:
            index = queue.popleft()
            remaining = self.deadline - time.monotonic()
            if remaining <= 0:
                left = len(queue) + 1
                self.notes.append(
                    f"out of time ({self.timeout:g} s for all cells): {left} code cell(s) not run"
                )
                return False
            limit = min(self.cell_timeout, remaining)
            if self.run.run(index, limit):
                self.done.append(index)
                continue
            where = f"code cell {index + 1}"
            if self.run.alive and self.run.responsive():
                self.notes.append(f"{where} was stopped after {limit:.0f} s and skipped")
                continue
            why = (
                f"{where} killed the kernel"
                if not self.run.alive
                else (f"{where} ran past {limit:.0f} s and ignored the interrupt")
            )
            if not self._restart(why):
                return False
            queue = deque([*self.done, *queue])
            self.done = []
        return True

    def score(self) -> dict[str, dict[str, Any]]:
        """Every question's test results, from the trusted scorer."""
        details: dict[str, dict[str, Any]] = {}
        scorer = self._scorer()
        for question in self.master.questions:
            if scorer is None:
                details[question] = _unscored(
                    question,
                    self.master,
                    f"{question}: not graded, the kernel could not be restarted",
                )
                continue
            try:
                details[question] = scorer.score(question, timeout=self.check_timeout)
            except KernelLost as error:
                lost = f"{question}: its tests stopped the kernel ({error})"
                details[question] = error.result or _unscored(question, self.master, lost)
                if error.result:
                    details[question]["notes"].append(lost)
                # The replay gets its own time: the student's budget may be spent already.
                self.deadline = time.monotonic() + self.timeout
                replay, self.done = self.done, []
                restarted = self._restart(lost) and self.run_cells(replay)
                scorer = self._scorer() if restarted else None
        return details

    def _scorer(self) -> Scorer:
        """A scorer on the current kernel, with a synchronous client of its own."""
        if self.kc is not None:
            self.kc.stop_channels()
        km = self.run.client.km
        self.kc = km.blocking_client()
        self.kc.start_channels()
        return Scorer(
            self.master,
            self.kc,
            interrupt=run_sync(km.interrupt_kernel),
            call_timeout=self.check_timeout,
        )

    def close(self) -> None:
        """Stop the scorer's client (the kernel itself is shut down by nbclient)."""
        if self.kc is not None:
            self.kc.stop_channels()
            self.kc = None


def _unscored(question: str, master: Master, why: str) -> dict[str, Any]:
    return {"score": 0.0, "possible": master.possible[question], "cases": [], "notes": [why]}


def _consistency_flags(details: dict[str, dict[str, Any]], master: Master) -> list[str]:
    """Results that are not the master's questions and test cases (the scores' range is
    `runtime_flags`'s)."""
    if list(details) != master.questions:
        return [f"results for {list(details)} where the master has {master.questions}"]
    flags = []
    for question, detail in details.items():
        cases = sum(len(suite["cases"]) for suite in master.tests[question]["suites"])
        if not detail.get("notes") and len(detail["cases"]) != cases:
            flags.append(f"{question}: {len(detail['cases'])} test results for {cases} tests")
    return flags


def grade_notebook(
    path: Path,
    master: Master,
    *,
    timeout: float = DEFAULT_TIMEOUT,
    cell_timeout: float = CELL_TIMEOUT,
    check_timeout: float = CHECK_TIMEOUT,
    limits: SandboxLimits | None = SANDBOX_LIMITS,
    label: str | None = None,
    compile_cache: Path | None = None,
) -> GradeResult:
    """Grade one submitted notebook against its master.

    **Arguments:**

    - `path`: the submitted notebook.
    - `master`: the master it answers.
    - `timeout`: seconds the submission's cells may run together.
    - `cell_timeout`: seconds one cell may run before it is interrupted and skipped.
    - `check_timeout`: seconds one question's tests may run.
    - `limits`: the sandbox's limits; `None` runs the kernel unconfined, with the grader's
      privileges (only for trusted notebooks, e.g. the masters).
    - `label`: the name used in the CSV (default: `path`).
    - `compile_cache`: a JAX compilation cache folder the sandboxed kernel reads and writes,
      shared with other runs; only for trusted notebooks (see `SandboxKernelManager`).

    **Returns:**

    The `GradeResult`; a notebook that cannot be read scores 0 with a note.
    """
    start = time.perf_counter()
    result = GradeResult(label or str(path), master.name, possible=dict(master.possible))
    result.scores = dict.fromkeys(master.questions, 0.0)
    try:
        nb = read_notebook(path)
    except Exception as error:
        result.notes.append(_clip(f"unreadable notebook: {type(error).__name__}: {error}"))
        return result
    cells = [cell for cell in nb.cells if cell.cell_type == "code"]
    run_nb = nbformat.v4.new_notebook(cells=cells, metadata=nb.metadata)
    with tempfile.TemporaryDirectory(prefix="diffnurbs-grade-") as tmp:
        scratch = Path(tmp) / "scratch"
        scratch.mkdir()
        shutil.copyfile(path, scratch / f"{master.name}.ipynb")  # `grader.check` reads it
        km = None
        if limits is not None:
            km = AsyncSandboxKernelManager(scratch, limits, compile_cache=compile_cache)
        client = make_client(
            run_nb,
            scratch,
            timeout=cell_timeout,
            allow_errors=True,
            km=km,
            client_class=_BoundedClient,
        )
        # `cleanup_kc`: shut the kernel (and with it the sandbox) down even when the manager
        # was given, not created, by nbclient.
        with client.setup_kernel(cleanup_kc=True):
            session = _Session(_Run(client), master, timeout, cell_timeout, check_timeout)
            try:
                session.run_cells(list(range(len(cells))))
                details = session.score()
            finally:
                session.close()
    result.notes += session.notes
    result.executed = run_nb
    result.details = details
    result.errors = [
        {**asdict(e), "evalue": _clip(e.evalue), "source": _clip(e.source)}
        for e in cell_errors(run_nb)
    ]
    for question in master.questions:
        result.scores[question] = float(details[question]["score"])
    result.flags = _consistency_flags(details, master) + submission_flags(
        run_nb, result, provided=master.handed_out
    )
    result.seconds = time.perf_counter() - start
    return result
