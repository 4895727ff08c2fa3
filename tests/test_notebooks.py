"""Every notebook of the course runs top to bottom; notebooks are committed without outputs.

Parametrized over the globs, so chapters written later are picked up. One kernel per notebook:
course chapters are executed by `test_browser.py`, in JupyterLab as students run them; masters
and exercises are executed here by their grading run (`notebook_runs.graded`), which
`test_grading.py` reuses for the scores.

Exercises: the student version has `...` where answers go, so an answer cell, or a later cell
that uses an answer, may raise. What must not raise: the grading and otter set-up cells, every
cell before the first answer, and every `grader.check(...)` cell (otter reports failures, it
never raises, so an error there means broken tests).

Wall times go to `build/notebook_times.md`.
"""

import shutil
import sys
from pathlib import Path

import nbformat
import pytest
from notebook_runs import (
    COURSE,
    LAYOUT,
    ROOT,
    answered,
    graded,
    graded_exercise,
    shared_dir,
)

import diffnurbs_course as dc

SOLUTIONS = dc.notebooks(LAYOUT.solutions)
EXERCISES = dc.notebooks(LAYOUT.exercises)
DATA = Path(__file__).parent / "data"
DEMO = [DATA / "solutions" / "99_demo.ipynb", DATA / "exercises" / "99_demo.ipynb"]


def _id(path: Path) -> str:
    return str(path.relative_to(ROOT))


@pytest.mark.parametrize("path", COURSE + SOLUTIONS + EXERCISES + DEMO, ids=_id)
def test_committed_without_outputs(path):
    problems = dc.policy_problems(dc.read_notebook(path))
    assert not problems, f"{_id(path)}: {problems}; run `.venv/bin/python tools/nbclean.py`"


@pytest.mark.parametrize("path", SOLUTIONS, ids=_id)
def test_master_runs(path, tmp_path_factory):
    result = graded(path, path, shared_dir(tmp_path_factory))
    assert not result.notes, result.notes
    assert not result.errors, [_describe(e) for e in result.errors]


def _describe(error: dict) -> str:
    return dc.CellError(**{**error, "tags": tuple(error["tags"])}).describe()


def forbidden_errors(exercise: Path, errors: list[dict]) -> list[str]:
    """The errors of an exercise's grading run that are not excused by unfilled answers.

    **Arguments:**

    - `exercise`: the student notebook.
    - `errors`: `GradeResult.errors` of its grading run (indexed by the notebook's code cells;
      the grader runs those alone, its tests run outside the kernel).

    **Returns:**

    Descriptions of the errors that should not happen.
    """
    code = [c for c in dc.read_notebook(exercise).cells if c.cell_type == "code"]
    tags = [cell.metadata.get("tags", []) for cell in code]
    answers = [i for i, cell_tags in enumerate(tags) if dc.ANSWER_TAG in cell_tags]
    first_answer = answers[0] if answers else len(code)
    bad = []
    for error in errors:
        index, source = error["index"], error["source"]
        setup = "grader = Notebook(" in source
        check = source.lstrip().startswith("grader.check(")
        if setup or check or index < first_answer:
            bad.append(_describe(error))
    return bad


@pytest.mark.parametrize("path", EXERCISES, ids=_id)
def test_exercise_runs(path, tmp_path_factory):
    result = graded_exercise(path, shared_dir(tmp_path_factory))
    assert not result.notes, result.notes
    assert not forbidden_errors(path, result.errors)


def test_kernel_is_this_python(tmp_path):
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell("import sys; sys.executable")])
    dc.execute_notebook(nb, tmp_path)
    assert nb.cells[0].outputs[0]["data"]["text/plain"] == repr(sys.executable)


def _check_outputs(nb) -> dict[str, str]:
    texts = {}
    for cell in nb.cells:
        if cell.source.startswith("grader.check("):
            assert not any(o.output_type == "error" for o in cell.outputs), cell.outputs
            question = cell.source.split('"')[1]
            texts[question] = "".join(o.get("data", {}).get("text/plain", "") for o in cell.outputs)
    return texts


def test_demo_exercise_in_student_mode(tmp_path):
    """`grader.check` reads the public tests from the notebook file, as in a student's session."""
    (tmp_path / "blank").mkdir()
    shutil.copyfile(DEMO[1], tmp_path / "blank" / DEMO[1].name)
    blank = dc.read_notebook(DEMO[1])
    dc.execute_notebook(blank, tmp_path / "blank", allow_errors=True)
    texts = _check_outputs(blank)
    assert texts == {q: f"{q}: not answered yet" for q in ("q1", "q2")}, texts

    (tmp_path / "solved").mkdir()
    solved = answered(DEMO[0], tmp_path)
    nbformat.write(solved, tmp_path / "solved" / DEMO[1].name)
    dc.execute_notebook(solved, tmp_path / "solved")
    texts = _check_outputs(solved)
    assert set(texts) == {"q1", "q2"}
    assert all("passed" in text for text in texts.values()), texts

    # A wrong answer: the statement that failed and its message, no doctest transcript.
    wrong = answered(DEMO[0], tmp_path)
    answer = next(c for c in wrong.cells if dc.ANSWER_TAG in c.metadata.get("tags", []))
    answer.source = answer.source.replace("return", "return 1 + ", 1)
    (tmp_path / "wrong").mkdir()
    nbformat.write(wrong, tmp_path / "wrong" / DEMO[1].name)
    dc.execute_notebook(wrong, tmp_path / "wrong", allow_errors=True)
    feedback = _check_outputs(wrong)["q1"]
    assert "tests failed" in feedback and "in: assert" in feedback, feedback
    assert "Trying:" not in feedback and "Traceback" not in feedback, feedback
