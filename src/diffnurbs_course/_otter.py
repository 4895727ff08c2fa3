"""otter-grader's conventions as the course uses them: the assignment config, otter assign, tests,
and otter's own autograder zip (for grading services such as Gradescope).

The conventions are written down for chapter authors in `course/AUTHORING.md`.
"""

from __future__ import annotations

import contextlib
import io
import logging
import re
import shutil
import sys
import tempfile
import warnings
from dataclasses import dataclass
from importlib.metadata import version
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


AUTOGRADER_SOURCE = "/autograder/source"
"""Where a grading service (Gradescope) unpacks an autograder zip; its files are in `files/`."""


def autograder_zip(master: Path, out_dir: Path, *, wheel: Path | None = None) -> Path:
    """Build otter's own autograder zip of a master, for `otter run` or Gradescope.

    otter assign runs on a copy of the master whose assignment config says `generate:`, so the
    zip holds the same tests as `diffnurbs-grade` uses (hidden ones included), an
    `environment.yml` for the venv's Python with `diffnurbs[course]` added to otter's
    requirements, and otter's `setup.sh` / `run_autograder` for the grading service.

    **Arguments:**

    - `master`: a master notebook in `solutions/`.
    - `out_dir`: the folder to write `<master stem>-autograder.zip` into (created if needed).
    - `wheel`: a diffnurbs wheel to ship inside the zip and install from there; without it the
        grading service installs `diffnurbs[course]` of this version from its package index.

    **Returns:**

    The zip's path.
    """
    master = Path(master).resolve()
    if master.suffix != ".ipynb" or not master.is_file():
        raise ValueError(f"master must be an existing .ipynb file, got {master}")
    nb = nbformat.read(master, as_version=4)
    header = "# ASSIGNMENT CONFIG\n"
    if not nb.cells or not nb.cells[0].source.startswith(header):
        raise ValueError(
            f"{master.name}: the first cell must be the raw '# ASSIGNMENT CONFIG' cell"
        )
    config = yaml.safe_load(nb.cells[0].source[len(header) :])
    requirement = f"diffnurbs[course]=={version('diffnurbs')}"
    if wheel is not None:
        wheel = Path(wheel).resolve()
        if wheel.suffix != ".whl" or not wheel.name.startswith("diffnurbs-") or not wheel.is_file():
            raise ValueError(f"wheel must be an existing diffnurbs-*.whl file, got {wheel}")
        requirement = f"diffnurbs[course] @ file://{AUTOGRADER_SOURCE}/files/{wheel.name}"
        config["autograder_files"] = [wheel.name]
    config.update(
        generate=True,
        requirements=[requirement],
        python_version=f"{sys.version_info.major}.{sys.version_info.minor}",
    )
    nb.cells[0].source = header + yaml.safe_dump(config, sort_keys=False).strip()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / f"{master.stem}-autograder.zip"
    with tempfile.TemporaryDirectory(prefix="diffnurbs-zip-") as tmp:
        copy = Path(tmp) / master.name
        nbformat.write(nb, copy)
        if wheel is not None:
            shutil.copyfile(wheel, Path(tmp) / wheel.name)
        assign(copy, Path(tmp) / "dist")
        (built,) = (Path(tmp) / "dist" / "autograder").glob("*.zip")
        shutil.move(built, target)
    return target


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
