"""Masters as the grader sees them: tests and points per question, and which one a file answers."""

from __future__ import annotations

import tempfile
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from pprint import pformat
from typing import Any

import nbformat

from ._flags import handed_out_code
from ._notebooks import notebooks, read_notebook
from ._otter import assign, otter_tests


@dataclass(frozen=True)
class Master:
    """The grading view of one master notebook.

    **Arguments:**

    - `name`: the master's stem, e.g. `"02_bezier_curves"`.
    - `tests`: OK-format test specs by question (public and hidden cases), in question order.
    - `possible`: the points of each question.
    - `init`: the source of the master's code cells before its first question (its imports
      and the helpers its tests use), where the grader runs the tests (`Scorer`).
    - `handed_out`: the code the student's notebook is given (`handed_out_code`), which
      `submission_flags` does not scan.
    """

    name: str
    tests: dict[str, dict[str, Any]]
    possible: dict[str, float]
    init: str = ""
    handed_out: tuple[str, ...] = ()

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
        assigned = assign(Path(path), Path(tmp))
        tests = otter_tests(read_notebook(assigned.autograder))
        handed_out = tuple(handed_out_code(read_notebook(assigned.student)))
    possible = {q: float(OKTestFile.from_spec(spec).possible) for q, spec in tests.items()}
    return Master(Path(path).stem, tests, possible, init_source(read_notebook(path)), handed_out)


def init_source(nb: nbformat.NotebookNode) -> str:
    """The code cells of a master before its first `# BEGIN QUESTION` cell, joined.

    **Arguments:**

    - `nb`: the master notebook.

    **Returns:**

    Their source, one cell after the other.
    """
    sources = []
    for cell in nb.cells:
        if cell.cell_type == "raw" and cell.source.lstrip().startswith("# BEGIN QUESTION"):
            break
        if cell.cell_type == "code":
            sources.append(cell.source)
    return "\n\n".join(sources)


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
        p.stem: load_master(p) for p in notebooks(solutions) if wanted is None or p.stem in wanted
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
        otter = nb.metadata.get("otter")
        # The metadata is the student's: any type may be there.
        assignment = otter.get("assignment_name") if isinstance(otter, dict) else None
        if isinstance(assignment, str) and assignment in names:
            return assignment
    if path.stem in names:
        return path.stem
    contained = [name for name in names if name in path.name]
    return max(contained, key=len) if contained else None
