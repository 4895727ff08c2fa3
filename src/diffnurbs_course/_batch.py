"""Grading a folder of submissions, each matched to its master."""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import nbformat

from ._flags import batch_flags
from ._grading import GradeResult, grade_notebook
from ._masters import Master, load_masters, match_master
from ._notebooks import notebooks, read_notebook


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
        return read_notebook(path)
    except Exception:
        return None


def _match(path: Path, names: list[str]) -> tuple[str | None, str | None]:
    """The master a file answers and, when it cannot be told, why (never raises)."""
    if path.is_symlink():  # it could point at a file of the teacher's: never read it
        return None, "a symbolic link: not graded"
    try:
        return match_master(path, _peek(path), names), None
    except Exception as error:
        return None, f"could not be matched to a master: {type(error).__name__}: {error}"


def _grade_one(
    path: Path, label: str, master: Master | None, why: str | None, options: dict[str, Any]
) -> GradeResult:
    if master is None:
        return GradeResult(
            label, None, notes=[why or "no master in the solutions folder matches it"]
        )
    try:
        result = grade_notebook(path, master, label=label, **options)
    except Exception as error:  # the grader's own failure: report it, grade the rest
        result = GradeResult(label, master.name, dict.fromkeys(master.questions, 0.0))
        result.possible = dict(master.possible)
        result.notes.append(f"grading failed: {type(error).__name__}: {str(error)[:2000]}")
    result.executed = None
    return result


def grade_directory(
    submissions: Path,
    solutions: Path,
    *,
    jobs: int = 1,
    progress: Callable[[int, int, GradeResult], None] | None = None,
    **options: Any,
) -> list[GradeResult]:
    """Grade every notebook under a folder.

    **Arguments:**

    - `submissions`: the folder of submitted notebooks (searched recursively).
    - `solutions`: the folder of masters.
    - `jobs`: how many notebooks to grade at once.
    - `progress`: called as `progress(done, total, result)` after each notebook.
    - `options`: passed to `grade_notebook` (`timeout`, `cell_timeout`, `check_timeout`,
      `limits`).

    **Returns:**

    One `GradeResult` per notebook, in file order, with the batch's flags (`batch_flags`).
    """
    paths = find_submissions(submissions)
    names = [p.stem for p in notebooks(solutions)]
    matched = {p: _match(p, names) for p in paths}
    masters = load_masters(solutions, {m for m, _ in matched.values() if m})
    tasks = [
        (
            p,
            str(p.relative_to(submissions)),
            masters.get(matched[p][0] or ""),
            matched[p][1],
            options,
        )
        for p in paths
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
    ordered = [results[i] for i in range(len(tasks))]
    batch_flags(ordered)
    return ordered
