"""The scores table `file, q1, ..., total, max, flags` and the progress line of a batch."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

from ._grading import GradeResult


def _number(value: float) -> str:
    return f"{round(value, 4):g}"


def question_columns(results: Sequence[GradeResult]) -> list[str]:
    """The question columns of a batch: every question of every matched master, first seen first."""
    columns: list[str] = []
    for result in results:
        columns += [q for q in result.possible if q not in columns]
    return columns


def write_csv(results: Sequence[GradeResult], path: Path) -> None:
    """Write the scores table `file, q1, ..., total, max, flags`.

    A question cell is blank where the question does not apply; `flags` holds the result's
    flags joined by `"; "` (blank when there are none).

    **Arguments:**

    - `results`: the graded notebooks.
    - `path`: the CSV file to write.
    """
    questions = question_columns(results)
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.writer(f)
        writer.writerow(["file", *questions, "total", "max", "flags"])
        for r in results:
            cells = [_number(r.scores[q]) if q in r.scores else "" for q in questions]
            maximum = _number(r.max_points) if r.master else ""
            writer.writerow([r.file, *cells, _number(r.total), maximum, "; ".join(r.flags)])


def print_progress(done: int, total: int, result: GradeResult) -> None:
    """Print one line per graded notebook: `[3/40] file: 7.5/10 (21 s) 2 flags  [notes]`.

    **Arguments:**

    - `done`, `total`: how many notebooks are graded, out of how many.
    - `result`: the notebook just graded.
    """
    score = f"{_number(result.total)}/{_number(result.max_points)}" if result.master else "-"
    count = len(result.flags)
    flags = f" {count} flag{'s' if count > 1 else ''}" if count else ""
    notes = f"  [{'; '.join(result.notes)}]" if result.notes else ""
    line = f"[{done}/{total}] {result.file}: {score} ({result.seconds:.0f} s){flags}{notes}"
    print(line, flush=True)
