"""The built wheel works outside the repository: `diffnurbs` alone, and `diffnurbs-grade`.

The wheel is installed into a fresh virtual environment in a temporary folder. Its
dependencies come from this project's environment, through a `.pth` line naming the project's
site-packages: the editable install's own `.pth` there is not processed (Python reads `.pth`
files only in site directories), so `diffnurbs` and `diffnurbs_course` resolve to the wheel's
copies, which the tests assert. Nothing is downloaded.
"""

import csv
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest
from notebook_runs import DEMO_MASTER, ROOT

DEMO_EXERCISE = DEMO_MASTER.parents[1] / "exercises" / DEMO_MASTER.name


class Installed:
    """A virtual environment with only the wheel installed in it.

    **Arguments:**

    - `venv`: the environment's folder.
    - `site`: its site-packages.
    """

    def __init__(self, venv: Path, site: Path):
        self.venv = venv
        self.site = site
        self.env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
        self.env["VIRTUAL_ENV"] = str(venv)
        self.env["PATH"] = f"{venv / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}"

    def run(self, program: str, *args: str, cwd: Path) -> subprocess.CompletedProcess:
        """Run `venv/bin/<program> args...` in `cwd`, capturing its output."""
        command = [str(self.venv / "bin" / program), *args]
        return subprocess.run(
            command, cwd=cwd, env=self.env, capture_output=True, text=True, timeout=300
        )

    def assert_loads_from_wheel(self, code: str, package: str, cwd: Path) -> None:
        """Run `python -c code`, whose last line prints a module's `__file__`: it must
        succeed, and the module must be the wheel's copy of `package`."""
        result = self.run("python", "-c", code, cwd=cwd)
        assert result.returncode == 0, result.stderr
        printed = Path(result.stdout.strip().splitlines()[-1])
        assert printed.is_relative_to(self.site / package), printed


def _check(command: list, **kwargs) -> subprocess.CompletedProcess:
    result = subprocess.run(command, capture_output=True, text=True, **kwargs)
    assert result.returncode == 0, f"{command}:\n{result.stdout}\n{result.stderr}"
    return result


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Installed:
    """Build the wheel and install it, without its dependencies, into a new environment."""
    tmp = tmp_path_factory.mktemp("wheel")
    pytest.importorskip("hatchling", reason="the dev extra installs hatchling: `make install`")
    pip = [sys.executable, "-m", "pip"]
    _check([*pip, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", tmp, ROOT])
    (wheel,) = tmp.glob("diffnurbs-*.whl")
    venv = tmp / "venv"
    _check([sys.executable, "-m", "venv", "--without-pip", venv])
    python = venv / "bin" / "python"
    _check([*pip, "--python", python, "install", "--no-index", "--no-deps", "--quiet", wheel])
    where = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    site = Path(_check([python, "-c", where]).stdout.strip())
    (site / "diffnurbs_project_dependencies.pth").write_text(
        sysconfig.get_paths()["purelib"] + "\n"
    )
    return Installed(venv, site)


def test_library_imports_from_the_wheel_without_course_dependencies(installed, tmp_path):
    code = (
        "import sys, diffnurbs\n"
        "bad = {'nbformat', 'nbclient', 'otter'} & {m.split('.')[0] for m in sys.modules}\n"
        "assert not bad, bad\n"
        "print(diffnurbs.__file__)\n"
    )
    installed.assert_loads_from_wheel(code, "diffnurbs", tmp_path)
    code = "import diffnurbs_course; print(diffnurbs_course.__file__)"
    installed.assert_loads_from_wheel(code, "diffnurbs_course", tmp_path)


def test_submodules_are_attributes_loaded_on_first_use(installed, tmp_path):
    code = (
        "import sys, diffnurbs as dn\n"
        "heavy = {'pyvista', 'matplotlib.pyplot'}\n"
        "assert not heavy & set(sys.modules), heavy & set(sys.modules)\n"
        "assert {'io', 'ph', 'plot', 'viz', 'widgets'} <= set(dir(dn))\n"
        "assert callable(dn.io.read_bpt) and callable(dn.ph.arc_length)\n"
        "assert callable(dn.plot.plot_curve) and callable(dn.viz.surface_mesh)\n"
        "assert 'pyvista' not in sys.modules  # viz imports pyvista only when it draws\n"
        "try:\n"
        "    dn.no_such_module\n"
        "except AttributeError as error:\n"
        "    print(error)\n"
    )
    result = installed.run("python", "-c", code, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "has no attribute 'no_such_module'" in result.stdout


def test_widget_front_end_ships_in_the_wheel(installed, tmp_path):
    code = (
        "import diffnurbs as dn, numpy as np\n"
        "editor = dn.widgets.CurveEditor(dn.NURBSCurve(np.eye(4, 2), 3))\n"
        "assert 'export default' in editor._esm and '.dn-editor' in editor._css\n"
        "view = dn.widgets.SurfaceView()\n"
        "assert 'WebGLRenderer' in view._esm and '.dn-view' in view._css\n"
        "print(dn.widgets.__file__)\n"
    )
    installed.assert_loads_from_wheel(code, "diffnurbs", tmp_path)


def test_installed_grader_scores_the_demo(installed, tmp_path):
    submissions = tmp_path / "submissions"
    (submissions / "master").mkdir(parents=True)
    (submissions / "blank").mkdir()
    shutil.copyfile(DEMO_MASTER, submissions / "master" / DEMO_MASTER.name)
    shutil.copyfile(DEMO_EXERCISE, submissions / "blank" / DEMO_EXERCISE.name)
    args = ["submissions", "-o", "scores.csv", "--solutions", str(DEMO_MASTER.parent)]
    args += ["--report", "report.json"]
    result = installed.run("diffnurbs-grade", *args, "--jobs", "2", cwd=tmp_path)
    assert result.returncode == 0, f"{result.stdout}\n{result.stderr}"
    with open(tmp_path / "scores.csv", newline="") as f:
        rows = {row.pop("file"): row for row in csv.DictReader(f)}
    # On a failure, what the grader printed and its per-test report say why.
    why = f"{result.stdout}\n{result.stderr}\n{(tmp_path / 'report.json').read_text()[:4000]}"
    assert rows == {
        "master/99_demo.ipynb": {"q1": "2", "q2": "3", "total": "5", "max": "5", "flags": ""},
        "blank/99_demo.ipynb": {"q1": "0", "q2": "0", "total": "0", "max": "5", "flags": ""},
    }, why


def test_installed_grader_without_solutions_says_what_it_looked_for(installed, tmp_path):
    (tmp_path / "submissions").mkdir()
    result = installed.run("diffnurbs-grade", "submissions", "-o", "scores.csv", cwd=tmp_path)
    assert result.returncode == 2
    assert f"{tmp_path / 'solutions'}/*.ipynb" in result.stderr
    assert "--solutions" in result.stderr
    assert not (tmp_path / "scores.csv").exists()
