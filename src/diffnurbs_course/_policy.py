"""The authoring rules a master notebook must follow (`course/AUTHORING.md`)."""

from __future__ import annotations

import ast
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import nbformat
import yaml

from ._notebooks import read_notebook
from ._otter import ASSIGNMENT_CONFIG, SOLUTION_MARKER, assign, assignment_config_text

_BLOCK = re.compile(r"#\s+(begin|end)\s+(question|solution|tests|prompt)\b", re.IGNORECASE)
_NONE_CALLS = {"update", "seed"}  # jax.config.update(...), np.random.seed(...): print nothing
_X64_LINE = 'jax.config.update("jax_enable_x64", True)'


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


def problems_in_test_code(source: str, where: str) -> list[str]:
    """Statements of an OK-format test that print, and so break the test (doctest compares output).

    **Arguments:**

    - `source`: the code of one test cell.
    - `where`: how problems name the cell, e.g. `"cell 7 (test of q1)"`.

    **Returns:**

    One problem per expression statement doctest would echo (at top level, or inside loops,
    `if` and `with`; a `try` body and calls to `assert...`, `update` or `seed` are fine), or the
    syntax error.
    """
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
    has_marker = cell.cell_type == "code" and bool(SOLUTION_MARKER.search(cell.source))
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
    return problems_in_test_code(cell.source, f"{where} (test of {questions[-1].name})")


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
