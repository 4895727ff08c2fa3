"""The bubblewrap sandbox of submission kernels: every test is an escape or abuse that must fail.

The attempts run in real sandboxed kernels; the test process, outside, is the oracle (its own
files, sockets, environment and process table).
"""

import asyncio
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import nbformat
import numpy as np
import pytest
from nbclient import NotebookClient
from scipy.interpolate import BSpline

from diffnurbs_course._sandbox import (
    AsyncSandboxKernelManager,
    SandboxKernelManager,
    SandboxLimits,
    sandbox_problem,
)

ROOT = Path(__file__).resolve().parents[1]
SECRET = f"grader-secret-{uuid.uuid4().hex}"


class Sandbox:
    """A started sandboxed kernel with a blocking client."""

    def __init__(self, scratch, limits=None, **options):
        self.km = SandboxKernelManager(scratch, limits or SandboxLimits(), **options)
        self.km.start_kernel()
        self.connect()

    def connect(self):
        self.kc = self.km.client()
        self.kc.start_channels()
        self.kc.wait_for_ready(timeout=60)

    def run(self, code, timeout=60):
        """Run `code`; return the reply status, the printed text and the error name."""
        text, error = [], None

        def hook(msg):
            nonlocal error
            if msg["msg_type"] == "stream":
                text.append(msg["content"]["text"])
            elif msg["msg_type"] == "error":
                error = msg["content"]["ename"]

        reply = self.kc.execute_interactive(code, timeout=timeout, output_hook=hook)
        return reply["content"]["status"], "".join(text), error

    def value(self, expression):
        """The JSON value of `expression` in the kernel."""
        status, text, error = self.run(f"import json; print(json.dumps({expression}))")
        assert status == "ok", error
        return json.loads(text)

    def close(self, now=True):
        self.kc.stop_channels()
        self.km.shutdown_kernel(now=now)


