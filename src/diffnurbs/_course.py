"""Course machinery: notebook execution, exercise generation with otter-grader, master checks.

Shared by `diffnurbs-grade` (`diffnurbs.grading`), the `tools/` scripts behind `make html` and
`make exercises`, and the notebook tests. Nothing here is part of the library's public API.

The conventions it implements are written down for chapter authors in `course/AUTHORING.md`.
"""

from __future__ import annotations

import ast
import asyncio
import contextlib
import hashlib
import io
import logging
import os
import re
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from queue import Empty
from typing import Any

import nbformat
import yaml
from nbclient import NotebookClient
from nbclient.client import timestamp
from nbclient.util import ensure_async

REPO_ROOT = Path(__file__).resolve().parents[2]
"""The repository root (valid for the editable install the Makefile sets up)."""

COURSE_DIR = REPO_ROOT / "course"
SOLUTIONS_DIR = REPO_ROOT / "solutions"
EXERCISES_DIR = REPO_ROOT / "exercises"
BUILD_DIR = REPO_ROOT / "build"

KERNEL_NAME = "python3"
"""Kernel used everywhere. jupyter_client resolves the native `python3` kernel to the running
interpreter (`sys.executable`), so notebooks run in the same virtual environment as the caller."""

KERNELSPEC = {"name": "python3", "display_name": "Python 3 (ipykernel)", "language": "python"}
"""The kernelspec every committed notebook carries (otter assign needs its `language`)."""

HEADLESS_ENV = {"VTK_DEFAULT_OPENGL_WINDOW": "vtkEGLRenderWindow", "PYVISTA_OFF_SCREEN": "true"}
"""Environment defaults under which pyvista renders static images without a display."""

ASSIGNMENT_CONFIG = {
    "init_cell": True,
    "check_all_cell": False,
    "export_cell": False,
    "generate": False,
    "run_tests": False,
    "solutions_pdf": False,
    "template_pdf": False,
    "show_question_points": True,
    "tests": {"files": False, "ok_format": True},
}
"""Every master's `# ASSIGNMENT CONFIG`, plus `name: <notebook stem>`."""

ANSWER_TAG = "otter_answer_cell"
"""Tag otter puts on the student's answer cells (solution cells with the solution stripped)."""

_SOLUTION_MARKER = re.compile(r"#\s*(BEGIN SOLUTION|END SOLUTION|SOLUTION)\b")
_BLOCK = re.compile(r"#\s+(begin|end)\s+(question|solution|tests|prompt)\b", re.IGNORECASE)
_NONE_CALLS = {"update", "seed"}  # jax.config.update(...), np.random.seed(...): print nothing
_X64_LINE = 'jax.config.update("jax_enable_x64", True)'


def assignment_config_text(name: str) -> str:
    """The exact first cell of a master notebook.

    **Arguments:**

    - `name`: the master's file stem, e.g. `"02_bezier_curves"`.

    **Returns:**

    The source of the raw `# ASSIGNMENT CONFIG` cell.
    """
    body = yaml.safe_dump({"name": name, **ASSIGNMENT_CONFIG}, sort_keys=False)
    return "# ASSIGNMENT CONFIG\n" + body.strip()


def use_headless_defaults() -> None:
    """Set the environment defaults for headless pyvista rendering (existing values win)."""
    for key, value in HEADLESS_ENV.items():
        os.environ.setdefault(key, value)


def notebooks(directory: Path) -> list[Path]:
    """The notebooks `NN_topic.ipynb` directly inside `directory`, sorted by name.

    **Arguments:**

    - `directory`: a folder such as `course/` (it may be missing).

    **Returns:**

    The sorted paths; checkpoints and hidden files are skipped.
    """
    if not directory.is_dir():
        return []
    return sorted(p for p in directory.glob("*.ipynb") if not p.name.startswith("."))


def read_notebook(path: Path) -> nbformat.NotebookNode:
    """Read a notebook as nbformat 4."""
    return nbformat.read(path, as_version=4)


