"""A bubblewrap sandbox around each submission's Jupyter kernel.

`SandboxKernelManager` starts the venv's ipykernel inside `bwrap` (bubblewrap, the sandbox of
Flatpak): new user, PID, network, IPC, UTS and cgroup namespaces, no capabilities, a read-only
view of the system and of the Python environment only, a private writable scratch folder seen
as `/scratch` (the kernel's working directory and HOME), a private `/tmp`, a cleared
environment, and limits on memory, tasks and file sizes. The kernel talks to the grader over
unix sockets (ZMQ `ipc` transport) in a private folder shared with the grader, since the
network namespace has no route to the host.

Teardown needs no bookkeeping: the kernel is a child of bwrap's init, PID 1 of the sandbox's
PID namespace. When the kernel exits, or the grader kills bwrap (`--die-with-parent` turns
that into a SIGKILL of the init), the kernel kills every process left in the namespace,
daemons that forked twice and called `setsid` included.

Limits, and why so:

- memory: `RLIMIT_AS` on every process (no cgroup needed, so it works for any user). It
  bounds each process, not their sum: a submission that starts many large processes can use
  up to `processes` times as much. To bound a whole batch, run the grader in a memory-limited
  scope (`systemd-run --user --scope -p MemoryMax=8G diffnurbs-grade ...`).
- processes: a cgroup `pids` limit when this user can create one (root, or a delegated
  cgroup v2 subtree); otherwise `RLIMIT_NPROC`, set inside the sandbox's user namespace,
  where Linux >= 5.14 counts only the sandbox's own tasks. Root needs the cgroup: Linux never
  enforces `RLIMIT_NPROC` on uid 0, and a user namespace keeps the real uid.
- files: `RLIMIT_FSIZE` on every file, and fixed sizes for the in-memory `/tmp` and
  `/dev/shm`. The scratch folder's total size is the host disk's.

Not hidden: the host paths of the sandbox's own mounts (`/proc/self/mountinfo`), and the
kernel's system calls are not filtered (no seccomp), as in Flatpak's default.

It works for an ordinary user (unprivileged user namespaces) and for root, as in CI.
`sandbox_problem` says when it cannot work on this machine.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import uuid
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from jupyter_client import AsyncKernelManager, KernelManager
from jupyter_client.utils import run_sync

from ._notebooks import HEADLESS_ENV, KERNEL_NAME

SCRATCH = "/scratch"
"""Where the scratch folder appears inside the sandbox (the kernel's working directory)."""


@dataclass(frozen=True)
class SandboxLimits:
    """Resource limits of one sandboxed kernel (every process in the sandbox).

    **Arguments:**

    - `memory_mb`: address space of each process (`RLIMIT_AS`), in MiB (CLI `--memory-mb`).
      Address space, not resident memory: XLA reserves far more than it touches. The
      course's heaviest masters (chapters 13 and 15) peak at 1.65 GiB of address space in
      the sandbox (2.4 GiB outside, with more malloc arenas) and 1 GiB resident, on 2
      cores; thread stacks add 8 MiB per thread. Each process has its own limit.
    - `processes`: tasks in the sandbox, threads included (CLI `--max-processes`). A JAX
      kernel runs about 32 threads on 2 cores; XLA's thread pools grow with the core count.
    - `file_mb`: largest file a process may write (`RLIMIT_FSIZE`), and the size of the
      sandbox's `/tmp` and `/dev/shm`, in MiB (CLI `--file-mb`).
    """

    memory_mb: int = 4096
    processes: int = 512
    file_mb: int = 256

    def __post_init__(self):
        for name in ("memory_mb", "processes", "file_mb"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"SandboxLimits.{name} must be a positive integer, got {value!r}")


# Run inside the sandbox (`python -I -S -c`), before the kernel: applies the limits, then
# execs the kernel. Set here rather than before bwrap starts because of RLIMIT_NPROC: Linux
# counts a user's tasks per user namespace and checks the limit in the task's namespace, so
# set inside the sandbox's own namespace it counts only the sandbox's tasks, whereas set
# before bwrap it would count every process of the teacher.
_APPLY_LIMITS = """\
import os, resource, sys
count = int(sys.argv[1])
for item in sys.argv[2:2 + count]:
    name, value = item.split("=")
    resource.setrlimit(getattr(resource, name), (int(value), int(value)))
os.execv(sys.argv[2 + count], sys.argv[2 + count:])
"""

_SYSTEM_DIRS = ("usr", "bin", "sbin", "lib", "lib32", "lib64", "libx32")
# What the interpreter, numpy, JAX and matplotlib read in /etc; not passwd (user names).
_ETC_FILES = ("ld.so.cache", "ld.so.conf", "ld.so.conf.d", "localtime", "fonts", "alternatives")


_NO_BWRAP = "bubblewrap (bwrap) is not installed or not on PATH (Debian: apt install bubblewrap)"


def _bwrap() -> str | None:
    return shutil.which("bwrap")


@functools.cache
def _python_paths() -> tuple[Path, ...]:
    """Folders the venv's interpreter reads outside the system: its prefixes and `sys.path`.

    Asked from a fresh interpreter with an empty environment, as the kernel starts, so that
    the caller's own additions (pytest's rootdir, PYTHONPATH) are not exposed.
    """
    # The packages' own folders too, in case an editable install maps them with an import
    # hook rather than a `sys.path` entry.
    code = (
        "import json, sys, importlib.util as u; print(json.dumps([sys.prefix, sys.base_prefix,"
        " *sys.path, *(u.find_spec(m).submodule_search_locations[0] + '/..'"
        " for m in ('diffnurbs', 'diffnurbs_course'))]))"
    )
    out = subprocess.run([sys.executable, "-c", code], env={}, capture_output=True, check=True)
    found: list[Path] = []
    for entry in json.loads(out.stdout):
        path = Path(os.path.normpath(entry))
        if not entry or not path.exists():
            continue
        if path.parts[1:2] and path.parts[1] in _SYSTEM_DIRS:
            continue
        found.append(path)
    # Keep the outermost folders only (site-packages lies inside its prefix).
    outer = sorted(set(found), key=lambda p: len(p.parts))
    return tuple(p for i, p in enumerate(outer) if not any(p.is_relative_to(q) for q in outer[:i]))


def _mount_fields(line: str) -> tuple[str, str, str, list[str]]:
    """Root, mount point, file system type and super options of a `/proc/self/mountinfo` line."""
    fields = line.split()
    dash = fields.index("-")
    return fields[3], fields[4], fields[dash + 1], fields[dash + 3].split(",")


def _pids_cgroup_home() -> Path | None:
    """This process's cgroup folder, if a child of it can be made with a `pids` limit.

    A cgroup v1 `pids` hierarchy, or cgroup v2 with `pids` enabled for children, writable by
    this user (root, or a delegated subtree).
    """
    own = {}
    for line in Path("/proc/self/cgroup").read_text().splitlines():
        _, controllers, path = line.split(":", 2)
        own[controllers] = path
    for line in Path("/proc/self/mountinfo").read_text().splitlines():
        root, mount, fstype, options = _mount_fields(line)
        if fstype == "cgroup" and "pids" in options:
            key = next((c for c in own if "pids" in c.split(",")), None)
        elif fstype == "cgroup2":
            key = ""
        else:
            continue
        if key not in own or not Path(own[key]).is_relative_to(root):
            continue
        home = Path(mount) / Path(own[key]).relative_to(root)
        if fstype == "cgroup2":
            try:
                enabled = (home / "cgroup.subtree_control").read_text().split()
            except OSError:
                continue
            if "pids" not in enabled:
                continue
        if os.access(home, os.W_OK):
            return home
    return None


def _process_limit_problem() -> str | None:
    """Why the process limit cannot be enforced here, or None."""
    if _pids_cgroup_home() is not None or os.geteuid() != 0:
        return None
    return (
        "the grader runs as root, for whom Linux never enforces RLIMIT_NPROC, and no writable "
        "cgroup with the pids controller was found to limit the sandbox's processes"
    )


def _sandbox_args(
    bwrap: str,
    scratch: Path,
    connection: Path | None,
    limits: SandboxLimits,
    *,
    nproc: bool,
    compile_cache: Path | None = None,
) -> list[str]:
    """The bwrap command line up to the command: namespaces, mounts, environment, limits.

    **Arguments:**

    - `bwrap`: the bwrap executable.
    - `scratch`: the host folder seen read-write as `/scratch`.
    - `connection`: the kernel's connection file, seen read-only at the same path, beside
      the folder `ipc` of its sockets, seen read-write (None: no kernel).
    - `limits`: the limits to apply.
    - `nproc`: whether to limit processes with RLIMIT_NPROC (else a cgroup does).
    - `compile_cache`: a JAX compilation cache folder seen read-write at the same path, or
      None.

    **Returns:**

    The arguments, ending with the limits launcher: append the command to run.
    """
    args = [
        bwrap,
        *("--unshare-user", "--unshare-pid", "--unshare-net", "--unshare-ipc"),
        *("--unshare-uts", "--unshare-cgroup", "--disable-userns"),
        *("--die-with-parent", "--new-session", "--cap-drop", "ALL", "--hostname", "sandbox"),
    ]
    for name in _SYSTEM_DIRS:
        host = Path("/") / name
        if host.is_symlink():
            args += ["--symlink", os.readlink(host), str(host)]
        elif host.is_dir():
            args += ["--ro-bind", str(host), str(host)]
    for name in _ETC_FILES:
        args += ["--ro-bind-try", f"/etc/{name}", f"/etc/{name}"]
    file_bytes = str(limits.file_mb * 2**20)
    args += ["--proc", "/proc", "--dev", "/dev", "--size", file_bytes, "--tmpfs", "/dev/shm"]
    args += ["--size", file_bytes, "--tmpfs", "/tmp", "--bind", str(scratch), SCRATCH]
    # After the private /tmp, which would hide an environment that lives under /tmp.
    for path in _python_paths():
        args += ["--ro-bind", str(path), str(path)]
    if compile_cache is not None:
        args += ["--bind", str(compile_cache), str(compile_cache)]
    if connection is not None:
        ipc = connection.parent / "ipc"
        args += ["--bind", str(ipc), str(ipc), "--ro-bind", str(connection), str(connection)]
    # bwrap's root is a tmpfs: without this the kernel could write anywhere outside the
    # mounts above (in memory, without limit). /dev too (its shm is a mount of its own).
    args += ["--remount-ro", "/dev", "--remount-ro", "/", "--chdir", SCRATCH, "--clearenv"]
    env = {
        "PATH": f"{Path(sys.executable).parent}:/usr/local/bin:/usr/bin:/bin",
        "HOME": SCRATCH,
        "USER": "student",
        "LOGNAME": "student",
        "LANG": "C.UTF-8",
        "TMPDIR": "/tmp",
        "XDG_CACHE_HOME": f"{SCRATCH}/.cache",
        "XDG_CONFIG_HOME": f"{SCRATCH}/.config",
        "XDG_DATA_HOME": f"{SCRATCH}/.local/share",
        "XDG_STATE_HOME": f"{SCRATCH}/.local/state",
        "MPLCONFIGDIR": f"{SCRATCH}/.config/matplotlib",
        "JUPYTER_PLATFORM_DIRS": "1",
        "JAX_PLATFORMS": "cpu",
        # glibc reserves 64 MiB of address space per malloc arena, up to 8 per core: on a
        # large machine that alone would exceed RLIMIT_AS.
        "MALLOC_ARENA_MAX": "4",
        # Silences ipykernel's debugger warning about frozen modules on every start.
        "PYDEVD_DISABLE_FILE_VALIDATION": "1",
        **HEADLESS_ENV,
    }
    # The grader's XLA compiler flags hold no secret and set how fast programs compile (the
    # test suite's fast flags, for instance): the one variable passed through.
    if "XLA_FLAGS" in os.environ:
        env["XLA_FLAGS"] = os.environ["XLA_FLAGS"]
    if compile_cache is not None:
        env["JAX_COMPILATION_CACHE_DIR"] = str(compile_cache)
        # Every program, however quick to compile: a notebook's eager JAX code dispatches
        # hundreds of small ones, which the next kernel would otherwise compile again.
        env["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"
    for key, value in env.items():
        args += ["--setenv", key, value]
    rlimits = [
        f"RLIMIT_AS={limits.memory_mb * 2**20}",
        f"RLIMIT_FSIZE={file_bytes}",
        "RLIMIT_CORE=0",
    ]
    if nproc:
        rlimits.append(f"RLIMIT_NPROC={limits.processes}")
    return [
        *args,
        "--",
        sys.executable,
        "-I",
        "-S",
        "-c",
        _APPLY_LIMITS,
        str(len(rlimits)),
        *rlimits,
    ]


def sandbox_problem() -> str | None:
    """Why submissions cannot be sandboxed on this machine, or None if they can.

    Starts a trial sandbox (a fraction of a second).

    **Returns:**

    None, or one sentence: bwrap missing, user namespaces disabled, limits that cannot be
    enforced, ...
    """
    bwrap = _bwrap()
    if bwrap is None:
        return _NO_BWRAP
    problem = _process_limit_problem()
    if problem is not None:
        return f"the sandbox cannot limit processes: {problem}"
    with tempfile.TemporaryDirectory(prefix="diffnurbs-sandbox-check-") as scratch:
        args = _sandbox_args(bwrap, Path(scratch), None, SandboxLimits(), nproc=os.geteuid() != 0)
        try:
            run = subprocess.run(
                [*args, sys.executable, "-I", "-S", "-c", ""], capture_output=True, timeout=60
            )
        except subprocess.TimeoutExpired:
            return "bubblewrap did not start a trial sandbox within 60 s"
    if run.returncode != 0:
        lines = run.stderr.decode(errors="replace").strip().splitlines() or ["no message"]
        return f"bubblewrap cannot start a sandbox here (exit status {run.returncode}): {lines[-1]}"
    return None


def _remove_cgroup(cgroup: Path) -> None:
    """Kill anything left in a sandbox's cgroup (normally nothing), then remove the cgroup."""
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        pids = (cgroup / "cgroup.procs").read_text().split()
        if not pids:
            break
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(int(pid), signal.SIGKILL)
        time.sleep(0.05)
    # A cgroup still busy after 5 s holds only dying processes: leave its empty folder.
    with contextlib.suppress(OSError):
        cgroup.rmdir()


class _Sandboxed:
    """The sandbox of the two kernel managers below (they differ in their public methods)."""

    def __init__(
        self,
        scratch: Path,
        limits: SandboxLimits = SandboxLimits(),
        *,
        compile_cache: Path | None = None,
        **kwargs: Any,
    ):
        kernel_name = kwargs.setdefault("kernel_name", KERNEL_NAME)
        if kernel_name != KERNEL_NAME:
            raise ValueError(f"kernel_name must be {KERNEL_NAME!r}, got {kernel_name!r}")
        scratch = Path(scratch)
        if not scratch.is_dir():
            raise ValueError(f"scratch must be an existing folder, got {scratch}")
        scratch = scratch.resolve()
        for path in _python_paths():
            if scratch.is_relative_to(path) or path.is_relative_to(scratch):
                raise ValueError(
                    f"the scratch folder {scratch} overlaps {path}, which the sandbox shows "
                    "read-only; expected a folder of its own, outside the Python environment "
                    "and its source folders"
                )
        temporary = Path(tempfile.gettempdir()).resolve()
        if temporary.is_relative_to(scratch):
            raise ValueError(
                f"the scratch folder {scratch} contains the temporary folder {temporary}, where "
                "the other kernels' sockets are; expected a folder of its own"
            )
        if not isinstance(limits, SandboxLimits):
            raise ValueError(f"limits must be a SandboxLimits, got {type(limits).__name__}")
        if compile_cache is not None:
            compile_cache = Path(compile_cache)
            if not compile_cache.is_dir():
                raise ValueError(f"compile_cache must be an existing folder, got {compile_cache}")
            compile_cache = compile_cache.resolve()
            if compile_cache.is_relative_to(scratch) or scratch.is_relative_to(compile_cache):
                raise ValueError(
                    f"compile_cache {compile_cache} overlaps the scratch folder {scratch}; "
                    "expected a folder of its own"
                )
        bwrap = _bwrap()
        if bwrap is None:
            raise RuntimeError(_NO_BWRAP)
        super().__init__(transport="ipc", **kwargs)
        self.scratch = scratch
        self.limits = limits
        self.compile_cache = compile_cache
        self._bwrap_path = bwrap
        self._cgroup_home = _pids_cgroup_home()
        if self._cgroup_home is None and os.geteuid() == 0:
            raise RuntimeError(_process_limit_problem())
        self._remove_cgroup: weakref.finalize | None = None
        self._new_runtime()

    def _new_runtime(self) -> None:
        """A private folder (mode 0700) for the connection file and the kernel's sockets.

        The kernel can write only in its `ipc` subfolder: were the connection file there, a
        kernel could replace it with a symbolic link, through which the grader would write
        the next connection file anywhere.
        """
        self._runtime = Path(tempfile.mkdtemp(prefix="diffnurbs-kernel-"))
        self.connection_file = str(self._runtime / "kernel.json")
        self.ip = str(self._runtime / "ipc" / "kernel")
        # Removed at full shutdown, or when the manager is dropped or Python exits.
        self._remove_runtime = weakref.finalize(self, shutil.rmtree, self._runtime, True)

    @property
    def kernel_spec(self):
        spec = super().kernel_spec
        spec.interrupt_mode = "message"
        return spec

    async def _async_pre_start_kernel(self, **kw: Any):
        if not self._runtime.is_dir():  # started again after a full shutdown
            self._new_runtime()
        # A fresh socket folder for every sandbox: the previous kernel may have left links.
        ipc = self._runtime / "ipc"
        shutil.rmtree(ipc, ignore_errors=True)
        ipc.mkdir(mode=0o700)
        kw["cwd"] = str(self.scratch)
        kw.setdefault("stdout", subprocess.DEVNULL)
        kw.setdefault("stderr", subprocess.DEVNULL)
        return await super()._async_pre_start_kernel(**kw)

    async def _async_launch_kernel(self, kernel_cmd: list[str], **kw: Any) -> None:
        args = _sandbox_args(
            self._bwrap_path,
            self.scratch,
            Path(self.connection_file),
            self.limits,
            nproc=self._cgroup_home is None,
            compile_cache=self.compile_cache,
        )
        command = [*args, *kernel_cmd]
        # bwrap needs no variables; its init, PID 1 in the sandbox, keeps the environment it
        # was started with, and the kernel can read it in /proc/1/environ.
        kw["env"] = {}
        if self._cgroup_home is not None:
            cgroup = self._cgroup_home / f"diffnurbs-sandbox-{uuid.uuid4().hex}"
            cgroup.mkdir()
            self._remove_cgroup = weakref.finalize(self, _remove_cgroup, cgroup)
            (cgroup / "pids.max").write_text(str(self.limits.processes))
            # Join the cgroup before exec, so that bwrap and everything it starts are in it.
            join = 'echo $$ > "$0/cgroup.procs" && exec "$@"'
            command = ["/bin/sh", "-c", join, str(cgroup), *command]
        await super()._async_launch_kernel(command, **kw)

    async def _async_cleanup_resources(self, restart: bool = False) -> None:
        await super()._async_cleanup_resources(restart=restart)
        if self._remove_cgroup is not None:
            self._remove_cgroup()
            self._remove_cgroup = None
        if not restart:
            self._remove_runtime()


class SandboxKernelManager(_Sandboxed, KernelManager):
    """A `KernelManager` whose kernel runs in a bubblewrap sandbox (see the module).

    For synchronous use: `start_kernel()`, then `client()` (a `BlockingKernelClient`); for
    nbclient, use `AsyncSandboxKernelManager` (nbclient's interrupt on a cell time-out hangs
    with a synchronous manager). Call `shutdown_kernel(now=True)` when done. The kernel's
    working directory is `/scratch` whatever `cwd` the caller passes; `restart_kernel`
    starts a fresh sandbox on the same scratch folder. Interrupts travel as messages (bwrap
    does not forward SIGINT). The kernel's own stdout and stderr (not the notebook's
    outputs) are discarded unless `start_kernel` is given `stdout=`/`stderr=`, so that a
    submission cannot flood the grader's terminal.

    **Arguments:**

    - `scratch`: an existing folder for this submission alone: the kernel can read, write
      and delete everything in it.
    - `limits`: resource limits.
    - `compile_cache`: a folder the kernel uses, read-write, as its JAX compilation cache
      (None: none). Only for trusted notebooks, such as the course's own masters in its
      tests: a submission could plant programs there that later kernels would load and run.
    - `**kwargs`: passed to `KernelManager` (`kernel_name`, if given, must be `python3`).

    **Raises:**

    `RuntimeError` where `sandbox_problem` finds bwrap missing or processes unlimitable.
    """

    # The public wrapper is bound to the base class's own step: rebind it to the override.
    cleanup_resources = run_sync(_Sandboxed._async_cleanup_resources)


class AsyncSandboxKernelManager(_Sandboxed, AsyncKernelManager):
    """`SandboxKernelManager` with asynchronous methods, as nbclient expects.

    Use it as `NotebookClient(nb, km=AsyncSandboxKernelManager(scratch))`, then
    `await km.shutdown_kernel(now=True)`: nbclient leaves running the kernels it does not
    own. Same arguments as `SandboxKernelManager`.
    """

    cleanup_resources = _Sandboxed._async_cleanup_resources
