import gc
import os
from pathlib import Path

# Compiled programs go to a disk cache shared by the test workers and the notebook kernels
# they start (set before jax is imported, and inherited by the kernels): the course
# notebook, the master and the exercise of a chapter compile many of the same programs.
os.environ.setdefault(
    "JAX_COMPILATION_CACHE_DIR", str(Path(__file__).resolve().parents[1] / "build" / "jax-cache")
)
# Every program, however quick to compile: each notebook runs in a fresh kernel, which would
# otherwise compile again the hundreds of small programs that eager JAX code dispatches.
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
# XLA's compiler, not the programs, takes most of the suite's time: test inputs are small, and
# a program compiled for them runs once or a few times. The unoptimised LLVM back end and the
# older elemental emitters compile 2-3x faster (closest point on a sweep: 25 s -> 11 s). The
# results agree to rounding (a few ulps: the order of operations and fused multiply-adds
# differ); only the compiled code is slower, which `make bench`, run without these flags,
# measures.
os.environ.setdefault(
    "XLA_FLAGS", "--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false"
)

import jax
import pytest

from diffnurbs_course import use_headless_defaults

# Tests compare against float64 oracles; the library itself never touches this flag.
jax.config.update("jax_enable_x64", True)
# Notebooks executed by the tests render pyvista figures to static images, as under `make test`.
use_headless_defaults()


def pytest_collection_modifyitems(items):
    """Run the hostile batch's tests first.

    They share one graded batch, made by the first of them behind a lock (`test_hostile.py`);
    under xdist a worker that meets one while the other worker grades the batch waits idle
    (61 s in a fresh run). pytest-xdist's work stealing gives each worker a contiguous share
    of the collection and steals from the ends of the queues, so tests at the head of the
    collection all run on one worker, one after the other.
    """
    items.sort(key=lambda item: item.path.name != "test_hostile.py")


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