# ----------------------------------------------------------------------------------------------
# Execution


@dataclass(frozen=True)
class CellError:
    """An error raised by one code cell.

    **Arguments:**

    - `index`: the cell's position in the notebook.
    - `ename`, `evalue`: the exception's name and message.
    - `tags`: the cell's tags.
    - `source`: the cell's source.
    """

    index: int
    ename: str
    evalue: str
    tags: tuple[str, ...]
    source: str

    def describe(self) -> str:
        """One line naming the cell and the exception."""
        first = self.source.strip().splitlines()[0] if self.source.strip() else ""
        return f"cell {self.index} ({first[:60]!r}): {self.ename}: {self.evalue[:200]}"


def cell_errors(nb: nbformat.NotebookNode) -> list[CellError]:
    """The errors recorded in an executed notebook's outputs.

    **Arguments:**

    - `nb`: an executed notebook.

    **Returns:**

    One `CellError` per cell with an `error` output, in cell order.
    """
    found = []
    for index, cell in enumerate(nb.cells):
        for output in cell.get("outputs", []):
            if output.get("output_type") == "error":
                tags = tuple(cell.get("metadata", {}).get("tags", []))
                found.append(CellError(index, output["ename"], output["evalue"], tags, cell.source))
                break
    return found


def count_figures(nb: nbformat.NotebookNode) -> int:
    """How many image outputs (matplotlib, pyvista static, ...) an executed notebook shows."""
    count = 0
    for cell in nb.cells:
        for output in cell.get("outputs", []):
            data = output.get("data", {})
            if any(mime.startswith("image/") for mime in data):
                count += 1
    return count


class PollingNotebookClient(NotebookClient):
    """`NotebookClient` that waits for a cell's reply in one-second polls.

    nbclient waits for the shell reply with a single `get_msg(timeout=cell timeout)`.
    After a cell that displays ipywidgets (`interact`) that wait sometimes never wakes up
    although the reply has arrived (jupyter/nbclient#312): the kernel sits idle and the
    run hangs until the cell timeout. A fresh poll sees the waiting message, so polling
    every second makes such runs finish normally.
    """

    async def _async_poll_for_reply(
        self, msg_id, cell, timeout, task_poll_output_msg, task_poll_kernel_alive
    ):
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            try:
                msg = await ensure_async(self.kc.shell_channel.get_msg(timeout=1.0))
            except Empty:
                if deadline is not None and time.monotonic() > deadline:
                    # Out of time: let nbclient check the kernel and raise as it does.
                    return await super()._async_poll_for_reply(
                        msg_id, cell, 0, task_poll_output_msg, task_poll_kernel_alive
                    )
                continue
            if msg["parent_header"].get("msg_id") != msg_id:
                continue
            if self.record_timing:
                cell["metadata"]["execution"]["shell.execute_reply"] = timestamp(msg)
            try:
                await asyncio.wait_for(task_poll_output_msg, self.iopub_timeout)
            except (asyncio.TimeoutError, Empty):
                self.log.warning("Timeout waiting for IOPub output")
            task_poll_kernel_alive.cancel()
            return msg


def make_client(
    nb: nbformat.NotebookNode, cwd: Path, *, timeout: int | None, allow_errors: bool
) -> NotebookClient:
    """An nbclient client on the venv's kernel, working in `cwd`.

    **Arguments:**

    - `nb`: the notebook to execute (modified in place by the client).
    - `cwd`: the kernel's working directory.
    - `timeout`: per-cell time limit in seconds (`None`: no limit).
    - `allow_errors`: whether to carry on after a cell raises.

    **Returns:**

    A `NotebookClient` that kills its kernel immediately when done.
    """
    use_headless_defaults()
    return PollingNotebookClient(
        nb,
        kernel_name=KERNEL_NAME,
        timeout=timeout,
        allow_errors=allow_errors,
        shutdown_kernel="immediate",
        resources={"metadata": {"path": str(cwd)}},
    )