def host_processes_with(marker):
    """The host's processes whose command line contains `marker`."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            if entry.name.isdigit() and marker in (entry / "cmdline").read_bytes().decode():
                found.append(int(entry.name))
        except OSError:
            continue
    return found


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """A submission's scratch folder and, beside it, another submission's folder."""
    base = tmp_path_factory.mktemp("batch")
    (base / "scratch").mkdir()
    (base / "other").mkdir()
    (base / "other" / "answers.ipynb").write_text("another student's answers")
    return base


@pytest.fixture(scope="module")
def sandbox(folders):
    os.environ["DIFFNURBS_TEST_SECRET"] = SECRET
    try:
        box = Sandbox(folders / "scratch")
    finally:
        del os.environ["DIFFNURBS_TEST_SECRET"]
    yield box
    box.close()


def test_sanity_numpy_diffnurbs_and_jax(sandbox):
    assert sandbox.value("1 + 1") == 2
    status, _, error = sandbox.run(
        "import jax, jax.numpy as jnp\nx = jax.jit(lambda x: jnp.sin(x) * 2)(jnp.arange(4.0))"
    )
    assert status == "ok", error
    np.testing.assert_allclose(sandbox.value("x.tolist()"), 2 * np.sin(np.arange(4.0)), rtol=1e-6)


def test_notebook_client_interrupts_and_evaluates_a_curve(folders):
    # A rational quadratic with an interior knot; the oracle is scipy's B-spline (outside).
    points, weights = [[0, 0], [1, 2], [3, 2], [4, 0]], [1.0, 0.5, 2.0, 1.0]
    knots, u = [0, 0, 0, 0.4, 1, 1, 1], np.linspace(0, 1, 7)
    nb = nbformat.v4.new_notebook()
    nb.cells.append(nbformat.v4.new_code_cell("while True: pass"))  # interrupted at time-out
    nb.cells.append(
        nbformat.v4.new_code_cell(
            "import json, numpy as np, diffnurbs as dn\n"
            f"curve = dn.NURBSCurve(np.array({points}, float), 2, np.array({knots}), "
            f"np.array({weights}))\n"
            f"print(json.dumps(np.asarray(curve(np.array({u.tolist()}))).tolist()))"
        )
    )
    scratch = folders / "notebook"
    scratch.mkdir()
    km = AsyncSandboxKernelManager(scratch)
    client = NotebookClient(
        nb,
        km=km,
        timeout_func=lambda cell: 2 if "while" in cell.source else 120,
        interrupt_on_timeout=True,
        allow_errors=True,
    )
    try:
        client.execute()
    finally:
        asyncio.run(km.shutdown_kernel(now=True))
    assert nb.cells[0].outputs[0]["ename"] == "KeyboardInterrupt"
    assert not Path(km.connection_file).parent.exists()  # the sockets' folder is gone
    (printed,) = [out["text"] for out in nb.cells[1].outputs if out.get("name") == "stdout"]
    inside = np.array(json.loads(printed))
    w = np.array(weights)
    numerator = BSpline(np.array(knots), np.array(points) * w[:, None], 2)(u)
    expected = numerator / BSpline(np.array(knots), w, 2)(u)[:, None]
    np.testing.assert_allclose(inside, expected, rtol=1e-5, atol=1e-6)


def test_writes_outside_scratch_fail(sandbox, folders):
    name = f"sandbox-{uuid.uuid4().hex}"
    connection = Path(sandbox.km.connection_file)  # read by the kernel, written by the grader
    targets = [ROOT / name, Path.home() / name, Path("/") / name, ROOT / "src" / name, connection]
    for target in targets:
        status, _, error = sandbox.run(f"open({str(target)!r}, 'w').write('x')")
        # In a clone under /tmp, a write there lands in the sandbox's private /tmp.
        if target == connection or not target.is_relative_to("/tmp"):
            assert (status, error) == ("error", "OSError"), target
        assert not target.exists() or target.read_text() != "x", target
    status, _, error = sandbox.run(f"__import__('os').remove({str(connection)!r})")
    assert (status, error) == ("error", "OSError")
    # /tmp inside is private, and the scratch folder is the host's.
    assert sandbox.run(f"open('/tmp/{name}', 'w').write('x')")[0] == "ok"
    assert not (Path("/tmp") / name).exists()
    assert sandbox.run(f"open('/scratch/{name}', 'w').write('x')")[0] == "ok"
    assert (folders / "scratch" / name).read_text() == "x"


def test_masters_other_submissions_and_repository_are_invisible(sandbox, folders):
    hidden = [
        ROOT / "solutions",
        folders / "other" / "answers.ipynb",
        ROOT / "tests",
        ROOT / "Makefile",
    ]
    assert all(path.exists() for path in hidden)  # outside, they are there
    for path in hidden:
        assert sandbox.value(f"__import__('os').path.exists({str(path)!r})") is False, path
    assert sandbox.value("__import__('diffnurbs').__file__") == str(
        ROOT / "src/diffnurbs/__init__.py"
    )


def test_proc_shows_only_the_sandbox(sandbox):
    cmdlines = sandbox.value(
        "[open(f'/proc/{p}/cmdline', 'rb').read().decode(errors='replace') "
        "for p in __import__('os').listdir('/proc') if p.isdigit()]"
    )
    # bwrap's init (a copy of bwrap) and the kernel; the grader is nowhere.
    assert len(cmdlines) == 2, cmdlines
    assert cmdlines[0].startswith(shutil.which("bwrap") + "\0")
    assert cmdlines[1].split("\0")[:3] == [sys.executable, "-m", "ipykernel_launcher"]
    grader = Path("/proc/self/cmdline").read_bytes().decode()
    assert grader not in cmdlines and host_processes_with(grader)


def test_no_socket_reaches_out_and_listeners_are_invisible(sandbox):
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        server.setblocking(False)
        port = server.getsockname()[1]
        for address in [("127.0.0.1", port), ("1.1.1.1", 53)]:
            status, _, error = sandbox.run(
                f"__import__('socket').create_connection({address!r}, timeout=3)"
            )
            assert status == "error" and error in {"OSError", "ConnectionRefusedError"}, error
        with pytest.raises(BlockingIOError):
            server.accept()
    # A port that nothing listens on outside (bound, not listening) while the kernel listens.
    with socket.socket() as reserved:
        reserved.bind(("127.0.0.1", 0))
        port = reserved.getsockname()[1]
        status, _, error = sandbox.run(
            f"listener = __import__('socket').create_server(('127.0.0.1', {port}))"
        )
        assert status == "ok", error
        with pytest.raises(ConnectionRefusedError):
            socket.create_connection(("127.0.0.1", port), timeout=3)


SANDBOX_VARIABLES = {
    *("PATH", "HOME", "USER", "LOGNAME", "LANG", "TMPDIR", "MPLCONFIGDIR", "XLA_FLAGS"),
    *("XDG_CACHE_HOME", "XDG_CONFIG_HOME", "XDG_DATA_HOME", "XDG_STATE_HOME"),
    *(
        "JUPYTER_PLATFORM_DIRS",
        "JAX_PLATFORMS",
        "MALLOC_ARENA_MAX",
        "PYDEVD_DISABLE_FILE_VALIDATION",
    ),
    *("VTK_DEFAULT_OPENGL_WINDOW", "PYVISTA_OFF_SCREEN"),
    # What ipykernel and the interpreter set for themselves once started.
    *("JPY_PARENT_PID", "PYTHONUNBUFFERED", "MPLBACKEND", "CLICOLOR", "CLICOLOR_FORCE", "PWD"),
    *("FORCE_COLOR", "TERM", "TF_CPP_MIN_LOG_LEVEL", "TPU_SKIP_MDS_QUERY"),  # the last two: jax
    *("PAGER", "GIT_PAGER", "PYDEVD_USE_FRAME_EVAL", "JPY_SESSION_NAME"),
}
"""Every variable the kernel may see: the sandbox's own list, and what the kernel adds."""


