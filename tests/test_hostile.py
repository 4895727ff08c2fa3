"""Hostile submissions, graded as a batch by `diffnurbs-grade` in its sandbox (issue 16).

Each notebook is the blank demo exercise (or the solved one) with one attacking cell added, as a
student who wants marks without answers, or wants out of the grader, would write it. Forgeries
must score what their answers earn (0 for blank answers), escapes must leave no trace outside
the sandbox, and broken or greedy notebooks must get their own row without costing the others.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import socket
import subprocess
import threading
import uuid
from pathlib import Path

import nbformat
import pytest
from notebook_runs import DEMO_MASTER, answered, locked, shared_dir

import diffnurbs_course as dc

DEMO_EXERCISE = DEMO_MASTER.parents[1] / "exercises" / DEMO_MASTER.name

pytestmark = pytest.mark.skipif(
    dc.sandbox_problem() is not None, reason=f"no sandbox here: {dc.sandbox_problem()}"
)


def _with_cells(nb, *sources: str, after: str = "grader = Notebook"):
    """`nb` with code cells holding `sources` inserted after the cell containing `after`."""
    index = next(i for i, cell in enumerate(nb.cells) if after in cell.source)
    nb.cells[index + 1 : index + 1] = [nbformat.v4.new_code_cell(s) for s in sources]
    return nb


class _Listener:
    """A TCP server on the host's loopback that records whether anything connected."""

    def __init__(self):
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.server.settimeout(0.2)
        self.connections = 0
        self.running = True
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        while self.running:
            try:
                conn, _ = self.server.accept()
            except TimeoutError:
                continue
            self.connections += 1
            conn.close()

    def close(self):
        self.running = False
        self.thread.join()
        self.server.close()


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """The batch's (rows by file, report by file, the world to check), graded once per run.

    Under pytest-xdist the tests of this file may land on both workers: the first grades the
    batch, the other reads its result.
    """
    shared = shared_dir(tmp_path_factory)
    cache = shared / "hostile.json"
    with locked(shared / "hostile.lock"):
        if not cache.exists():
            cache.write_text(json.dumps(_grade_batch(tmp_path_factory.mktemp("hostile"))))
    rows, results, world = json.loads(cache.read_text())
    world["subs"] = Path(world["subs"])
    return rows, results, world