def execute_notebook(
    nb: nbformat.NotebookNode, cwd: Path, *, timeout: int | None = 600, allow_errors: bool = False
) -> float:
    """Execute a notebook top to bottom in one fresh kernel.

    **Arguments:**

    - `nb`: the notebook; outputs are written into it.
    - `cwd`: the kernel's working directory.
    - `timeout`: per-cell time limit in seconds.
    - `allow_errors`: carry on after errors (else the first error raises
      `nbclient.exceptions.CellExecutionError`).

    **Returns:**

    The wall time in seconds, kernel start-up included.
    """
    start = time.perf_counter()
    make_client(nb, cwd, timeout=timeout, allow_errors=allow_errors).execute()
    return time.perf_counter() - start


# ----------------------------------------------------------------------------------------------
# Notebook policy: committed without outputs


def clean_notebook(nb: nbformat.NotebookNode) -> nbformat.NotebookNode:
    """Strip outputs, execution counts and editor state, and set the standard kernelspec.

    **Arguments:**

    - `nb`: a notebook (modified in place).

    **Returns:**

    The same notebook, in the form it is committed in.
    """
    for cell in nb.cells:
        if cell.cell_type == "code":
            cell.outputs = []
            cell.execution_count = None
        for key in ("execution", "collapsed", "scrolled", "ExecuteTime"):
            cell.metadata.pop(key, None)
    nb.metadata.pop("widgets", None)
    nb.metadata["kernelspec"] = dict(KERNELSPEC)
    nb.metadata.setdefault("language_info", {"name": "python"})
    return nb


def policy_problems(nb: nbformat.NotebookNode) -> list[str]:
    """Why a notebook is not in its committed form (empty when it is).

    **Arguments:**

    - `nb`: a notebook as read from disk.

    **Returns:**

    Human-readable problems: outputs, execution counts, widget state, wrong kernelspec.
    """
    problems = []
    try:
        nbformat.validate(nb)
    except nbformat.ValidationError as error:
        problems.append(f"invalid nbformat: {error.message}")
    for index, cell in enumerate(nb.cells):
        if cell.cell_type != "code":
            continue
        if cell.get("outputs"):
            problems.append(f"cell {index} has outputs")
        if cell.get("execution_count") is not None:
            problems.append(f"cell {index} has an execution count")
    if "widgets" in nb.metadata:
        problems.append("notebook metadata holds widget state")
    spec = nb.metadata.get("kernelspec", {})
    if spec.get("name") != KERNELSPEC["name"] or spec.get("language") != "python":
        problems.append(f"kernelspec should be {KERNELSPEC}, got {spec}")
    return problems


# ----------------------------------------------------------------------------------------------
# otter assign


@dataclass(frozen=True)
class Assigned:
    """The notebooks otter assign wrote for one master.

    **Arguments:**

    - `student`: the student notebook (solutions stripped, public tests in its metadata).
    - `autograder`: the autograder notebook (solutions kept, all tests in its metadata).
    """

    student: Path
    autograder: Path


def assign(master: Path, result: Path) -> Assigned:
    """Run otter assign on a master notebook without running its tests.

    **Arguments:**

    - `master`: a master notebook in `solutions/`.
    - `result`: the output folder; otter writes `autograder/` and `student/` into it.

    **Returns:**

    The paths of the two generated notebooks.
    """
    master, result = Path(master).resolve(), Path(result).resolve()
    otter_logger = logging.getLogger("otter")
    level = otter_logger.level
    otter_logger.setLevel(logging.WARNING)
    try:
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)  # traitlets, inside otter
            from otter.assign import main as otter_assign

            otter_assign(str(master), str(result), no_pdfs=True, no_run_tests=True)
    finally:
        otter_logger.setLevel(level)
    return Assigned(result / "student" / master.name, result / "autograder" / master.name)


def otter_tests(nb: nbformat.NotebookNode) -> dict[str, dict[str, Any]]:
    """The OK-format tests otter stored in a generated notebook's metadata, by question."""
    return dict(nb.metadata.get("otter", {}).get("tests", {}))


