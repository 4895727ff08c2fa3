"""`exercises/` is generated from `solutions/` (`make exercises`) and holds no hidden test.

The demo master in `tests/data/` is checked the same way, so the round trip is tested even
before the first real master exists.
"""

from pathlib import Path

import pytest
from notebook_runs import LAYOUT, ROOT

import diffnurbs_course as dc

DATA = Path(__file__).parent / "data"
PAIRS = [(DATA / "solutions", DATA / "exercises"), (LAYOUT.solutions, LAYOUT.exercises)]
MASTERS = [
    (master, exercises) for solutions, exercises in PAIRS for master in dc.notebooks(solutions)
]


def _id(path: Path) -> str:
    return str(path.relative_to(ROOT))


@pytest.mark.parametrize(("master", "exercises"), MASTERS, ids=[_id(m) for m, _ in MASTERS])
def test_master_follows_the_authoring_rules(master, exercises):
    problems = dc.master_problems(master)
    assert not problems, f"{_id(master)} (see course/AUTHORING.md):\n" + "\n".join(problems)


@pytest.mark.parametrize(("master", "exercises"), MASTERS, ids=[_id(m) for m, _ in MASTERS])
def test_exercise_is_in_sync(master, exercises):
    drift = dc.exercise_drift(master, exercises / master.name)
    assert not drift, (
        f"{_id(exercises / master.name)} is out of date, run `make exercises`: {drift}"
    )


@pytest.mark.parametrize(("solutions", "exercises"), PAIRS, ids=["demo", "course"])
def test_every_exercise_has_a_master(solutions, exercises):
    orphans = [p.name for p in dc.notebooks(exercises) if not (solutions / p.name).exists()]
    assert not orphans, f"exercises without a master in {_id(solutions)}: {orphans}"


@pytest.mark.parametrize(("solutions", "exercises"), PAIRS, ids=["demo", "course"])
def test_no_hidden_tests_under_exercises(solutions, exercises):
    if not exercises.is_dir():
        pytest.skip(f"no {_id(exercises)}")
    leaks = dc.hidden_test_leaks(exercises, solutions)
    assert not leaks, "\n".join(leaks)


def test_leak_detector_sees_a_leak(tmp_path):
    """Copying a master, or its autograder version, into exercises/ must be caught."""
    master = DATA / "solutions" / "99_demo.ipynb"
    assigned = dc.assign(master, tmp_path / "otter")
    (tmp_path / "exercises").mkdir()
    (tmp_path / "exercises" / "99_demo.ipynb").write_bytes(assigned.autograder.read_bytes())
    (tmp_path / "exercises" / "98_copy.ipynb").write_bytes(master.read_bytes())
    (tmp_path / "exercises" / "tests").mkdir()
    (tmp_path / "exercises" / "tests" / "q1.py").write_text("OK_FORMAT = True")
    leaks = dc.hidden_test_leaks(tmp_path / "exercises", DATA / "solutions")
    assert any("metadata" in leak for leak in leaks)
    assert any("contains a hidden test" in leak for leak in leaks)
    assert any("only student notebooks" in leak for leak in leaks)


def test_drift_is_detected(tmp_path):
    master = DATA / "solutions" / "99_demo.ipynb"
    nb = dc.read_notebook(DATA / "exercises" / "99_demo.ipynb")
    nb.cells[3].source += "\n# edited by hand"
    import nbformat

    nbformat.write(nb, tmp_path / "99_demo.ipynb")
    assert dc.exercise_drift(master, tmp_path / "99_demo.ipynb")
    assert dc.exercise_drift(master, tmp_path / "missing.ipynb")


def test_master_checker_reports_broken_rules(tmp_path):
    import nbformat

    nb = dc.read_notebook(DATA / "solutions" / "99_demo.ipynb")
    nb.cells[0].source = nb.cells[0].source.replace("show_question_points: true", "")
    for cell in nb.cells:
        cell.source = cell.source.replace("  # SOLUTION", "").replace("# HIDDEN\n", "")
        cell.source = cell.source.replace("assert np.shape(midpoint) == (2,)", "np.shape(midpoint)")
    path = tmp_path / "99_demo.ipynb"
    nbformat.write(nb, path)
    problems = "\n".join(dc.master_problems(path))
    assert "ASSIGNMENT CONFIG" in problems
    assert "solution cell needs" in problems
    assert "needs at least one hidden test" in problems
    assert "bare expression" in problems


def test_printing_test_statements_are_reported():
    """doctest echoes expression statements in loops too; calls expected to raise are fine."""
    source = "for n in (1, 2):\n    f(n)\ntry:\n    g()\nexcept ValueError:\n    pass\nh()\n"
    problems = dc.problems_in_test_code(source, "test")
    assert [p.split(" is ")[0] for p in problems] == ["test: line 2", "test: line 7"]
    assert not dc.problems_in_test_code("assert f(1)\nnp.testing.assert_allclose(a, b)\n", "test")
