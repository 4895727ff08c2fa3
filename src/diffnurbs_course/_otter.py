"""otter-grader's conventions as the course uses them: the assignment config, otter assign, tests.

The conventions are written down for chapter authors in `course/AUTHORING.md`.
"""

from __future__ import annotations

import contextlib
import io
import logging
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import nbformat
import yaml

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

SOLUTION_MARKER = re.compile(r"#\s*(BEGIN SOLUTION|END SOLUTION|SOLUTION)\b")
"""Matches otter's solution markers, which never belong in a student notebook."""


def assignment_config_text(name: str) -> str:
    """The exact first cell of a master notebook.

    **Arguments:**

    - `name`: the master's file stem, e.g. `"02_bezier_curves"`.

    **Returns:**

    The source of the raw `# ASSIGNMENT CONFIG` cell.
    """
    body = yaml.safe_dump({"name": name, **ASSIGNMENT_CONFIG}, sort_keys=False)
    return "# ASSIGNMENT CONFIG\n" + body.strip()


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


def hidden_cases(nb: nbformat.NotebookNode) -> list[str]:
    """The code of every hidden test case in a generated notebook's otter metadata."""
    return [
        case["code"]
        for spec in otter_tests(nb).values()
        for suite in spec.get("suites", [])
        for case in suite.get("cases", [])
        if case.get("hidden")
    ]
