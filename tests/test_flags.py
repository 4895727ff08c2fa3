"""Flags for the teacher (`submission_flags`, `batch_flags`) and the CSV's `flags` column.

Honest work must get no flag: every master in `solutions/` (and the demo) and its exercise,
with the code the exercise hands out (`handed_out_code`) not counted as the student's. Each
hostile cell below is added to the blank demo exercise and must be flagged, naming its cell
and what it touches.
"""

import csv

import nbformat
import pytest
from notebook_runs import DEMO_MASTER, LAYOUT

import diffnurbs_course as dc
from diffnurbs_course._flags import (
    batch_flags,
    handed_out_code,
    runtime_flags,
    static_flags,
    submission_flags,
)
from diffnurbs_course._scores import print_progress, write_csv

MASTERS = [*dc.notebooks(LAYOUT.solutions), DEMO_MASTER]
DEMO_EXERCISE = DEMO_MASTER.parents[1] / "exercises" / DEMO_MASTER.name


def _exercise(master):
    return master.parents[1] / "exercises" / master.name


@pytest.mark.parametrize("master", MASTERS, ids=lambda p: p.stem)
def test_masters_and_their_exercises_get_no_flags(master):
    """With the results honest work gets: full marks for a master, 0 for a blank exercise."""
    possible = dc.load_master(master).possible
    exercise = dc.read_notebook(_exercise(master))
    provided = handed_out_code(exercise)
    full = dc.GradeResult(str(master), master.stem, dict(possible), dict(possible), seconds=20.0)
    blank = dc.GradeResult(str(master), master.stem, dict.fromkeys(possible, 0.0), dict(possible))
    assert submission_flags(dc.read_notebook(master), full, provided=provided) == []
    assert submission_flags(exercise, blank, provided=provided) == []


@pytest.mark.parametrize("chapter", ["05_bspline_basis", "06_bspline_derivatives", "15_fitting"])
def test_handed_out_helpers_count_only_when_the_student_changes_them(chapter):
    """These exercises hand out helpers that switch library functions off during a test:
    flagged unless they are the handed-out code."""
    exercise = dc.read_notebook(LAYOUT.exercises / f"{chapter}.ipynb")
    provided = handed_out_code(exercise)
    code = [cell for cell in exercise.cells if cell.cell_type == "code"]
    (number,) = [i for i, cell in enumerate(code, 1) if "def without_" in cell.source]
    (unscanned,) = static_flags(exercise)
    assert unscanned.startswith(f"code cell {number} ")
    assert unscanned.endswith("on dn (the libraries the tests use)") or " assigns dn." in unscanned
    assert static_flags(exercise, provided) == []
    # A student's helper that leaves the library switched off no longer matches.
    helper = code[number - 1]
    assert "    finally:" in helper.source
    helper.source = helper.source.replace("    finally:", "    except Exception:")
    (flag,) = static_flags(exercise, provided)
    assert flag.startswith(f"code cell {number} ")


