"""pyvista meshes of curves and surfaces (pyvista is imported on first use)."""

import html
import os

import numpy as np

from ._sampling import even_grid, import_pyvista, lift_to_3d


def surface_mesh(surface, samples=(60, 60)):
    """A `pyvista.StructuredGrid` sampling the surface on an even grid of its domain.

    **Arguments:**

    - `surface`: any surface (`NURBSSurface`, `CoonsPatch`, `KinematicSweep`) of
      dimension <= 3.
    - `samples`: `(count along u, count along v)`.

    **Returns:**

    The grid, with point data `"u"` and `"v"` holding the parameters.
    """
    pv = import_pyvista()
    us, vs, points = even_grid(surface, samples)
    grid = pv.StructuredGrid(points[..., 0], points[..., 1], points[..., 2])
    # StructuredGrid stores points in Fortran order over (u, v).
    grid["u"] = np.repeat(us[:, None], len(vs), axis=1).ravel(order="F")
    grid["v"] = np.repeat(vs[None, :], len(us), axis=0).ravel(order="F")
    return grid


def control_net_mesh(control_points):
    """The control net of a surface (or polygon of a curve) as pyvista lines.

    **Arguments:**

    - `control_points`: array `(nu, nv, dim)` or `(n, dim)`.

    **Returns:**

    A `pyvista.PolyData` of line segments through the control points.
    """
    pv = import_pyvista()
    points = lift_to_3d(control_points)
    if points.ndim == 2:
        return pv.lines_from_points(points)
    index = np.arange(points.shape[0] * points.shape[1]).reshape(points.shape[:2])
    rows = [np.column_stack([row[:-1], row[1:]]) for row in index]
    cols = [np.column_stack([col[:-1], col[1:]]) for col in index.T]
    segments = np.concatenate(rows + cols)
    cells = np.column_stack([np.full(len(segments), 2), segments]).ravel()
    return pv.PolyData(points.reshape(-1, 3), lines=cells)


def curve_polyline(curve, samples=200):
    """A `pyvista.PolyData` polyline through `samples` points of the curve."""
    pv = import_pyvista()
    lower, upper = curve.domain
    points = lift_to_3d(curve(np.linspace(float(lower), float(upper), samples)))
    return pv.lines_from_points(points)


def use_notebook_backend() -> None:
    """Make pyvista draw a notebook's 3D figures as PNG images, rendered off screen (EGL).

    The same in JupyterLab (`make lab`), headless runs (`make test`) and the site. pyvista's
    rotatable views (the trame backends, "html" included) start a trame server in the kernel,
    which patches the kernel's asyncio loop with `nest_asyncio2`; the next widget callback
    can then kill the kernel ("pop from an empty deque", ipykernel issue #1250), as moving
    chapter 12's slider did in the browser tests. A view that must turn or change live is a
    `diffnurbs.widgets.SurfaceView` instead. Returns nothing, so that the set-up cell of a
    chapter prints nothing.
    """
    # VTK picks its render window when the first one is made: set it before any render.
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    pv = import_pyvista()
    pv.OFF_SCREEN = True  # never a native window, even where no display is set
    pv.set_jupyter_backend("static")


def show(plotter, *captions: str) -> None:
    """Show a pyvista plotter in a notebook with its captions as text above the views, then
    close it.

    Captions go into the page as text, one per subplot from left to right, so that the site
    and a screen reader have them as text. Closing the
    plotter frees its render window: a plotter left open keeps tens of megabytes.

    **Arguments:**

    - `plotter`: a `pyvista.Plotter` with its meshes added.
    - `captions`: one text per subplot.
    """
    from IPython.display import HTML, display

    if captions:
        cells = "".join(
            f"<div style='flex: 1; text-align: center'>{html.escape(text)}</div>"
            for text in captions
        )
        width = plotter.window_size[0]
        style = f"display: flex; width: {width}px; font: 13px sans-serif; white-space: pre-line"
        display(HTML(f"<div style='{style}'>{cells}</div>"))
    plotter.show()
    plotter.close()
