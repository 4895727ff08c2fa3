"""Where a course's folders are: every path comes from the caller, none from this package."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ._notebooks import notebooks


def _folder(name: str, doc: str) -> property:
    return property(lambda layout: Path(layout.root) / name, doc=doc)


@dataclass(frozen=True)
class CourseLayout:
    """The folders of a course repository such as this one.

    **Arguments:**

    - `root`: the folder holding `course/`, `solutions/`, `exercises/` (and `build/`).
    """

    root: Path

    course = _folder("course", "The chapters, `root/course`.")
    solutions = _folder("solutions", "The exercise masters, `root/solutions`.")
    exercises = _folder("exercises", "The generated student notebooks, `root/exercises`.")
    build = _folder("build", "Generated files that are not committed, `root/build`.")


def find_solutions(course: Path | None = None, cwd: Path | None = None) -> Path:
    """The folder of master notebooks to use when none is given.

    **Arguments:**

    - `course`: a course folder holding `solutions/` (when given, only it is looked at).
    - `cwd`: the folder to look in otherwise (default: the current working directory).

    **Returns:**

    `course/solutions`, else `cwd/solutions`: the one looked at, if it holds masters
    (`NN_topic.ipynb`).

    **Raises:**

    `FileNotFoundError` naming the folder looked for when it holds no master notebook.
    """
    base = Path(course) if course is not None else Path.cwd() if cwd is None else Path(cwd)
    candidate = base / "solutions"
    if notebooks(candidate):
        return candidate
    state = "holds no *.ipynb" if candidate.is_dir() else "does not exist"
    raise FileNotFoundError(
        f"no master notebooks found: looked for {candidate.absolute()}/*.ipynb ({state}); "
        "pass --solutions DIR, or --course DIR for a course folder that contains solutions/"
    )
