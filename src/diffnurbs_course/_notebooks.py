"""Notebooks: find, read, execute in a fresh kernel, collect errors and figures, clean them."""

from __future__ import annotations

import asyncio
import copy
import os
import time
from dataclasses import dataclass
from pathlib import Path
from queue import Empty

import nbformat
from jupyter_client import KernelManager
from nbclient import NotebookClient
from nbclient.client import timestamp
from nbclient.util import ensure_async

KERNEL_NAME = "python3"
"""Kernel used everywhere. jupyter_client resolves the native `python3` kernel to the running
interpreter (`sys.executable`), so notebooks run in the same virtual environment as the caller."""

KERNELSPEC = {"name": "python3", "display_name": "Python 3 (ipykernel)", "language": "python"}
"""The kernelspec every committed notebook carries (otter assign needs its `language`)."""


def language_info() -> dict:
    """The `language_info` that this environment's kernel reports when a notebook opens.

    Committed with every notebook, so that opening one in JupyterLab (which writes the
    kernel's report into the metadata) leaves it unmodified.
    """
    from ipykernel.ipkernel import IPythonKernel

    return copy.deepcopy(IPythonKernel.language_info)


HEADLESS_ENV = {"VTK_DEFAULT_OPENGL_WINDOW": "vtkEGLRenderWindow", "PYVISTA_OFF_SCREEN": "true"}
"""Environment defaults under which pyvista renders static images without a display."""


def use_headless_defaults() -> None:
    """Set the environment defaults for headless pyvista rendering (existing values win)."""
    for key, value in HEADLESS_ENV.items():
        os.environ.setdefault(key, value)


def notebooks(directory: Path) -> list[Path]:
    """The notebooks `NN_topic.ipynb` directly inside `directory`, sorted by name.

    **Arguments:**

    - `directory`: a folder such as `course/` (it may be missing).

    **Returns:**

    The sorted paths; checkpoints and hidden files are skipped.
    """
    if not directory.is_dir():
        return []
    return sorted(p for p in directory.glob("*.ipynb") if not p.name.startswith("."))


def read_notebook(path: Path) -> nbformat.NotebookNode:
    """Read a notebook as nbformat 4."""
    return nbformat.read(path, as_version=4)


# ----------------------------------------------------------------------------------------------
# Execution


@dataclass(frozen=True)
class CellError:
    """An error raised by one code cell.

    **Arguments:**

    - `index`: the cell's position in the notebook.
    - `ename`, `evalue`: the exception's name and message.
    - `tags`: the cell's tags.
    - `source`: the cell's source.
    """

    index: int
    ename: str
    evalue: str
    tags: tuple[str, ...]
    source: str

    def describe(self) -> str:
        """One line naming the cell and the exception."""
        first = self.source.strip().splitlines()[0] if self.source.strip() else ""
        return f"cell {self.index} ({first[:60]!r}): {self.ename}: {self.evalue[:200]}"


def cell_errors(nb: nbformat.NotebookNode) -> list[CellError]:
    """The errors recorded in an executed notebook's outputs.

    **Arguments:**

    - `nb`: an executed notebook.

    **Returns:**

    One `CellError` per cell with an `error` output, in cell order.
    """
    found = []
    for index, cell in enumerate(nb.cells):
        for output in cell.get("outputs", []):
            if output.get("output_type") == "error":
                tags = tuple(cell.get("metadata", {}).get("tags", []))
                found.append(CellError(index, output["ename"], output["evalue"], tags, cell.source))
                break
    return found


def count_figures(nb: nbformat.NotebookNode) -> int:
    """How many image outputs (matplotlib, pyvista static, ...) an executed notebook shows."""
    count = 0
    for cell in nb.cells:
        for output in cell.get("outputs", []):
            data = output.get("data", {})
            if any(mime.startswith("image/") for mime in data):
                count += 1
    return count


class PollingNotebookClient(NotebookClient):
    """`NotebookClient` that waits for a cell's reply in one-second polls.

    nbclient waits for the shell reply with a single `get_msg(timeout=cell timeout)`.
    After a cell that displays ipywidgets (`interact`) that wait sometimes never wakes up
    although the reply has arrived (jupyter/nbclient#312): the kernel sits idle and the
    run hangs until the cell timeout. A fresh poll sees the waiting message, so polling
    every second makes such runs finish normally.
    """

    async def _async_poll_for_reply(
        self, msg_id, cell, timeout, task_poll_output_msg, task_poll_kernel_alive
    ):
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            try:
                msg = await ensure_async(self.kc.shell_channel.get_msg(timeout=1.0))
            except Empty:
                if deadline is not None and time.monotonic() > deadline:
                    # Out of time: let nbclient check the kernel and raise as it does.
                    return await super()._async_poll_for_reply(
                        msg_id, cell, 0, task_poll_output_msg, task_poll_kernel_alive
                    )
                continue
            if msg["parent_header"].get("msg_id") != msg_id:
                continue
            if self.record_timing:
                cell["metadata"]["execution"]["shell.execute_reply"] = timestamp(msg)
            try:
                await asyncio.wait_for(task_poll_output_msg, self.iopub_timeout)
            except (asyncio.TimeoutError, Empty):
                self.log.warning("Timeout waiting for IOPub output")
            task_poll_kernel_alive.cancel()
            return msg


