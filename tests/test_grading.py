"""`diffnurbs-grade` on the demo master (tests/data) and on every real master and exercise."""

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest
from notebook_runs import DEMO_MASTER, LAYOUT, ROOT, answered, graded, graded_exercise, shared_dir

import diffnurbs_course as dc

SOLUTIONS = dc.notebooks(LAYOUT.solutions)
EXERCISES = dc.notebooks(LAYOUT.exercises)
DEMO_EXERCISE = DEMO_MASTER.parents[1] / "exercises" / DEMO_MASTER.name


def _id(path: Path) -> str:
    return str(path.relative_to(ROOT))


def _answer_cell(nb, needle: str):
    return next(cell for cell in nb.cells if needle in cell.source)


def _variant(work: Path, name: str, edit=None) -> None:
    """Write the solved demo, changed by `edit`, as `submissions/<name>`."""
    nb = answered(DEMO_MASTER, work / name)
    if edit:
        edit(nb)
    path = work / "submissions" / name
    path.parent.mkdir(parents=True, exist_ok=True)
    nbformat.write(nb, path)


def _raise_in_q2(nb) -> None:
    _answer_cell(nb, "midpoint =").source = "midpoint = 1 / 0"


def _syntax_error_in_q1(nb) -> None:
    _answer_cell(nb, "def bernstein_values").source = "def bernstein_values(n, t) return 1"


def _hang_in_q2(nb) -> None:
    _answer_cell(nb, "midpoint =").source = "while True:\n    pass"


def _hang_ignoring_interrupts_in_q2(nb) -> None:
    _answer_cell(
        nb, "midpoint ="
    ).source = "import signal\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\nwhile True:\n    pass"


def _grade(work: Path, *options: str, header=("file", "q1", "q2", "total", "max")):
    """Run `diffnurbs-grade` on `work/submissions`; return the CSV rows by file."""
    scores = work / "scores.csv"
    argv = [str(work / "submissions"), "-o", str(scores), "--solutions", str(DEMO_MASTER.parent)]
    assert dc.main([*argv, *options]) == 0
    with open(scores, newline="") as f:
        rows = list(csv.DictReader(f))
    with open(scores, newline="") as f:
        assert next(csv.reader(f)) == list(header)
    return {row["file"]: row for row in rows}


def _scores(row: dict[str, str]) -> tuple[float | None, ...]:
    return tuple(float(row[k]) if row.get(k) else None for k in ("q1", "q2", "total", "max"))


def test_demo_batch_with_broken_submissions(tmp_path, capsys):
    submissions = tmp_path / "submissions"
    _variant(tmp_path, "alice_99_demo.ipynb")
    _variant(tmp_path, "raises_99_demo.ipynb", _raise_in_q2)
    _variant(tmp_path, "syntax_99_demo.ipynb", _syntax_error_in_q1)
    (submissions / "master").mkdir()
    (submissions / "master" / "99_demo.ipynb").write_bytes(DEMO_MASTER.read_bytes())
    (submissions / "blank").mkdir()
    (submissions / "blank" / "99_demo.ipynb").write_bytes(DEMO_EXERCISE.read_bytes())
    (submissions / "garbled_99_demo.ipynb").write_text("{ not a notebook")
    (submissions / ".ipynb_checkpoints").mkdir()
    (submissions / ".ipynb_checkpoints" / "99_demo-checkpoint.ipynb").write_text("{}")

    rows = _grade(tmp_path, "--timeout", "300", "--report", str(tmp_path / "report.json"))

    assert _scores(rows["alice_99_demo.ipynb"]) == (2, 3, 5, 5)
    assert _scores(rows["master/99_demo.ipynb"]) == (2, 3, 5, 5)
    assert _scores(rows["blank/99_demo.ipynb"]) == (0, 0, 0, 5)
    assert _scores(rows["raises_99_demo.ipynb"]) == (2, 0, 2, 5)
    assert _scores(rows["syntax_99_demo.ipynb"]) == (0, 3, 3, 5)
    assert _scores(rows["garbled_99_demo.ipynb"]) == (0, 0, 0, 5)
    assert len(rows) == 6
    report = {r["file"]: r for r in json.loads((tmp_path / "report.json").read_text())}
    assert report["raises_99_demo.ipynb"]["errors"][0]["ename"] == "ZeroDivisionError"
    assert report["garbled_99_demo.ipynb"]["notes"][0].startswith("unreadable notebook")
    hidden = [c for c in report["alice_99_demo.ipynb"]["details"]["q1"]["cases"] if c["hidden"]]
    assert hidden and all(c["passed"] for c in hidden)
    assert "[6/6]" in capsys.readouterr().out