# (hostile cell, words its flag must contain); the cell is appended as the last code cell.
HOSTILE = [
    ("import subprocess as sp\nsp.run(['ls'])", "imports subprocess (other programs)"),
    ("import os\nos.system('id')", "uses os.system (other programs)"),
    ("from os import fork\nfork()", "imports os.fork (other programs)"),
    ("import multiprocessing", "imports multiprocessing (other programs)"),
    ("import pty", "imports pty (other programs)"),
    ("pid = open('/proc/1/cmdline').read()", "mentions /proc"),
    ("path = f'/proc/{1}/cmdline'", "mentions /proc"),
    ("import socket\ns = socket.socket()", "imports socket (the network)"),
    ("from urllib.request import urlopen", "imports urllib.request.urlopen (the network)"),
    ("import http.server", "imports http.server (the network)"),
    ("import requests", "imports requests (the network)"),
    ("import ctypes", "imports ctypes (native code)"),
    ("import cffi", "imports cffi (native code)"),
    ("import sys\nsys.modules['numpy'] = None", "uses sys.modules (the import system)"),
    ("import builtins\nbuiltins.print = None", "imports builtins (the import system)"),
    ("import importlib\nimportlib.reload(np)", "imports importlib (the import system)"),
    ("__builtins__.abs = None", "uses __builtins__.abs (the import system)"),
    ("np.allclose = lambda *a, **k: True", "assigns np.allclose (the libraries the tests use)"),
    ("setattr(np, 'isclose', max)", "calls setattr on np (the libraries the tests use)"),
    ("class Fake:\n    pass\n\nnp = Fake()", "rebinds np (the libraries the tests use)"),
    ("import numpy as xp\nxp.linalg.norm = abs", "assigns xp.linalg.norm (the libraries"),
    ("dn.bernstein = lambda n, t: 0", "assigns dn.bernstein (the libraries the tests use)"),
    ("del jnp.allclose", "deletes jnp.allclose (the libraries the tests use)"),
    ("import otter", "imports otter (the grading machinery)"),
    ("from otter.execute import Checker", "imports otter.execute.Checker (the grading"),
    ("from diffnurbs_course import KernelSession", "imports diffnurbs_course.KernelSession"),
    ("Notebook.init_grading_mode('tests')", "uses diffnurbs_course.Notebook.init_grading_mode"),
    ("grader.check_all()", "uses grader.check_all (the grading machinery)"),
    ("_diffnurbs_session.save = print", "uses _diffnurbs_session.save (the grading machinery)"),
    ("globals()['_diffnurbs_session']", "mentions _diffnurbs_session (the grading machinery)"),
    ("data = open('/home/teacher/solutions.ipynb').read()", "opens the path /home/teacher/"),
    ("from pathlib import Path\nPath('../solutions').iterdir()", "opens the path ../solutions"),
    ("import signal\nsignal.signal(signal.SIGINT, signal.SIG_IGN)", "imports signal (signal"),
    ("value = eval('1 + 1')", "uses eval (code built from strings)"),
    ("exec('x = 1')", "uses exec (code built from strings)"),
    ("os_module = __import__('os')", "uses __import__ (code built from strings)"),
    ("import sys\nframe = sys._getframe(1)", "uses sys._getframe (the interpreter's internals)"),
    ("!ls /", "runs the shell command !ls / (the shell)"),
    ("files = !cat /etc/passwd", "runs the shell command !cat /etc/passwd (the shell)"),
    ("%%bash\necho hi", "runs the shell magic %%bash (the shell)"),
    ("%%writefile ../solutions/x.py\nprint(1)", "uses the IPython magic %%writefile"),
    ("%env SECRET=1", "uses the IPython magic %env (the IPython shell)"),
    ("shell = get_ipython()", "uses get_ipython() (the IPython shell)"),
    ("def broken(:\n    import subprocess", "(which does not parse) touches other programs"),
]


def _with_cell(source: str) -> tuple[nbformat.NotebookNode, int]:
    nb = dc.read_notebook(DEMO_EXERCISE)
    nb.cells.append(nbformat.v4.new_code_cell(source))
    return nb, sum(cell.cell_type == "code" for cell in nb.cells)


@pytest.mark.parametrize(("source", "words"), HOSTILE, ids=[h[0][:30] for h in HOSTILE])
def test_hostile_cells_are_flagged_by_cell(source, words):
    nb, number = _with_cell(source)
    flags = static_flags(nb, handed_out_code(dc.read_notebook(DEMO_EXERCISE)))
    assert any(flag.startswith(f"code cell {number} {words}") for flag in flags), flags
    assert all(flag.startswith(f"code cell {number} ") for flag in flags), flags


HONEST = [
    "signal = np.sin(np.linspace(0, 1, 5))\nnoise = signal + 1",
    "import re\npattern = re.compile(r'\\d+')",
    "%matplotlib inline\n%timeit np.zeros(3)",
    "%%time\nx = np.ones(3)",
    "with open('my_notes.txt', 'w') as f:\n    f.write('a/b')",
    "jax.config.update('jax_enable_x64', True)\nnp.random.seed(0)",
    "same = np.allclose(np.ones(2), np.ones(2))",
    "parts = 'a/b/c'.split('/')",
    "import os\nhere = os.getcwd()",
    "def my_eval(x):\n    return x\n\nmy_eval(1)",
    "import matplotlib.pyplot as plt\nplt.plot([0, 1], [0, 1])",
    "bernstein_values?",
]