def test_environment_is_cleared(sandbox):
    inside = sandbox.value("dict(__import__('os').environ)")
    assert SECRET not in json.dumps(inside)
    # Nor in any process of the sandbox (bwrap's init keeps the environment it started with).
    environs = sandbox.value(
        "[open(f'/proc/{p}/environ', 'rb').read().decode(errors='replace') "
        "for p in __import__('os').listdir('/proc') if p.isdigit()]"
    )
    assert len(environs) == 2 and not any(SECRET in environ for environ in environs)
    # The test suite's own settings (conftest.py) stay outside too, except the XLA compiler
    # flags, the one variable passed through (it sets how fast programs compile).
    assert os.environ.get("JAX_COMPILATION_CACHE_DIR") and "JAX_COMPILATION_CACHE_DIR" not in inside
    assert inside.get("XLA_FLAGS") == os.environ.get("XLA_FLAGS")
    assert set(inside) <= SANDBOX_VARIABLES, set(inside) - SANDBOX_VARIABLES
    assert inside["HOME"] == "/scratch" and sandbox.value("__import__('os').getcwd()") == "/scratch"


def test_a_trusted_kernel_shares_a_compile_cache(tmp_path):
    (tmp_path / "scratch").mkdir()
    (tmp_path / "cache").mkdir()
    box = Sandbox(tmp_path / "scratch", compile_cache=tmp_path / "cache")
    try:
        program = "import jax, jax.numpy as jnp; print(float(jax.jit(lambda x: 3 * x + 1)(2.0)))"
        assert box.run(program) == ("ok", "7.0\n", None)
        assert box.value("__import__('os').environ['JAX_COMPILATION_CACHE_DIR']") == str(
            (tmp_path / "cache").resolve()
        )
    finally:
        box.close()
    # What the kernel compiled is on the host, for the next trusted kernel to load.
    assert any((tmp_path / "cache").iterdir())
    with pytest.raises(ValueError, match=r"compile_cache .* overlaps"):
        SandboxKernelManager(tmp_path, compile_cache=tmp_path / "cache")
    with pytest.raises(ValueError, match="compile_cache must be an existing folder"):
        SandboxKernelManager(tmp_path / "scratch", compile_cache=tmp_path / "missing")


def test_memory_beyond_the_limit_fails_inside(sandbox):
    limit = SandboxLimits().memory_mb * 2**20
    status, _, error = sandbox.run(f"block = bytearray({limit})")
    assert (status, error) == ("error", "MemoryError")
    status, _, error = sandbox.run("block = bytearray(64 * 2**20); del block")  # below: fine
    assert status == "ok", error
    assert sandbox.value("1 + 1") == 2


def test_file_beyond_the_limit_fails(sandbox):
    size = SandboxLimits().file_mb * 2**20
    for folder in ["/scratch", "/tmp"]:
        status, _, error = sandbox.run(
            f"with open('{folder}/big', 'wb') as f:\n    f.write(bytes({size}))\n    f.write(b'x')"
        )
        assert (status, error) == ("error", "OSError"), folder
        assert sandbox.value(f"__import__('os').path.getsize('{folder}/big')") <= size
        sandbox.run(f"__import__('os').remove('{folder}/big')")


def test_interrupt_stops_a_busy_loop(sandbox):
    timer = threading.Timer(1.0, sandbox.km.interrupt_kernel)
    timer.start()
    start = time.monotonic()
    status, _, error = sandbox.run("while True: pass", timeout=30)
    assert (status, error) == ("error", "KeyboardInterrupt")
    assert time.monotonic() - start < 10
    assert sandbox.value("1 + 1") == 2


