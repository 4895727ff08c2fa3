"""otter's own autograder zip of a master (`autograder_zip`), graded by otter itself.

Oracles: the points and hidden test cells written in the master notebook itself, and otter's
own non-containerised runner (`otter run`, `otter.api.grade_submission`), which must give a
solved notebook full marks and the blank exercise 0.
"""

import ast
import json
import math
import subprocess
import sys
import zipfile
from importlib.metadata import version
from pathlib import Path

import nbformat
import pytest
import yaml
from notebook_runs import DEMO_MASTER, LAYOUT, answered
from packaging.requirements import Requirement

import diffnurbs_course as dc
from diffnurbs_course._otter import AUTOGRADER_SOURCE, autograder_zip

REAL_MASTER = LAYOUT.solutions / "01_representations.ipynb"
"""The real master whose zip is graded too (otter grades its solved notebook in about 12 s)."""


def _exercise(master: Path) -> Path:
    return master.parents[1] / "exercises" / master.name


def _written_questions(master: Path) -> dict[str, tuple[float, int]]:
    """`(points, hidden test cells)` per question, read from the master's own cells."""
    questions, name = {}, None
    for cell in dc.read_notebook(master).cells:
        if cell.cell_type == "raw" and cell.source.startswith("# BEGIN QUESTION"):
            config = yaml.safe_load(cell.source.split("\n", 1)[1])
            name = config["name"]
            questions[name] = (float(config["points"]), 0)
        elif cell.cell_type == "code" and cell.source.startswith("# HIDDEN") and name:
            points, hidden = questions[name]
            questions[name] = (points, hidden + 1)
    return questions


def _zipped_tests(archive: Path) -> dict[str, dict]:
    """The OK-format test specs in a zip's `tests/`, by question."""
    specs = {}
    with zipfile.ZipFile(archive) as zf:
        for name in zf.namelist():
            if name.startswith("tests/") and name.endswith(".py"):
                module = ast.parse(zf.read(name).decode())
                (value,) = [
                    node.value
                    for node in module.body
                    if isinstance(node, ast.Assign) and node.targets[0].id == "test"
                ]
                specs[Path(name).stem] = ast.literal_eval(value)
    return specs


@pytest.fixture(scope="module")
def zips(tmp_path_factory) -> dict[Path, Path]:
    out = tmp_path_factory.mktemp("zips")
    return {master: autograder_zip(master, out) for master in (DEMO_MASTER, REAL_MASTER)}


@pytest.mark.parametrize("master", [DEMO_MASTER, REAL_MASTER], ids=lambda p: p.stem)
def test_zip_holds_every_question_with_its_hidden_tests(zips, master):
    archive = zips[master]
    assert archive == archive.parent / f"{master.stem}-autograder.zip"
    specs = _zipped_tests(archive)
    written = _written_questions(master)
    assert set(specs) == set(written)
    for question, (points, hidden) in written.items():
        cases = [case for suite in specs[question]["suites"] for case in suite["cases"]]
        assert sum(case["hidden"] for case in cases) == hidden, question
        assert float(specs[question]["points"]) == points, question
    # The same tests as diffnurbs-grade's.
    assert specs == dc.load_master(master).tests
    with zipfile.ZipFile(archive) as zf:
        environment = yaml.safe_load(zf.read("environment.yml"))
        assert {"run_autograder", "setup.sh", "otter_config.json"} <= set(zf.namelist())
        assert json.loads(zf.read("otter_config.json"))["assignment_name"] == master.stem
    python = f"python={sys.version_info.major}.{sys.version_info.minor}"
    assert python in environment["dependencies"]
    (pip,) = [d["pip"] for d in environment["dependencies"] if isinstance(d, dict)]
    assert f"diffnurbs[course]=={version('diffnurbs')}" in pip


def test_otter_run_gives_the_solved_demo_full_marks(zips, tmp_path):
    submission = tmp_path / "solved.ipynb"
    nbformat.write(answered(DEMO_MASTER, tmp_path), submission)
    otter = Path(sys.executable).parent / "otter"
    command = [otter, "run", "-a", zips[DEMO_MASTER], "-o", tmp_path, "--no-logo", submission]
    run = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    tests = json.loads((tmp_path / "results.json").read_text())["tests"]
    scores = {t["name"]: (t["score"], t["max_score"]) for t in tests if "score" in t}
    assert scores == {q: (p, p) for q, (p, _) in _written_questions(DEMO_MASTER).items()}


def test_otter_grades_the_blank_demo_exercise_zero(zips):
    from otter.api import grade_submission

    results = grade_submission(str(_exercise(DEMO_MASTER)), str(zips[DEMO_MASTER]), quiet=True)
    points = sum(p for p, _ in _written_questions(DEMO_MASTER).values())
    assert (results.total, results.possible) == (0, points)


def test_otter_grades_a_solved_real_master_full_marks(zips, tmp_path):
    from otter.api import grade_submission

    submission = tmp_path / "solved.ipynb"
    nbformat.write(answered(REAL_MASTER, tmp_path), submission)
    results = grade_submission(str(submission), str(zips[REAL_MASTER]), quiet=True)
    for question, (points, _) in _written_questions(REAL_MASTER).items():
        result = results.results[question]
        assert all(case.passed for case in result.test_case_results), question
        # otter splits a question's points over its tests: 3 x 2/3 is 2 to rounding.
        assert math.isclose(result.score, points, rel_tol=1e-12), question


def test_a_wheel_ships_inside_the_zip(tmp_path):
    pip = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation"]
    build = subprocess.run(
        [*pip, "--no-index", "-q", "-w", tmp_path, LAYOUT.root],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert build.returncode == 0, build.stderr
    (wheel,) = tmp_path.glob("diffnurbs-*.whl")
    archive = autograder_zip(DEMO_MASTER, tmp_path / "out", wheel=wheel)
    with zipfile.ZipFile(archive) as zf:
        assert zf.read(f"files/{wheel.name}") == wheel.read_bytes()
        environment = yaml.safe_load(zf.read("environment.yml"))
    (pip_lines,) = [d["pip"] for d in environment["dependencies"] if isinstance(d, dict)]
    (line,) = [line for line in pip_lines if line.startswith("diffnurbs")]
    requirement = Requirement(line)
    assert (requirement.name, requirement.extras) == ("diffnurbs", {"course"})
    assert requirement.url == f"file://{AUTOGRADER_SOURCE}/files/{wheel.name}"


def test_bad_arguments_are_named(tmp_path):
    with pytest.raises(ValueError, match=r"master must be an existing \.ipynb file"):
        autograder_zip(tmp_path / "missing.ipynb", tmp_path)
    plain = tmp_path / "plain.ipynb"
    nbformat.write(nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell("1")]), plain)
    with pytest.raises(ValueError, match="ASSIGNMENT CONFIG"):
        autograder_zip(plain, tmp_path)
    with pytest.raises(ValueError, match="wheel must be an existing diffnurbs-"):
        autograder_zip(DEMO_MASTER, tmp_path, wheel=plain)