@pytest.mark.parametrize("source", HONEST, ids=[h[:30] for h in HONEST])
def test_ordinary_code_is_not_flagged(source):
    nb, _ = _with_cell(source)
    assert static_flags(nb, handed_out_code(dc.read_notebook(DEMO_EXERCISE))) == []


def _demo_result(scores, notes=(), errors=()) -> dc.GradeResult:
    return dc.GradeResult(
        "s.ipynb", "99_demo", dict(scores), {"q1": 2.0, "q2": 3.0}, list(notes), [], list(errors)
    )


def test_runtime_flags():
    nb = dc.read_notebook(DEMO_EXERCISE)
    died = ["the kernel died"]
    high = runtime_flags(nb, _demo_result({"q1": 2.0, "q2": 1.5}, died))
    assert high == ["the kernel died, yet the notebook scored 3.5/5"]
    assert runtime_flags(nb, _demo_result({"q1": 2.0, "q2": 0.0}, died)) == []
    # Full marks, yet the stub of q1 (code cell 2) raised "not answered yet".
    stub = next(c.source for c in nb.cells if "def bernstein_values" in c.source)
    error = {"index": 3, "ename": "NotImplementedError", "evalue": "not answered yet"}
    error |= {"tags": [dc.ANSWER_TAG], "source": stub}
    full = _demo_result({"q1": 2.0, "q2": 3.0}, errors=[error])
    assert runtime_flags(nb, full) == [
        "every question passed, yet code cell 2 raised NotImplementedError"
    ]
    assert runtime_flags(nb, _demo_result({"q1": 1.0, "q2": 3.0}, errors=[error])) == []
    forged = _demo_result({"q1": 4000.0, "q2": 0.0, "q9": 1.0})
    assert runtime_flags(nb, forged) == [
        "q1 scored 4000, more than its 2 points",
        "q9 is scored but is not a question of 99_demo",
    ]


def _run(master, seconds, total, maximum=10.0) -> dc.GradeResult:
    label = f"{master}-{seconds}"
    return dc.GradeResult(label, master, {"q1": total}, {"q1": maximum}, seconds=seconds)


def test_batch_flags_short_runs_with_high_scores():
    quick = _run("a", 5.0, 8.0)
    slow_class = [_run("a", s, 7.0) for s in (30.0, 32.0, 35.0, 40.0)]
    quick_low = _run("a", 4.0, 3.0)
    few = [_run("b", s, 9.0) for s in (1.0, 30.0, 31.0)]  # 3 runs: too few to compare
    unread = _run("a", 0.0, 0.0)
    batch = [quick, *slow_class, quick_low, *few, unread]
    batch_flags(batch)
    # median of a's runs that executed: 30, 32, 35, 40, 5, 4 -> 31 s; a third is 10.3 s
    assert quick.flags == ["unusually short run: 5.0 s against a median of 31.0 s for a, with 8/10"]
    assert all(r.flags == [] for r in batch if r is not quick)


def test_csv_flags_column_and_progress(tmp_path, capsys):
    flagged = _demo_result({"q1": 2.0, "q2": 3.0})
    flagged.flags = ["code cell 3 uses eval (code built from strings)", 'odd, "quoted"; text']
    plain = _demo_result({"q1": 0.0, "q2": 0.0})
    path = tmp_path / "scores.csv"
    write_csv([flagged, plain], path)
    rows = list(csv.reader(path.open(newline="", encoding="utf-8")))
    assert rows[0] == ["file", "q1", "q2", "total", "max", "flags"]
    assert rows[1][-1] == "; ".join(flagged.flags) and rows[2][-1] == ""
    print_progress(1, 2, flagged)
    print_progress(2, 2, plain)
    first, second = capsys.readouterr().out.splitlines()
    assert first.startswith("[1/2] s.ipynb: 5/5 (0 s) 2 flags")
    assert "flag" not in second