def _cell_id(cell: nbformat.NotebookNode, seen: dict[str, int]) -> str:
    digest = hashlib.sha1((cell.cell_type + "\n" + cell.source).encode()).hexdigest()[:12]
    seen[digest] = seen.get(digest, 0) + 1
    return digest if seen[digest] == 1 else f"{digest}-{seen[digest]}"


def normalize_exercise(nb: nbformat.NotebookNode) -> nbformat.NotebookNode:
    """Give a generated student notebook content-derived cell ids, so regeneration is byte-stable.

    **Arguments:**

    - `nb`: otter's student notebook (modified in place).

    **Returns:**

    The same notebook, cleaned like every committed notebook.
    """
    seen: dict[str, int] = {}
    for cell in nb.cells:
        cell.id = _cell_id(cell, seen)
    return clean_notebook(nb)


def generate_exercise(master: Path, exercise: Path, build: Path) -> nbformat.NotebookNode:
    """Generate the student version of a master and write it.

    **Arguments:**

    - `master`: `solutions/NN_topic.ipynb`.
    - `exercise`: where to write the student notebook, e.g. `exercises/NN_topic.ipynb`.
    - `build`: folder for otter's output (the autograder with hidden tests stays there).

    **Returns:**

    The student notebook written.
    """
    assigned = assign(master, build)
    nb = normalize_exercise(read_notebook(assigned.student))
    exercise.parent.mkdir(parents=True, exist_ok=True)
    nbformat.write(nb, exercise)
    return nb


def notebook_sources(nb: nbformat.NotebookNode) -> list[tuple[str, str]]:
    """`(cell_type, source)` of every cell: what exercise sync compares (ids are otter's noise)."""
    return [(cell.cell_type, cell.source) for cell in nb.cells]


# ----------------------------------------------------------------------------------------------
# Master format checks


@dataclass
class _Question:
    name: str
    points: Any
    public: int = 0
    hidden: int = 0


def _block(cell: nbformat.NotebookNode) -> tuple[str, str] | None:
    if cell.cell_type != "raw":
        return None
    match = _BLOCK.match(cell.source)
    return (match.group(1).lower(), match.group(2).lower()) if match else None


def _config_problems(nb: nbformat.NotebookNode, name: str) -> list[str]:
    if not nb.cells or nb.cells[0].cell_type != "raw":
        return ["the first cell must be the raw `# ASSIGNMENT CONFIG` cell"]
    source = nb.cells[0].source
    if not source.startswith("# ASSIGNMENT CONFIG"):
        return ["the first cell must start with `# ASSIGNMENT CONFIG`"]
    config = yaml.safe_load(source)
    expected = {"name": name, **ASSIGNMENT_CONFIG}
    if config != expected:
        return [f"ASSIGNMENT CONFIG must be exactly:\n{assignment_config_text(name)}"]
    return []


def _test_problems(source: str, where: str) -> list[str]:
    try:
        tree = ast.parse(source)
    except SyntaxError as error:
        return [f"{where}: syntax error: {error.msg}"]
    return [
        f"{where}: line {node.lineno} is a bare expression; OK-format tests compare printed "
        "output (also inside loops), so write `assert ...` or `_ = ...` instead"
        for node in _echoed_expressions(tree.body)
        if not _is_assert_call(node.value)
    ]


