import gc
import os

import jax
import pytest

# Tests compare against float64 oracles; the library itself never touches this flag.
jax.config.update("jax_enable_x64", True)
# Notebooks executed by the tests render pyvista figures to static images, as under `make test`.
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's compiled programs after each test module.

    Every compiled program holds a few memory maps; a worker that runs most of the suite
    compiles thousands of them and would reach the kernel's limit on maps per process
    (`vm.max_map_count`, 65530 by default), where XLA aborts the worker.
    """
    yield
    jax.clear_caches()
    gc.collect()
