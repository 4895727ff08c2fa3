"""Student notebooks: generated from the masters, in sync with them, free of hidden tests."""

from __future__ import annotations

import hashlib
import re
import tempfile
from pathlib import Path

import nbformat

from ._feedback import ANSWERS_KEY, NOT_ANSWERED, answer_names
from ._notebooks import clean_notebook, notebooks, read_notebook
from ._otter import ANSWER_TAG, SOLUTION_MARKER, assign, hidden_cases


def _cell_id(cell: nbformat.NotebookNode, seen: dict[str, int]) -> str:
    digest = hashlib.sha1((cell.cell_type + "\n" + cell.source).encode()).hexdigest()[:12]
    seen[digest] = seen.get(digest, 0) + 1
    return digest if seen[digest] == 1 else f"{digest}-{seen[digest]}"


_OTTER_INIT = re.compile(r'# Initialize Otter\nimport otter\ngrader = otter\.Notebook\(("[^"]+")\)')
_STUB = re.compile(r"^(\s+)\.\.\.$", flags=re.M)
_CHECK = re.compile(r'grader\.check\("([^"]+)"\)')


def _first_cell_sets_up(nb: nbformat.NotebookNode) -> None:
    """One code cell, after the title, holds the set-up and the grader: running it is all
    that `grader.check` needs (otter puts its own cell first and the master's set-up later)."""
    inits = [c for c in nb.cells if c.cell_type == "code" and _OTTER_INIT.fullmatch(c.source)]
    answers = [i for i, c in enumerate(nb.cells) if ANSWER_TAG in c.metadata.get("tags", [])]
    if len(inits) != 1 or not answers:
        raise ValueError(
            f"expected otter's student notebook: one init cell (found {len(inits)}) and answer "
            f"cells (found {len(answers)}); does the master have `init_cell: true` and questions?"
        )
    init, first_question = inits[0], answers[0]
    setup = [c for c in nb.cells[:first_question] if c.cell_type == "code" and c is not init]
    grader = (
        "from diffnurbs_course import Notebook\n\n"
        f'grader = Notebook({_OTTER_INIT.fullmatch(init.source)[1]})  # grader.check("q1")'
    )
    init.source = "\n\n".join([*(c.source for c in setup), grader])
    nb.cells = [c for c in nb.cells if c is not init and not any(c is s for s in setup)]
    title = next(i for i, c in enumerate(nb.cells) if c.cell_type == "markdown")
    nb.cells.insert(title + 1, init)


def normalize_exercise(nb: nbformat.NotebookNode) -> nbformat.NotebookNode:
    """Shape a generated student notebook as the course hands it out, byte-stable.

    The set-up and the grader go into one code cell after the title; a function body left
    as `...` raises `NotImplementedError("not answered yet")`, nbgrader's convention, and the
    names each question's answer defines go into the metadata: the checks then report an
    unanswered question as such (`Feedback`); cells get content-derived ids.

    **Arguments:**

    - `nb`: otter's student notebook (modified in place).

    **Returns:**

    The same notebook, cleaned like every committed notebook.
    """
    _first_cell_sets_up(nb)
    answers: dict[str, list[str]] = {}
    names: list[str] = []
    for cell in nb.cells:
        if ANSWER_TAG in cell.metadata.get("tags", []):
            cell.source = _STUB.sub(rf'\1raise NotImplementedError("{NOT_ANSWERED}")', cell.source)
            names += answer_names(cell.source)
        elif check := _CHECK.fullmatch(cell.source.strip()):
            answers[check[1]], names = names, []
    nb.metadata[ANSWERS_KEY] = answers
    seen: dict[str, int] = {}
    for cell in nb.cells:
        cell.id = _cell_id(cell, seen)
    return clean_notebook(nb)


def generate_exercise(master: Path, exercise: Path, build: Path) -> nbformat.NotebookNode:
    """Generate the student version of a master and write it.

    **Arguments:**

    - `master`: `solutions/NN_topic.ipynb`.
    - `exercise`: where to write the student notebook, e.g. `exercises/NN_topic.ipynb`.
    - `build`: folder for otter's output (the autograder with hidden tests stays there).

    **Returns:**

    The student notebook written.
    """
    assigned = assign(master, build)
    nb = normalize_exercise(read_notebook(assigned.student))
    exercise.parent.mkdir(parents=True, exist_ok=True)
    nbformat.write(nb, exercise)
    return nb