def _echoed_expressions(statements: list[ast.stmt]) -> list[ast.Expr]:
    """Expression statements doctest would print: at top level or in loops, ifs and withs.

    A `try` body is skipped: a call there is expected to raise (`pytest.raises` style)."""
    found = []
    for statement in statements:
        if isinstance(statement, ast.Expr):
            found.append(statement)
        elif not isinstance(statement, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            is_try = isinstance(statement, ast.Try)
            names = ("orelse", "finalbody") if is_try else ("body", "orelse")
            for name in names:
                found += _echoed_expressions(getattr(statement, name, []))
            for handler in getattr(statement, "handlers", []):
                found += _echoed_expressions(handler.body)
    return found


def _is_assert_call(node: ast.expr) -> bool:
    if not isinstance(node, ast.Call):
        return False
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
    return name.startswith("assert") or name in _NONE_CALLS


def _first_code_cell_problems(nb: nbformat.NotebookNode) -> list[str]:
    code = [cell for cell in nb.cells if cell.cell_type == "code"]
    if not code or _X64_LINE not in code[0].source:
        return [f"the first code cell must enable float64: `{_X64_LINE}`"]
    return []


def _scan_blocks(nb: nbformat.NotebookNode) -> tuple[list[_Question], list[str]]:
    questions: list[_Question] = []
    problems: list[str] = []
    stack: list[str] = []
    for index, cell in enumerate(nb.cells[1:], start=1):
        block = _block(cell)
        where = f"cell {index}"
        if block and block[0] == "begin":
            stack.append(block[1])
            if block[1] == "question":
                config = yaml.safe_load(cell.source) or {}
                questions.append(_Question(str(config.get("name")), config.get("points")))
            continue
        if block:
            if stack and stack[-1] == block[1]:
                stack.pop()
            else:
                problems.append(f"{where}: `# END {block[1].upper()}` without a matching BEGIN")
            continue
        problems += _cell_problems(cell, stack, questions, where)
    if stack:
        problems.append(f"unclosed block(s): {', '.join(stack)}")
    return questions, problems


def _cell_problems(
    cell: nbformat.NotebookNode, stack: list[str], questions: list[_Question], where: str
) -> list[str]:
    inside = stack[-1] if stack else None
    has_marker = cell.cell_type == "code" and bool(_SOLUTION_MARKER.search(cell.source))
    if inside == "solution" and cell.cell_type == "code" and not has_marker:
        return [
            f"{where}: a solution cell needs `# BEGIN SOLUTION`/`# END SOLUTION` or `# SOLUTION` "
            "markers (unmarked lines are given to students)"
        ]
    if inside != "solution" and has_marker:
        return [f"{where}: solution markers outside a `# BEGIN SOLUTION` block"]
    if inside != "tests":
        return []
    first = cell.source.lstrip().splitlines()[0] if cell.source.strip() else ""
    hidden = first.startswith("#") and "hidden" in first.lower()
    if hidden and first.strip() != "# HIDDEN":
        return [f"{where}: a hidden test starts with the line `# HIDDEN` exactly"]
    if questions:
        if hidden:
            questions[-1].hidden += 1
        else:
            questions[-1].public += 1
    return _test_problems(cell.source, f"{where} (test of {questions[-1].name})")


def _question_problems(questions: list[_Question]) -> list[str]:
    problems = []
    if not questions:
        problems.append("no questions (`# BEGIN QUESTION` raw cells)")
    for number, question in enumerate(questions, start=1):
        if question.name != f"q{number}":
            problems.append(f"question {number} is named {question.name!r}, expected 'q{number}'")
        points = question.points
        if isinstance(points, bool) or not isinstance(points, int | float) or points <= 0:
            problems.append(f"{question.name}: `points` must be a positive number, got {points!r}")
        if question.public == 0:
            problems.append(f"{question.name}: needs at least one public test")
        if question.hidden == 0:
            problems.append(f"{question.name}: needs at least one hidden test (`# HIDDEN`)")
    return problems


def master_problems(path: Path) -> list[str]:
    """Check a master notebook against the rules of `course/AUTHORING.md`.

    **Arguments:**

    - `path`: a master notebook `solutions/NN_topic.ipynb`.

    **Returns:**

    Human-readable problems (empty when the master follows the rules).
    """
    nb = read_notebook(path)
    problems = _config_problems(nb, Path(path).stem)
    problems += _first_code_cell_problems(nb)
    questions, block_problems = _scan_blocks(nb)
    problems += block_problems + _question_problems(questions)
    if not problems:
        with tempfile.TemporaryDirectory(prefix="diffnurbs-assign-") as tmp:
            try:
                assign(Path(path), Path(tmp))
            except Exception as error:
                problems.append(f"otter assign fails: {type(error).__name__}: {error}")
    return problems


# ----------------------------------------------------------------------------------------------
# Exercise sync and leak checks


def _first_difference(actual: list[tuple[str, str]], expected: list[tuple[str, str]]) -> str:
    for index, (a, e) in enumerate(zip(actual, expected, strict=False)):
        if a != e:
            return f"cell {index} differs: {a[1][:80]!r} != expected {e[1][:80]!r}"
    return f"{len(actual)} cells, expected {len(expected)}"


def exercise_drift(master: Path, exercise: Path) -> list[str]:
    """How a committed exercise differs from what its master generates now.

    Compares cell types and sources and the otter metadata (public tests, assignment name);
    cell ids are ignored.

    **Arguments:**

    - `master`: `solutions/NN_topic.ipynb`.
    - `exercise`: the committed `exercises/NN_topic.ipynb`.

    **Returns:**

    Human-readable differences (empty when in sync).
    """
    if not exercise.exists():
        return [f"{exercise} is missing"]
    with tempfile.TemporaryDirectory(prefix="diffnurbs-sync-") as tmp:
        expected = generate_exercise(master, Path(tmp) / master.name, Path(tmp) / "build")
    actual = read_notebook(exercise)
    drift = []
    if notebook_sources(actual) != notebook_sources(expected):
        drift.append(_first_difference(notebook_sources(actual), notebook_sources(expected)))
    if actual.metadata.get("otter") != expected.metadata.get("otter"):
        drift.append("the otter metadata (public tests or assignment name) differs")
    return drift


def _key_lines(code: str) -> set[str]:
    lines = set()
    for line in code.splitlines():
        line = re.sub(r"^(>>>|\.\.\.) ?", "", line.strip()).strip()
        if line and not line.startswith(("#", "import ", "from ")):
            lines.add(line)
    return lines


def hidden_cases(nb: nbformat.NotebookNode) -> list[str]:
    """The code of every hidden test case in a generated notebook's otter metadata."""
    return [
        case["code"]
        for spec in otter_tests(nb).values()
        for suite in spec.get("suites", [])
        for case in suite.get("cases", [])
        if case.get("hidden")
    ]


def _notebook_leaks(path: Path, hidden: list[set[str]]) -> list[str]:
    nb = read_notebook(path)
    leaks = [f"{path}: hidden test in the notebook metadata" for _ in hidden_cases(nb)]
    for index, cell in enumerate(nb.cells):
        lines = {line.strip() for line in cell.source.splitlines()}
        if any(key and key <= lines for key in hidden):
            leaks.append(f"{path}: cell {index} contains a hidden test")
        if "# HIDDEN" in cell.source or _SOLUTION_MARKER.search(cell.source):
            leaks.append(f"{path}: cell {index} contains a `# HIDDEN` or solution marker")
    return leaks


def hidden_test_leaks(exercises: Path, solutions: Path) -> list[str]:
    """Look for hidden tests (and anything that is not a student notebook) under `exercises`.

    **Arguments:**

    - `exercises`: the folder of student notebooks.
    - `solutions`: the folder of masters whose hidden tests must not appear there.

    **Returns:**

    Human-readable leaks (empty when there are none).
    """
    hidden: list[set[str]] = []
    with tempfile.TemporaryDirectory(prefix="diffnurbs-hidden-") as tmp:
        for master in notebooks(solutions):
            autograder = read_notebook(assign(master, Path(tmp) / master.stem).autograder)
            hidden += [_key_lines(code) for code in hidden_cases(autograder)]
    leaks = []
    for path in sorted(p for p in exercises.rglob("*") if p.is_file()):
        if any(part.startswith(".") for part in path.relative_to(exercises).parts):
            continue  # .OTTER_LOG, .ipynb_checkpoints/: the student's local state, git-ignored
        if path.suffix != ".ipynb" or path.parent != exercises:
            leaks.append(f"{path}: only student notebooks belong under {exercises}")
        else:
            leaks += _notebook_leaks(path, hidden)
    return leaks
