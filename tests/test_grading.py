"""`diffnurbs-grade` on the demo master (tests/data) and on every real master and exercise."""

import csv
import shutil
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest
from notebook_runs import DEMO_MASTER, LAYOUT, ROOT, graded, graded_exercise, shared_dir

import diffnurbs_course as dc

SOLUTIONS = dc.notebooks(LAYOUT.solutions)
EXERCISES = dc.notebooks(LAYOUT.exercises)


def _id(path: Path) -> str:
    return str(path.relative_to(ROOT))


def _grade(work: Path, *options: str, header=("file", "q1", "q2", "total", "max", "flags")):
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


def test_unmatched_notebook_gets_an_empty_row(tmp_path):
    (tmp_path / "submissions").mkdir()
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell("x = 1")])
    nbformat.write(nb, tmp_path / "submissions" / "homework.ipynb")
    rows = _grade(tmp_path, header=("file", "total", "max", "flags"))
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
        "file,q1,q2,q3,total,max,flags",
        "a.ipynb,1,0.5,,1.5,2,",
        "b.ipynb,2,0,0.3333,2.3333,6,",
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


def test_without_a_sandbox_the_grader_refuses_unless_told(tmp_path, monkeypatch, capsys):
    (tmp_path / "submissions").mkdir()
    shutil.copyfile(DEMO_MASTER, tmp_path / "submissions" / DEMO_MASTER.name)
    monkeypatch.setenv("PATH", str(tmp_path))  # no bwrap on it
    argv = [str(tmp_path / "submissions"), "-o", str(tmp_path / "s.csv")]
    argv += ["--solutions", str(DEMO_MASTER.parent)]
    assert dc.main(argv) == 2
    error = capsys.readouterr().err
    assert "no sandbox on this machine" in error and "bubblewrap" in error, error
    assert "--no-sandbox" in error and not (tmp_path / "s.csv").exists()
    rows = _grade(tmp_path, "--no-sandbox")
    assert _scores(rows[DEMO_MASTER.name]) == (2, 3, 5, 5)