def notebook_sources(nb: nbformat.NotebookNode) -> list[tuple[str, str]]:
    """`(cell_type, source)` of every cell: what exercise sync compares (ids are otter's noise)."""
    return [(cell.cell_type, cell.source) for cell in nb.cells]


def _first_difference(actual: list[tuple[str, str]], expected: list[tuple[str, str]]) -> str:
    for index, (a, e) in enumerate(zip(actual, expected, strict=False)):
        if a != e:
            return f"cell {index} differs: {a[1][:80]!r} != expected {e[1][:80]!r}"
    return f"{len(actual)} cells, expected {len(expected)}"


def exercise_drift(master: Path, exercise: Path) -> list[str]:
    """How a committed exercise differs from what its master generates now.

    Compares cell types and sources, the otter metadata (public tests, assignment name) and
    the answers' names; cell ids are ignored.

    **Arguments:**

    - `master`: `solutions/NN_topic.ipynb`.
    - `exercise`: the committed `exercises/NN_topic.ipynb`.

    **Returns:**

    Human-readable differences (empty when in sync).
    """
    if not exercise.exists():
        return [f"{exercise} is missing"]
    with tempfile.TemporaryDirectory(prefix="diffnurbs-sync-") as tmp:
        expected = generate_exercise(master, Path(tmp) / master.name, Path(tmp) / "build")
    actual = read_notebook(exercise)
    drift = []
    if notebook_sources(actual) != notebook_sources(expected):
        drift.append(_first_difference(notebook_sources(actual), notebook_sources(expected)))
    if actual.metadata.get("otter") != expected.metadata.get("otter"):
        drift.append("the otter metadata (public tests or assignment name) differs")
    if actual.metadata.get(ANSWERS_KEY) != expected.metadata.get(ANSWERS_KEY):
        drift.append(f"the answers' names ({ANSWERS_KEY} metadata) differ")
    return drift


def _key_lines(code: str) -> set[str]:
    lines = set()
    for line in code.splitlines():
        line = re.sub(r"^(>>>|\.\.\.) ?", "", line.strip()).strip()
        if line and not line.startswith(("#", "import ", "from ")):
            lines.add(line)
    return lines


def _notebook_leaks(path: Path, hidden: list[set[str]]) -> list[str]:
    nb = read_notebook(path)
    leaks = [f"{path}: hidden test in the notebook metadata" for _ in hidden_cases(nb)]
    for index, cell in enumerate(nb.cells):
        lines = {line.strip() for line in cell.source.splitlines()}
        if any(key and key <= lines for key in hidden):
            leaks.append(f"{path}: cell {index} contains a hidden test")
        if "# HIDDEN" in cell.source or SOLUTION_MARKER.search(cell.source):
            leaks.append(f"{path}: cell {index} contains a `# HIDDEN` or solution marker")
    return leaks


def hidden_test_leaks(exercises: Path, solutions: Path) -> list[str]:
    """Look for hidden tests (and anything that is not a student notebook) under `exercises`.

    **Arguments:**

    - `exercises`: the folder of student notebooks.
    - `solutions`: the folder of masters whose hidden tests must not appear there.

    **Returns:**

    Human-readable leaks (empty when there are none).
    """
    hidden: list[set[str]] = []
    with tempfile.TemporaryDirectory(prefix="diffnurbs-hidden-") as tmp:
        for master in notebooks(solutions):
            autograder = read_notebook(assign(master, Path(tmp) / master.stem).autograder)
            hidden += [_key_lines(code) for code in hidden_cases(autograder)]
    leaks = []
    for path in sorted(p for p in exercises.rglob("*") if p.is_file()):
        if any(part.startswith(".") for part in path.relative_to(exercises).parts):
            continue  # .OTTER_LOG, .ipynb_checkpoints/: the student's local state, git-ignored
        if path.suffix != ".ipynb" or path.parent != exercises:
            leaks.append(f"{path}: only student notebooks belong under {exercises}")
        else:
            leaks += _notebook_leaks(path, hidden)
    return leaks
