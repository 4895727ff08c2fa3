"""Grading a folder of submissions, each matched to its master."""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import nbformat

from ._grading import DEFAULT_TIMEOUT, GradeResult, grade_notebook
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


def _grade_one(path: Path, label: str, master: Master | None, timeout: float) -> GradeResult:
    if master is None:
        return GradeResult(label, None, notes=["no master in the solutions folder matches it"])
    try:
        result = grade_notebook(path, master, timeout=timeout, label=label)
    except Exception as error:  # the grader's own failure: report it, grade the rest
        result = GradeResult(label, master.name, dict.fromkeys(master.questions, 0.0))
        result.possible = dict(master.possible)
        result.notes.append(f"grading failed: {type(error).__name__}: {error}")
    result.executed = None
    return result


def grade_directory(
    submissions: Path,
    solutions: Path,
    *,
    timeout: float = DEFAULT_TIMEOUT,
    jobs: int = 1,
    progress: Callable[[int, int, GradeResult], None] | None = None,
) -> list[GradeResult]:
    """Grade every notebook under a folder.

    **Arguments:**

    - `submissions`: the folder of submitted notebooks (searched recursively).
    - `solutions`: the folder of masters.
    - `timeout`: seconds each submission's cells may run together.
    - `jobs`: how many notebooks to grade at once.
    - `progress`: called as `progress(done, total, result)` after each notebook.

    **Returns:**

    One `GradeResult` per notebook, in file order.
    """
    paths = find_submissions(submissions)
    names = [p.stem for p in notebooks(solutions)]
    matched = {p: match_master(p, _peek(p), names) for p in paths}
    masters = load_masters(solutions, {m for m in matched.values() if m})
    tasks = [
        (p, str(p.relative_to(submissions)), masters.get(matched[p] or ""), timeout) for p in paths
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
    return [results[i] for i in range(len(tasks))]