def test_fork_bomb_stops_at_the_process_limit(tmp_path):
    limits = SandboxLimits(processes=64)
    box = Sandbox(tmp_path, limits)
    marker = f"bomb-{uuid.uuid4().hex}"
    try:
        status, _, error = box.run(
            "import subprocess, sys, time\n"
            "bomb = 'import os\\nwhile True:\\n    try: os.fork()\\n    except OSError: pass'\n"
            f"subprocess.Popen([sys.executable, '-c', bomb, {marker!r}])\n"
            "time.sleep(1)"
        )
        assert status == "ok", error
        tasks = box.value(
            "sum(len(__import__('os').listdir(f'/proc/{p}/task')) "
            "for p in __import__('os').listdir('/proc') if p.isdigit())"
        )
        # The bomb went off and filled the sandbox up to its limit (bwrap's outer process,
        # outside the sandbox's PID namespace, counts too when a cgroup is used).
        assert limits.processes - 8 <= tasks <= limits.processes
        assert subprocess.run(["true"]).returncode == 0  # the grader can still start processes
    finally:
        box.close()
    assert host_processes_with(marker) == []


def test_daemons_and_restart_leave_nothing(tmp_path):
    box = Sandbox(tmp_path)
    marker = f"daemon-{uuid.uuid4().hex}"
    seconds = f"600.{uuid.uuid4().int % 10**9}"  # marks the `sleep` of the second daemon
    daemons = (
        "import os, subprocess, sys, time\n"
        "if os.fork() == 0:\n"
        "    os.setsid()\n"
        "    if os.fork() == 0:\n"
        f"        argv = [sys.executable, '-c', 'import time; time.sleep(600)', {marker!r}]\n"
        "        os.execv(sys.executable, argv)\n"
        "    os._exit(0)\n"
        f"subprocess.Popen(['sleep', {seconds!r}], start_new_session=True)\n"
        "time.sleep(1)"
    )

    def running():
        return len(host_processes_with(marker)), len(host_processes_with(seconds))

    try:
        assert box.run(daemons)[0] == "ok"
        assert running() == (1, 1)
        state = "x = 1; open('/tmp/state', 'w').write('x'); open('state', 'w').write('x')"
        assert box.run(state)[0] == "ok"
        # A link planted beside the kernel's sockets (the grader connects to those paths).
        link = Path(box.km.connection_file).parent / "ipc" / "kernel-9"
        assert box.run(f"__import__('os').symlink('/etc/passwd', {str(link)!r})")[0] == "ok"
        assert link.is_symlink()
        box.kc.stop_channels()
        box.km.restart_kernel(now=True)
        box.connect()
        assert running() == (0, 0) and not link.is_symlink()
        assert box.run("x")[2] == "NameError"  # a fresh interpreter
        assert box.value("__import__('os').path.exists('/tmp/state')") is False  # a fresh /tmp
        assert box.value("open('state').read()") == "x"  # the same scratch folder
        assert box.run(daemons)[0] == "ok"
        assert running() == (1, 1)
    finally:
        box.close(now=False)  # the kernel exits by itself: its sandbox goes with it
    assert running() == (0, 0)


def test_sandbox_problem(monkeypatch, tmp_path):
    # Not skipped where the sandbox cannot work: `make install` provides bubblewrap, and the
    # grader refuses untrusted work without it, so such a machine should fail loudly.
    assert sandbox_problem() is None
    monkeypatch.setenv("PATH", str(tmp_path))
    assert "bwrap" in sandbox_problem()
    with pytest.raises(RuntimeError, match="bwrap"):
        SandboxKernelManager(tmp_path)


def test_bad_arguments(tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="memory_mb"):
        SandboxLimits(memory_mb=0)
    with pytest.raises(ValueError, match="processes"):
        SandboxLimits(processes=2.5)
    with pytest.raises(ValueError, match="existing folder"):
        SandboxKernelManager(tmp_path / "missing")
    with pytest.raises(ValueError, match="kernel_name"):
        SandboxKernelManager(tmp_path, kernel_name="other")
    for overlapping in [ROOT / "src" / "diffnurbs", ROOT.parent]:
        with pytest.raises(ValueError, match="overlaps"):
            SandboxKernelManager(overlapping)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))  # where sockets go
    (tmp_path / "tmp").mkdir()
    with pytest.raises(ValueError, match="temporary folder"):
        SandboxKernelManager(tmp_path)