def _grade_batch(work: Path):
    """Write the batch into `work`, grade it with `diffnurbs-grade`, and look around."""
    subs = work / "submissions"
    subs.mkdir()
    masters = work / "solutions"
    masters.mkdir()
    (masters / DEMO_MASTER.name).write_bytes(DEMO_MASTER.read_bytes())
    master_bytes = (masters / DEMO_MASTER.name).read_bytes()
    marker = f"diffnurbs-daemon-{uuid.uuid4().hex}"
    outside = work / "outside"  # a folder of the teacher's that no submission may touch
    outside.mkdir()
    listener = _Listener()
    solved = answered(DEMO_MASTER, work / "answered")
    blank = dc.read_notebook(DEMO_EXERCISE)

    def write(name, nb):
        nbformat.write(nb, subs / name)

    def blank_with(*sources):
        return _with_cells(nbformat.from_dict(json.loads(json.dumps(blank))), *sources)

    def solved_with(*sources, after="grader = Notebook"):
        return _with_cells(
            nbformat.from_dict(json.loads(json.dumps(solved))), *sources, after=after
        )

    write("honest_99_demo.ipynb", solved)
    write("blank_99_demo.ipynb", blank)
    raises = nbformat.from_dict(json.loads(json.dumps(solved)))
    next(c for c in raises.cells if "midpoint =" in c.source).source = "midpoint = 1 / 0"
    write("raises_99_demo.ipynb", raises)
    syntax = nbformat.from_dict(json.loads(json.dumps(solved)))
    cell = next(c for c in syntax.cells if "def bernstein_values" in c.source)
    cell.source = "def bernstein_values(n, t) return 1"
    write("syntax_99_demo.ipynb", syntax)
    attack = {}
    attack["patch_otter"] = (
        "from otter.test_files import OKTestFile\n"
        "from otter.test_files.abstract_test import TestCaseResult\n"
        "OKTestFile.run = lambda self, env: setattr(self, 'test_case_results', "
        "[TestCaseResult(c, '', True) for c in self.test_cases])\n"
        "OKTestFile.score = property(lambda self: 10.0)\n"
        "from otter.execute import Checker\n"
        "Checker.check = classmethod(lambda cls, *a, **k: None)"
    )
    attack["rewrite_tests"] = (
        "import os\n"
        "forged = \"OK_FORMAT = True\\ntest = {'name': 'q1', 'points': 2000, 'suites': "
        "[{'cases': [{'code': '>>> True\\\\nTrue', 'hidden': False, 'locked': False}], "
        "'scored': True, 'setup': '', 'teardown': '', 'type': 'doctest'}]}\\n\"\n"
        "for top in ('..', '../..', '/tmp', os.path.expanduser('~')):\n"
        "    for root, dirs, files in os.walk(top):\n"
        "        for f in files:\n"
        "            if f in ('q1.py', 'q2.py'):\n"
        "                try:\n"
        "                    open(os.path.join(root, f), 'w').write(forged)\n"
        "                except OSError:\n"
        "                    pass"
    )
    attack["overwrite_results"] = (
        "import json, os\n"
        "full = {q: {'score': p, 'possible': p, 'cases': []} for q, p in (('q1', 2), ('q2', 3))}\n"
        "for top in ('..', '../..', '/tmp'):\n"
        "    for root, dirs, files in os.walk(top):\n"
        "        for f in files:\n"
        "            if f.endswith('.json'):\n"
        "                try:\n"
        "                    json.dump(full, open(os.path.join(root, f), 'w'))\n"
        "                except OSError:\n"
        "                    pass"
    )
    attack["fake_numpy"] = (
        "import sys\n"
        "import numpy as _real\n"
        "class _Fake:\n"
        "    def __getattr__(self, name):\n"
        "        return getattr(_real, name)\n"
        "    def allclose(self, *a, **k):\n"
        "        return True\n"
        "    def isclose(self, *a, **k):\n"
        "        return True\n"
        "    def array_equal(self, *a, **k):\n"
        "        return True\n"
        "np = _Fake()\n"
        "sys.modules['numpy'].allclose = np.allclose\n"
        "def bernstein_values(n, t):\n"
        "    return _real.zeros(n + 1)\n"
        "midpoint = _real.zeros(2)"
    )
    attack["lying_object"] = (
        "class Everything:\n"
        "    def __eq__(self, other):\n"
        "        return True\n"
        "    def __array__(self, *a, **k):\n"
        "        raise TypeError\n"
        "    def __float__(self):\n"
        "        return 0.5\n"
        "    def __len__(self):\n"
        "        return 3\n"
        "def bernstein_values(n, t):\n"
        "    return Everything()\n"
        "midpoint = Everything()"
    )
    attack["proc_cmdline"] = (
        "import glob, json\n"
        "seen = []\n"
        "for d in glob.glob('/proc/[0-9]*'):\n"
        "    try:\n"
        "        seen += open(d + '/cmdline', 'rb').read().decode().split('\\0')\n"
        "    except OSError:\n"
        "        pass\n"
        "for folder in {w for w in seen if w.endswith('solutions')}:\n"
        "    for path in glob.glob(folder + '/*.ipynb'):\n"
        "        for cell in json.load(open(path))['cells']:\n"
        "            if cell['cell_type'] == 'code':\n"
        "                try:\n"
        "                    exec(''.join(cell['source']))\n"
        "                except Exception:\n"
        "                    pass"
    )
    # Escapes.
    attack["write_outside"] = (
        "import os\n"
        f"targets = [{str(masters / DEMO_MASTER.name)!r}, {str(outside / 'pwned')!r},\n"
        f"           {str(subs / 'honest_99_demo.ipynb')!r}, '/tmp/diffnurbs-pwned',\n"
        "           os.path.expanduser('~/diffnurbs-pwned')]\n"
        "for target in targets:\n"
        "    try:\n"
        "        open(target, 'w').write('pwned')\n"
        "    except OSError:\n"
        "        pass"
    )
    attack["read_others"] = (
        "import json\n"
        f"stolen = json.load(open({str(subs / 'honest_99_demo.ipynb')!r}))\n"
        "for cell in stolen['cells']:\n"
        "    if cell['cell_type'] == 'code' and 'grader' not in ''.join(cell['source']):\n"
        "        exec(''.join(cell['source']))"
    )
    attack["socket"] = (
        "import socket\n"
        f"for address in (('127.0.0.1', {listener.port}), ('8.8.8.8', 53)):\n"
        "    try:\n"
        "        socket.create_connection(address, timeout=2).sendall(b'pwned')\n"
        "    except OSError:\n"
        "        pass"
    )
    attack["daemon"] = (
        "import subprocess, sys\n"
        "subprocess.Popen([sys.executable, '-c', 'import time\\nwhile True: time.sleep(1)', "
        f"{marker!r}], start_new_session=True, stdout=subprocess.DEVNULL, "
        "stderr=subprocess.DEVNULL)"
    )
    # Three notebooks of attacks with blank answers: forging the tests' results, forging the
    # values they compare, and getting out of the sandbox.
    groups = {
        "forge_runner": ("patch_otter", "rewrite_tests", "overwrite_results", "lying_object"),
        "forge_values": ("fake_numpy", "proc_cmdline"),
        "escape": ("write_outside", "read_others", "socket", "daemon"),
    }
    for name, members in groups.items():
        write(f"{name}_99_demo.ipynb", blank_with(*(attack[m] for m in members)))
    # Broken or greedy notebooks: their own rows, the others unharmed.
    meta = json.loads(json.dumps(solved))
    meta["metadata"]["otter"]["assignment_name"] = ["99_demo"]
    write("list_metadata_99_demo.ipynb", nbformat.from_dict(meta))
    (subs / "garbled_99_demo.ipynb").write_text("{ not a notebook")
    greedy = (
        # 16 GiB asked for, never written: the limit is on address space, so the MemoryError
        # comes at 4 GiB at once rather than after seconds of writing pages.
        "import numpy as np\nhog = [np.empty(2**28, np.uint8) for _ in range(64)]",
        "print('x' * 100_000_000)",
        "raise ValueError('x' * 5_000_000)",
    )
    write("greedy_99_demo.ipynb", solved_with(*greedy))
    write("hang_cell_99_demo.ipynb", solved_with("while True:\n    pass"))
    write(
        "stubborn_99_demo.ipynb",
        solved_with(
            "import signal\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\nwhile True:\n    pass"
        ),
    )
    write(
        "hang_function_99_demo.ipynb",
        solved_with(
            "def bernstein_values(n, t):\n    while True:\n        pass",
            after="def bernstein_values",
        ),
    )

    scores, report = work / "scores.csv", work / "report.json"
    argv = [str(subs), "-o", str(scores), "--solutions", str(masters), "--report", str(report)]
    options = ["--jobs", "2", "--cell-timeout", "15", "--check-timeout", "15"]
    printed = io.StringIO()
    try:
        with contextlib.redirect_stdout(printed):
            assert dc.main([*argv, *options]) == 0
    finally:
        listener.close()

    with open(scores, newline="") as f:
        rows = {row["file"]: row for row in csv.DictReader(f)}
    results = {r["file"]: r for r in json.loads(report.read_text())}
    world = {
        "master_unchanged": (masters / DEMO_MASTER.name).read_bytes() == master_bytes,
        "outside": sorted(p.name for p in outside.iterdir()),
        "connections": listener.connections,
        "marker": marker,
        "report_bytes": report.stat().st_size,
        "subs": str(subs),
        "printed": printed.getvalue(),
    }
    return rows, results, world


