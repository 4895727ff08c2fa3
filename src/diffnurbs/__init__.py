"""Differentiable Bezier, B-spline and NURBS curves and surfaces in JAX."""

from . import ph as ph
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
from ._coons import CoonsPatch as CoonsPatch, bilinear_patch as bilinear_patch, coons as coons
from ._cubic import (
    HERMITE_MATRIX as HERMITE_MATRIX,
    cardinal_spline as cardinal_spline,
    catmull_rom as catmull_rom,
    cubic_matrix as cubic_matrix,
    hermite_segment as hermite_segment,
    matrix_segment as matrix_segment,
    uniform_cubic_bspline as uniform_cubic_bspline,
)
from ._curve import NURBSCurve as NURBSCurve
from ._ffd import deform_image as deform_image, ffd as ffd, ffd_lattice as ffd_lattice
from ._fit_curve import CurveFitReport as CurveFitReport, fit_curve as fit_curve
from ._fit_function import FunctionFitReport as FunctionFitReport, fit_function as fit_function
from ._frames import (
    KinematicSweep as KinematicSweep,
    frames as frames,
    kinematic_sweep as kinematic_sweep,
)
from ._halfedge import HalfEdgeMesh as HalfEdgeMesh, weld_vertices as weld_vertices
from ._interpolate import (
    approximate as approximate,
    approximate_surface as approximate_surface,
    interpolate as interpolate,
    interpolate_surface as interpolate_surface,
)
from ._knots import (
    approximation_knots as approximation_knots,
    averaged_knots as averaged_knots,
    clamped_knots as clamped_knots,
    parametrize as parametrize,
    periodic_knots as periodic_knots,
)
from ._motion import extrude as extrude, revolve as revolve, sweep as sweep
from ._objects import design_object as design_object, revolution_patches as revolution_patches
from ._patches import (
    BEZIER_MATRIX as BEZIER_MATRIX,
    BSPLINE_MATRIX as BSPLINE_MATRIX,
    CATMULL_ROM_MATRIX as CATMULL_ROM_MATRIX,
    bicubic_patch as bicubic_patch,
    cubic_basis_matrix as cubic_basis_matrix,
)
from ._rational import (
    from_homogeneous as from_homogeneous,
    rational_curve_derivatives as rational_curve_derivatives,
    rational_surface_derivatives as rational_surface_derivatives,
    to_homogeneous as to_homogeneous,
)
from ._shapes import arc as arc, circle as circle, ellipse as ellipse
from ._surface import NURBSSurface as NURBSSurface

__version__ = "0.1.0"
