"""Differentiable Bezier, B-spline and NURBS curves and surfaces in JAX.

Naming convention, followed by every public function and class:

- `control_points`: array `(n_control, dim)` for a curve, `(nu, nv, dim)` for a surface.
- `n_control`: a count of control points: an int for curves, a pair `(nu, nv)` for
  surfaces. Shapes are written with it (`(n_control, dim)`), never as `n + 1`.
- `degree`: an int `p` for curves; a pair `(p, q)` for surfaces; a tuple with one entry
  per axis for volumes and lattices.
- `knots`: a knot vector for curves, a pair `(U, V)` for surfaces.
- `order`: the highest derivative order asked for (`curve.derivatives(u, order)`).
- `u`, `v`: curve and surface parameters; `us`, `vs`: the axes of a tensor grid.
- Fitting functions take `(data, n_control, degree, ...)` in that order (`approximate`,
  `approximate_surface`, `fit_curve`, `fit_surface`, `smooth`, `approximation_knots`);
  where there is no `n_control` (interpolation) the degree follows the data. `closed=True`
  fits a periodic curve; `penalty` is the weight of a roughness penalty (`smooth`,
  `fit_surface`), `smoothing` the residual that chooses it (`smooth`).
- `max_steps`: the limit of any iterative solver; `tol`: its tolerance.
- `direction`: `"u"` or `"v"`, the keyword-only last argument of every surface operation
  that acts along one direction (`insert_knot`, `refine`, `elevate_degree`).
- `frame`: `"rmf"` or `"frenet"`, the kind of moving frame.
- `full_output=True` makes a function also return its report (`CurveFitReport`, ...).
- One public name per concept: classes are constructed directly (`CoonsPatch(...)`,
  `KinematicSweep(...)`); functions build what no class names (`circle`, `revolve`).

Submodules `io` (files and meshes), `plot` (matplotlib), `viz` (pyvista), `ph`
(Pythagorean-hodograph curves) and `widgets` (Jupyter editors, on anywidget) are attributes
of the package, imported on first use.
"""

import importlib

from ._basis import (
    basis_funs as basis_funs,
    basis_matrix as basis_matrix,
    bernstein as bernstein,
    cox_de_boor as cox_de_boor,
    ders_basis_funs as ders_basis_funs,
    find_span as find_span,
)
from ._bezier import (
    bezier_derivative_points as bezier_derivative_points,
    bezier_matrix as bezier_matrix,
    de_casteljau as de_casteljau,
    de_casteljau_surface as de_casteljau_surface,
    de_casteljau_volume as de_casteljau_volume,
    subdivide as subdivide,
)
from ._coons import CoonsPatch as CoonsPatch, bilinear_patch as bilinear_patch
from ._cubic import (
    cardinal_spline as cardinal_spline,
    catmull_rom as catmull_rom,
    cubic_matrix as cubic_matrix,
    hermite_segment as hermite_segment,
    matrix_segment as matrix_segment,
    uniform_cubic_bspline as uniform_cubic_bspline,
)
from ._curve import NURBSCurve as NURBSCurve
from ._deboor import de_boor_levels as de_boor_levels
from ._ffd import deform_image as deform_image, ffd as ffd, ffd_lattice as ffd_lattice
from ._fit_curve import CurveFitReport as CurveFitReport, fit_curve as fit_curve
from ._fit_function import FunctionFitReport as FunctionFitReport, fit_function as fit_function
from ._fit_surface import SurfaceFitReport as SurfaceFitReport, fit_surface as fit_surface
from ._frames import KinematicSweep as KinematicSweep, frames as frames
from ._halfedge import HalfEdgeMesh as HalfEdgeMesh, weld_vertices as weld_vertices
from ._interpolate import (
    approximate as approximate,
    approximate_surface as approximate_surface,
    interpolate as interpolate,
    interpolate_surface as interpolate_surface,
)
from ._intersect import curve_intersections as curve_intersections
from ._knots import (
    approximation_knots as approximation_knots,
    averaged_knots as averaged_knots,
    clamped_knots as clamped_knots,
    parametrize as parametrize,
    periodic_knots as periodic_knots,
)
from ._motion import extrude as extrude, revolve as revolve, sweep as sweep
from ._objects import design_object as design_object, revolution_patches as revolution_patches
from ._patches import bicubic_patch as bicubic_patch
from ._rational import (
    from_homogeneous as from_homogeneous,
    rational_curve_derivatives as rational_curve_derivatives,
    rational_surface_derivatives as rational_surface_derivatives,
    to_homogeneous as to_homogeneous,
)
from ._shapes import arc as arc, circle as circle, ellipse as ellipse
from ._skinning import gordon as gordon, loft as loft
from ._smooth import SmoothingReport as SmoothingReport, smooth as smooth
from ._surface import AbstractSurface as AbstractSurface, NURBSSurface as NURBSSurface
from ._surface_intersect import (
    IntersectionCurve as IntersectionCurve,
    curve_surface_intersections as curve_surface_intersections,
    surface_intersections as surface_intersections,
)

__version__ = "0.1.0"

_SUBMODULES = ("io", "ph", "plot", "viz", "widgets")


def __getattr__(name):
    # Submodules load on first use: `viz` and `io` would pull in pyvista, `plot` pyplot.
    if name in _SUBMODULES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_SUBMODULES))