def _total(rows, name) -> float:
    return float(rows[name]["total"])


ATTACKS = ["forge_runner_99_demo.ipynb", "forge_values_99_demo.ipynb", "escape_99_demo.ipynb"]


def test_honest_and_blank_submissions_score_as_before(batch):
    rows, results, _ = batch
    assert (
        float(rows["honest_99_demo.ipynb"]["q1"]),
        float(rows["honest_99_demo.ipynb"]["q2"]),
    ) == (2, 3)
    assert _total(rows, "blank_99_demo.ipynb") == 0
    cases = results["honest_99_demo.ipynb"]["details"]["q1"]["cases"]
    assert any(c["hidden"] for c in cases) and all(c["passed"] for c in cases)
    assert results["honest_99_demo.ipynb"]["flags"] == []


@pytest.mark.parametrize("name", ATTACKS)
def test_attacks_with_blank_answers_score_zero(batch, name):
    rows, results, _ = batch
    assert _total(rows, name) == 0, results[name]["details"]
    for question, detail in results[name]["details"].items():
        assert detail["score"] <= detail["possible"], question


@pytest.mark.parametrize(
    "name, why",
    [
        ("forge_runner_99_demo.ipynb", "otter"),
        ("forge_values_99_demo.ipynb", "/proc"),
        ("escape_99_demo.ipynb", "socket"),
        ("escape_99_demo.ipynb", "subprocess"),
    ],
)
def test_attacks_are_flagged_for_the_teacher(batch, name, why):
    rows, results, _ = batch
    assert any(why in flag for flag in results[name]["flags"]), results[name]["flags"]
    assert rows[name]["flags"]


