import os

import jax

# Tests compare against float64 oracles; the library itself never touches this flag.
jax.config.update("jax_enable_x64", True)
# Notebooks executed by the tests render pyvista figures to static images, as under `make test`.
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