def test_hanging_submissions_are_cut_off(tmp_path):
    _variant(tmp_path, "hangs_99_demo.ipynb", _hang_in_q2)
    _variant(tmp_path, "stubborn_99_demo.ipynb", _hang_ignoring_interrupts_in_q2)
    rows = _grade(tmp_path, "--timeout", "12", "--jobs", "2")
    # q1 was checked by its grader.check cell before the hang: its marks stay.
    assert _scores(rows["hangs_99_demo.ipynb"]) == (2, 0, 2, 5)
    assert _scores(rows["stubborn_99_demo.ipynb"]) == (2, 0, 2, 5)


def test_unmatched_notebook_gets_an_empty_row(tmp_path):
    (tmp_path / "submissions").mkdir()
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell("x = 1")])
    nbformat.write(nb, tmp_path / "submissions" / "homework.ipynb")
    rows = _grade(tmp_path, header=("file", "total", "max"))
    assert _scores(rows["homework.ipynb"]) == (None, None, 0, None)


def test_default_solutions_folder(tmp_path, monkeypatch):
    (tmp_path / "course" / "solutions").mkdir(parents=True)
    shutil.copyfile(DEMO_MASTER, tmp_path / "course" / "solutions" / DEMO_MASTER.name)
    assert dc.find_solutions(tmp_path / "course") == tmp_path / "course" / "solutions"
    assert dc.find_solutions(cwd=tmp_path / "course") == tmp_path / "course" / "solutions"
    monkeypatch.chdir(tmp_path / "course")
    assert dc.find_solutions().resolve() == (tmp_path / "course" / "solutions").resolve()
    with pytest.raises(FileNotFoundError, match=r"solutions/\*\.ipynb \(does not exist\)"):
        dc.find_solutions(tmp_path)
    (tmp_path / "solutions").mkdir()
    with pytest.raises(FileNotFoundError, match="holds no"):
        dc.find_solutions(cwd=tmp_path)


def test_match_master():
    names = ["02_bezier_curves", "12_surfaces_of_motion"]
    nb = nbformat.v4.new_notebook()
    assert dc.match_master(Path("02_bezier_curves.ipynb"), nb, names) == "02_bezier_curves"
    assert dc.match_master(Path("bob-02_bezier_curves (1).ipynb"), None, names) == (
        "02_bezier_curves"
    )
    nb.metadata["otter"] = {"assignment_name": "12_surfaces_of_motion"}
    assert dc.match_master(Path("copy.ipynb"), nb, names) == "12_surfaces_of_motion"
    assert dc.match_master(Path("copy.ipynb"), None, names) is None


def test_csv_columns_span_every_master(tmp_path):
    a = dc.GradeResult("a.ipynb", "A", {"q1": 1.0, "q2": 0.5}, {"q1": 1.0, "q2": 1.0})
    b = dc.GradeResult(
        "b.ipynb", "B", {"q1": 2.0, "q2": 0.0, "q3": 1 / 3}, dict.fromkeys(["q1", "q2", "q3"], 2.0)
    )
    dc.write_csv([a, b], tmp_path / "s.csv")
    lines = (tmp_path / "s.csv").read_text().splitlines()
    assert lines == [
        "file,q1,q2,q3,total,max",
        "a.ipynb,1,0.5,,1.5,2",
        "b.ipynb,2,0,0.3333,2.3333,6",
    ]


def test_console_script_is_installed():
    script = Path(sys.executable).parent / "diffnurbs-grade"
    assert script.exists(), "run `make install` (pip install -e .)"
    result = subprocess.run([script, "--help"], capture_output=True, text=True, check=True)
    assert "SUBMISSIONS" in result.stdout.upper()


@pytest.mark.parametrize("path", SOLUTIONS, ids=_id)
def test_master_scores_full_marks(path, tmp_path_factory):
    result = graded(path, path, shared_dir(tmp_path_factory))
    assert result.max_points > 0
    failed = {q: result.details.get(q) for q, s in result.scores.items() if s < result.possible[q]}
    assert result.total == pytest.approx(result.max_points), failed


@pytest.mark.parametrize("path", EXERCISES, ids=_id)
def test_blank_exercise_scores_zero(path, tmp_path_factory):
    result = graded_exercise(path, shared_dir(tmp_path_factory))
    passed = [q for q, s in result.scores.items() if s > 0]
    assert result.total == 0, f"blank answers pass {passed}: the tests do not test the answer"