def test_nothing_outside_the_sandbox_was_touched(batch):
    _, _, world = batch
    assert world["master_unchanged"]
    assert world["outside"] == []
    assert world["connections"] == 0
    assert not Path("/tmp/diffnurbs-pwned").exists()
    assert not (Path.home() / "diffnurbs-pwned").exists()
    assert (world["subs"] / "honest_99_demo.ipynb").read_text().startswith("{")


def test_no_process_survives_its_sandbox(batch):
    _, _, world = batch
    table = subprocess.run(["ps", "-eo", "args"], capture_output=True, text=True, check=True)
    assert world["marker"] not in table.stdout


def test_broken_notebooks_get_their_own_rows(batch):
    rows, results, world = batch
    assert (float(rows["raises_99_demo.ipynb"]["q1"]), _total(rows, "raises_99_demo.ipynb")) == (
        2,
        2,
    )
    assert results["raises_99_demo.ipynb"]["errors"][0]["ename"] == "ZeroDivisionError"
    assert (float(rows["syntax_99_demo.ipynb"]["q2"]), _total(rows, "syntax_99_demo.ipynb")) == (
        3,
        3,
    )
    assert f"[{len(rows)}/{len(rows)}]" in world["printed"]
    assert _total(rows, "list_metadata_99_demo.ipynb") == 5  # matched by its file name
    assert _total(rows, "garbled_99_demo.ipynb") == 0
    assert results["garbled_99_demo.ipynb"]["notes"][0].startswith("unreadable notebook")


def test_greedy_cells_cost_only_themselves(batch):
    rows, results, world = batch
    name = "greedy_99_demo.ipynb"
    assert _total(rows, name) == 5, results[name]["notes"]
    assert [e["ename"] for e in results[name]["errors"]] == ["MemoryError", "ValueError"]
    assert all(len(e["evalue"]) <= 2 * dc.MESSAGE_LIMIT for e in results[name]["errors"])
    assert world["report_bytes"] < 4 * dc.OUTPUT_LIMIT


def test_a_hung_cell_is_skipped_and_later_questions_keep_their_marks(batch):
    rows, results, _ = batch
    notes = results["hang_cell_99_demo.ipynb"]["notes"]
    assert _total(rows, "hang_cell_99_demo.ipynb") == 5, notes
    assert any("stopped after" in n for n in notes), notes
    # One that ignores the interrupt costs a restart; the cells before it run again.
    notes = results["stubborn_99_demo.ipynb"]["notes"]
    assert _total(rows, "stubborn_99_demo.ipynb") == 5, notes
    assert any("ignored the interrupt" in n and "restarted" in n for n in notes), notes


def test_a_hung_function_costs_only_its_question(batch):
    rows, results, _ = batch
    row = rows["hang_function_99_demo.ipynb"]
    assert (float(row["q1"]), float(row["q2"])) == (0, 3)
    messages = [
        c["message"] for c in results["hang_function_99_demo.ipynb"]["details"]["q1"]["cases"]
    ]
    assert any("timed out" in m for m in messages), messages


def test_the_environment_of_the_grader_does_not_reach_the_kernel(tmp_path, monkeypatch):
    """A secret in the teacher's environment is not visible to the submission."""
    monkeypatch.setenv("DIFFNURBS_TEACHER_SECRET", "hunter2")
    solved = answered(DEMO_MASTER, tmp_path / "answered")
    # The student's `midpoint` is the secret if it can read it, else the right answer.
    cell = next(c for c in solved.cells if "midpoint =" in c.source)
    cell.source += "\nimport os\nif os.environ.get('DIFFNURBS_TEACHER_SECRET'):\n    midpoint = 0"
    path = tmp_path / "99_demo.ipynb"
    nbformat.write(solved, path)
    result = dc.grade_notebook(path, dc.load_master(DEMO_MASTER))
    assert result.scores["q2"] == 3, result.details["q2"]
    assert os.environ["DIFFNURBS_TEACHER_SECRET"] == "hunter2"