def make_client(
    nb: nbformat.NotebookNode,
    cwd: Path,
    *,
    timeout: int | None,
    allow_errors: bool,
    km: KernelManager | None = None,
    client_class: type[NotebookClient] | None = None,
) -> NotebookClient:
    """An nbclient client on the venv's kernel, working in `cwd`.

    **Arguments:**

    - `nb`: the notebook to execute (modified in place by the client).
    - `cwd`: the kernel's working directory.
    - `timeout`: per-cell time limit in seconds (`None`: no limit).
    - `allow_errors`: whether to carry on after a cell raises.
    - `km`: the kernel manager to start the kernel with (default: the venv's kernel, unconfined).
    - `client_class`: a subclass of `PollingNotebookClient` to use instead of it.

    **Returns:**

    A `NotebookClient` that kills its kernel immediately when done.
    """
    use_headless_defaults()
    return (client_class or PollingNotebookClient)(
        nb,
        km=km,
        kernel_name=KERNEL_NAME,
        timeout=timeout,
        allow_errors=allow_errors,
        shutdown_kernel="immediate",
        resources={"metadata": {"path": str(cwd)}},
    )


def execute_notebook(
    nb: nbformat.NotebookNode, cwd: Path, *, timeout: int | None = 600, allow_errors: bool = False
) -> float:
    """Execute a notebook top to bottom in one fresh kernel.

    **Arguments:**

    - `nb`: the notebook; outputs are written into it.
    - `cwd`: the kernel's working directory.
    - `timeout`: per-cell time limit in seconds.
    - `allow_errors`: carry on after errors (else the first error raises
      `nbclient.exceptions.CellExecutionError`).

    **Returns:**

    The wall time in seconds, kernel start-up included.
    """
    start = time.perf_counter()
    make_client(nb, cwd, timeout=timeout, allow_errors=allow_errors).execute()
    return time.perf_counter() - start


# ----------------------------------------------------------------------------------------------
# Notebook policy: committed without outputs


def clean_notebook(nb: nbformat.NotebookNode) -> nbformat.NotebookNode:
    """Strip outputs, execution counts and editor state; set the standard kernelspec and
    this environment's `language_info`.

    **Arguments:**

    - `nb`: a notebook (modified in place).

    **Returns:**

    The same notebook, in the form it is committed in.
    """
    for cell in nb.cells:
        if cell.cell_type == "code":
            cell.outputs = []
            cell.execution_count = None
        for key in ("execution", "collapsed", "scrolled", "ExecuteTime"):
            cell.metadata.pop(key, None)
    nb.metadata.pop("widgets", None)
    nb.metadata["kernelspec"] = dict(KERNELSPEC)
    nb.metadata["language_info"] = language_info()
    return nb


def policy_problems(nb: nbformat.NotebookNode) -> list[str]:
    """Why a notebook is not in its committed form (empty when it is).

    **Arguments:**

    - `nb`: a notebook as read from disk.

    **Returns:**

    Human-readable problems: outputs, execution counts, widget state, wrong kernelspec or
    language_info.
    """
    problems = []
    try:
        nbformat.validate(nb)
    except nbformat.ValidationError as error:
        problems.append(f"invalid nbformat: {error.message}")
    for index, cell in enumerate(nb.cells):
        if cell.cell_type != "code":
            continue
        if cell.get("outputs"):
            problems.append(f"cell {index} has outputs")
        if cell.get("execution_count") is not None:
            problems.append(f"cell {index} has an execution count")
    if "widgets" in nb.metadata:
        problems.append("notebook metadata holds widget state")
    spec = nb.metadata.get("kernelspec", {})
    if spec.get("name") != KERNELSPEC["name"] or spec.get("language") != "python":
        problems.append(f"kernelspec should be {KERNELSPEC}, got {spec}")
    info, expected = nb.metadata.get("language_info", {}), language_info()
    if info != expected:
        problems.append(f"language_info should be {expected} (this kernel's), got {info}")
    return problems
