"""How a chapter reads: the measures of the chapter template (`course/AUTHORING.md`).

Visible code against prose, visible asserts, long visible cells, links and anchors that
resolve, Markdown tables whose rows all have the header's columns, and (for an executed
chapter) warning or error text in the outputs. Cells tagged `check` are the folded checks:
they count as neither visible code nor visible asserts.
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass, field
from pathlib import Path

import nbformat

from ._notebooks import read_notebook

CHECK_TAG = "check"
"""The tag of a folded check cell: executed by the tests, hidden on the site."""

LIMITS = {"asserts": 5, "longest_cell": 40}
"""Most visible asserts per chapter, and most lines in one visible code cell."""

_LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)")
_WARNING = re.compile(r"\b(Warning|Error|Traceback)\b")


@dataclass
class ChapterMetrics:
    """The template's measures for one chapter; `problems` lists what breaks a limit."""

    name: str
    prose_lines: int = 0
    code_lines: int = 0
    check_lines: int = 0
    asserts: int = 0
    longest_cell: int = 0
    problems: list[str] = field(default_factory=list)


def _lines(source: str) -> list[str]:
    return [line for line in source.splitlines() if line.strip()]


def _tags(cell: nbformat.NotebookNode) -> set[str]:
    return set(cell.get("metadata", {}).get("tags", []))


def _count_asserts(source: str) -> int:
    try:
        tree = ast.parse(source)
    except SyntaxError:  # IPython magics: count the assert lines instead
        return sum(line.lstrip().startswith("assert ") for line in source.splitlines())
    return sum(isinstance(node, ast.Assert) for node in ast.walk(tree))


def jupyter_anchor(heading: str) -> str:
    """The anchor JupyterLab gives a Markdown heading: its text, spaces made `-`, case kept
    (the course site makes the same, so links between chapters work in both)."""
    return heading.strip().replace(" ", "-")


def heading_anchors(nb: nbformat.NotebookNode) -> set[str]:
    """The `#anchors` of a notebook's Markdown headings (`jupyter_anchor`)."""
    anchors = set()
    for cell in nb.cells:
        if cell.cell_type != "markdown":
            continue
        for line in cell.source.splitlines():
            match = re.match(r"#+\s+(.*)", line)
            if match:
                anchors.add(jupyter_anchor(match.group(1)))
    return anchors


def _link_problems(nb: nbformat.NotebookNode, path: Path) -> list[str]:
    problems = []
    for cell in nb.cells:
        if cell.cell_type != "markdown":
            continue
        for target in _LINK.findall(cell.source):
            if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
                continue
            file, _, anchor = target.partition("#")
            linked = (path.parent / file).resolve() if file else path
            if not linked.exists():
                problems.append(f"link to {target}: no file {linked}")
            elif (
                anchor
                and linked.suffix == ".ipynb"
                and anchor not in heading_anchors(read_notebook(linked))
            ):
                problems.append(f"link to {target}: no heading with that anchor")
    return problems


def _table_problems(source: str) -> list[str]:
    """Rows of a Markdown table with another number of cells than its header (a `|` in a
    cell, as in `$|x|$`, must be written `\\|`)."""
    problems, columns = [], None
    for line in source.splitlines():
        stripped = line.strip()
        if not stripped.startswith("|"):
            columns = None
            continue
        cells = len(re.split(r"(?<!\\)\|", stripped.strip("|")))
        if columns is None:
            columns = cells
        elif cells != columns:
            problems.append(f"table row with {cells} cells under a {columns}-cell header: {line!r}")
    return problems


def _output_problems(executed: nbformat.NotebookNode) -> list[str]:
    problems = []
    for index, cell in enumerate(executed.cells):
        for output in cell.get("outputs", []):
            text = output.get("text", "") if output.get("output_type") == "stream" else ""
            if output.get("output_type") == "error" or output.get("name") == "stderr":
                problems.append(f"cell {index}: error or stderr output")
            elif _WARNING.search(text):
                problems.append(f"cell {index}: warning text in the output")
    return problems


def chapter_metrics(path: Path, executed: nbformat.NotebookNode | None = None) -> ChapterMetrics:
    """Measure one chapter against the template's limits.

    **Arguments:**

    - `path`: the chapter notebook (links resolve from its folder).
    - `executed`: the same notebook with outputs, to check them; None skips the outputs.

    **Returns:**

    The `ChapterMetrics`, with every broken limit in `problems`.
    """
    nb = read_notebook(path)
    metrics = ChapterMetrics(path.stem)
    for index, cell in enumerate(nb.cells):
        lines = _lines(cell.source)
        if cell.cell_type == "markdown":
            metrics.prose_lines += len(lines)
            metrics.problems += [f"cell {index}: {p}" for p in _table_problems(cell.source)]
        elif cell.cell_type == "code" and CHECK_TAG in _tags(cell):
            metrics.check_lines += len(lines)
        elif cell.cell_type == "code":
            metrics.code_lines += len(lines)
            metrics.asserts += _count_asserts(cell.source)
            metrics.longest_cell = max(metrics.longest_cell, len(lines))
    if metrics.code_lines > metrics.prose_lines:
        metrics.problems.append(
            f"{metrics.code_lines} visible code lines, more than {metrics.prose_lines} of prose"
        )
    for key, limit in LIMITS.items():
        if getattr(metrics, key) > limit:
            metrics.problems.append(f"{key} = {getattr(metrics, key)} > {limit}")
    metrics.problems += _link_problems(nb, path)
    if executed is not None:
        metrics.problems += _output_problems(executed)
    return metrics


def course_report(metrics: list[ChapterMetrics]) -> str:
    """A Markdown table of the chapters' measures, then each chapter's problems."""
    rows = [
        "| chapter | prose lines | visible code lines | check lines | visible asserts "
        "| longest visible cell | problems |",
        "|---|---|---|---|---|---|---|",
    ]
    rows += [
        f"| {m.name} | {m.prose_lines} | {m.code_lines} | {m.check_lines} | {m.asserts} "
        f"| {m.longest_cell} | {len(m.problems)} |"
        for m in metrics
    ]
    details = [
        f"\n## {m.name}\n\n" + "\n".join(f"- {p}" for p in m.problems)
        for m in metrics
        if m.problems
    ]
    return "# Course report\n\n" + "\n".join(rows) + "\n" + "".join(details) + "\n"
