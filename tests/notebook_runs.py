"""One execution per notebook per test run, shared by the notebook and grading tests.

`test_notebooks.py` (does it run?) and `test_dc.py` (does it score?) look at the same
grading run of each master and exercise. Under pytest-xdist they may land on different workers,
so runs are cached in a folder shared by the whole run, behind a per-notebook file lock: the
first test executes the notebook, the other reads the result.

Each run's wall time also goes into `build/notebook_times.md` (a measurement, not a limit).
"""

from __future__ import annotations

import fcntl
import json
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

import diffnurbs_course as dc

GRADING_TIMEOUT = 900
"""Generous limit for the course's own notebooks: a hang fails the test instead of blocking CI."""

ROOT = Path(__file__).resolve().parents[1]
"""The repository root."""

LAYOUT = dc.CourseLayout(ROOT)
"""The repository's course folders."""

TIMES_TABLE = LAYOUT.build / "notebook_times.md"


COURSE = dc.notebooks(LAYOUT.course)
"""The chapters. `test_browser.py` runs each in JupyterLab in Chromium, where students meet
them, and checks the saved notebook; they are not also run headless."""


COMPILE_CACHE = Path(os.environ["JAX_COMPILATION_CACHE_DIR"])
"""The suite's JAX compilation cache (conftest.py), shared with the sandboxed kernels of the
course's own masters and exercises: trusted notebooks, which otherwise compile cold."""
COMPILE_CACHE.mkdir(parents=True, exist_ok=True)


def shared_dir(tmp_path_factory) -> Path:
    """A folder shared by every worker of this pytest run (and only this run).

    **Arguments:**

    - `tmp_path_factory`: pytest's fixture.

    **Returns:**

    The folder: the run's base temp directory (the parent of the workers' ones under xdist).
    """
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    path = root / "notebook-runs"
    path.mkdir(exist_ok=True)
    return path


@contextmanager
def locked(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on `path` (created if needed) across processes."""
    with open(path, "a+") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _key(path: Path) -> str:
    return f"{path.parent.name}-{path.stem}"


def graded(path: Path, master: Path, shared: Path) -> dc.GradeResult:
    """The grading run of a notebook against a master, executed once per test run.

    **Arguments:**

    - `path`: the notebook to grade (a master itself, or an exercise).
    - `master`: its master notebook.
    - `shared`: `shared_dir(...)`.

    **Returns:**

    The `GradeResult` (without the executed notebook).
    """
    cache = shared / f"{_key(path)}.json"
    with locked(shared / f"{_key(path)}.lock"):
        if cache.exists():
            return dc.GradeResult.from_json(json.loads(cache.read_text()))
        result = dc.grade_notebook(
            path,
            dc.load_master(master),
            timeout=GRADING_TIMEOUT,
            label=str(path),
            compile_cache=COMPILE_CACHE,
        )
        result.executed = None
        cache.write_text(json.dumps(result.to_json()))
    record_time(shared, path, result.seconds, "graded")
    return result


def record_time(shared: Path, path: Path, seconds: float, how: str) -> None:
    """Add a notebook's wall time to this run's table in `build/notebook_times.md`.

    **Arguments:**

    - `shared`: `shared_dir(...)`.
    - `path`: the notebook.
    - `seconds`: its wall time, kernel start-up included.
    - `how`: `"executed"`, `"graded"` (graded runs include the tests) or `"browser"`.
    """
    rows = shared / "times"
    rows.mkdir(exist_ok=True)
    row = {"notebook": str(path.relative_to(ROOT)), "seconds": seconds, "how": how}
    (rows / f"{_key(path)}.json").write_text(json.dumps(row))
    with locked(shared / "times.lock"):
        _write_table([json.loads(p.read_text()) for p in sorted(rows.glob("*.json"))])


def _write_table(rows: list[dict]) -> None:
    lines = [
        "# Notebook wall times",
        "",
        f"Last `pytest` run, {time.strftime('%Y-%m-%d %H:%M')}; kernel start-up included; "
        "*graded* runs include the hidden tests.",
        "",
        "| notebook | seconds | run |",
        "|---|---:|---|",
    ]
    lines += [f"| {r['notebook']} | {r['seconds']:.1f} | {r['how']} |" for r in rows]
    lines += ["", f"Total: {sum(r['seconds'] for r in rows):.0f} s over {len(rows)} notebooks."]
    TIMES_TABLE.parent.mkdir(parents=True, exist_ok=True)
    tmp = TIMES_TABLE.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text("\n".join(lines) + "\n")
    os.replace(tmp, TIMES_TABLE)


DEMO_MASTER = Path(__file__).parent / "data" / "solutions" / "99_demo.ipynb"


def answered(master: Path, work: Path):
    """A student notebook of `master` with every answer cell filled in with the solution.

    **Arguments:**

    - `master`: a master notebook.
    - `work`: a scratch folder.

    **Returns:**

    The notebook (what a student who solved everything hands in).
    """
    assigned = dc.assign(master, work / "assigned")
    student = dc.read_notebook(assigned.student)
    solved = dc.read_notebook(assigned.autograder)
    assert len(student.cells) == len(solved.cells), "answers must be code cells"
    for cell, solution in zip(student.cells, solved.cells, strict=True):
        if dc.ANSWER_TAG in cell.metadata.get("tags", []):
            cell.source = solution.source
    return dc.normalize_exercise(student)


def graded_exercise(exercise: Path, shared: Path) -> dc.GradeResult:
    """The grading run of a committed exercise against its master, which must exist.

    **Arguments:**

    - `exercise`: `exercises/NN_topic.ipynb`.
    - `shared`: `shared_dir(tmp_path_factory)`.

    **Returns:**

    The grading result.
    """
    master = LAYOUT.solutions / exercise.name
    if not master.exists():
        pytest.fail(f"{exercise.relative_to(ROOT)} has no master {master.relative_to(ROOT)}")
    return graded(exercise, master, shared)
