"""CAD exchange: STEP through OpenCascade's Python bindings (`cadquery-ocp`) and Rhino's
`.3dm` through `rhino3dm` (openNURBS), so that a curve or surface made or fitted here can
go into a CAD system and come back with its degrees, knots, weights and control points
exactly (STEP writes numbers in decimal; they come back to a few units in the last digit).

Both libraries are optional (`pip install diffnurbs[cad]`): they are imported on first use.
Curves are written in space (2D curves get `z = 0`); curves and surfaces come back as
`NURBSCurve` and `NURBSSurface` in the order they were written, curves first in STEP.
openNURBS drops the first and last knot of a clamped vector (its "superfluous" knots): they
are dropped on writing and put back on reading.
"""

import contextlib
import os
import types
from pathlib import Path

import numpy as np

from ._curve import NURBSCurve
from ._knotops import clamp
from ._surface import NURBSSurface


def _import(module: str, package: str):
    try:
        return __import__(module, fromlist=["_"])
    except ImportError as error:
        raise ValueError(
            f"this file format needs {package}: pip install {package} (or diffnurbs[cad])"
        ) from error


@contextlib.contextmanager
def _quiet():
    """OpenCascade prints its progress to the process's standard output: silence it."""
    saved = os.dup(1)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        try:
            yield
        finally:
            os.dup2(saved, 1)
            os.close(saved)


def _parts(shape) -> tuple[np.ndarray, np.ndarray]:
    """Control points in space and weights (ones if not rational) of a curve or surface."""
    points = np.asarray(shape.control_points, dtype=float)
    if points.shape[-1] == 2:
        points = np.concatenate([points, np.zeros((*points.shape[:-1], 1))], axis=-1)
    if points.shape[-1] != 3:
        raise ValueError(
            f"CAD files hold curves and surfaces in 2D or 3D, got dim = {points.shape[-1]}"
        )
    weights = np.ones(points.shape[:-1]) if shape.weights is None else np.asarray(shape.weights)
    return points, weights


def _shapes(shapes) -> list:
    shapes = [shapes] if isinstance(shapes, NURBSCurve | NURBSSurface) else list(shapes)
    for shape in shapes:
        if not isinstance(shape, NURBSCurve | NURBSSurface):
            raise ValueError(
                f"shapes must be NURBSCurve or NURBSSurface, got {type(shape).__name__}"
            )
    return shapes


def _from_parts(points, weights, knots, degree):
    """A curve or surface with clamped knots: OpenCascade reads a closed one as periodic,
    whose knots run past the domain ([-0.25, 0, 0, ..., 1, 1, 1.25] for a circle), and
    clamping gives back the same curve on the knots it was written with."""
    weights = None if np.allclose(weights, 1.0, rtol=0, atol=0) else weights
    if isinstance(degree, tuple):
        surface = NURBSSurface(points, degree, knots, weights)
        for direction in ("u", "v"):
            surface = surface._along(direction, clamp)
        return surface
    curve = NURBSCurve(points, degree, knots, weights)
    return curve._from_homogeneous_points(*clamp(curve.homogeneous_points(), knots, degree))


# STEP (OpenCascade)


def _ocp():
    """OpenCascade's modules, imported on first use."""
    _import("OCP.Geom", "cadquery-ocp")
    from OCP import (
        BRep,
        BRepBuilderAPI,
        Geom,
        GeomConvert,
        IFSelect,
        STEPControl,
        TopAbs,
        TopExp,
        TopoDS,
        gp,
    )
    from OCP.OCP import collections

    return types.SimpleNamespace(
        BRep=BRep, BRepBuilderAPI=BRepBuilderAPI, Geom=Geom, GeomConvert=GeomConvert,
        IFSelect=IFSelect, STEPControl=STEPControl, TopAbs=TopAbs, TopExp=TopExp,
        TopoDS=TopoDS, gp=gp, collections=collections,
    )  # fmt: skip


def _array1(kind, values):
    array = kind(1, len(values))
    for i, value in enumerate(values):
        array.SetValue(i + 1, value)
    return array


def to_occ(shape):
    """A curve or surface as an OpenCascade geometry, to use with OpenCascade's own
    algorithms (`GeomAPI`, `GeomAdaptor`, ...) through `cadquery-ocp`.

    Poles, weights and knots (with their multiplicities) are copied: nothing is
    approximated. Curves are put in space (2D curves get `z = 0`).

    **Arguments:**

    - `shape`: a `NURBSCurve` or `NURBSSurface`.

    **Returns:**

    An `OCP.Geom.Geom_BSplineCurve` or `OCP.Geom.Geom_BSplineSurface`.
    """
    if not isinstance(shape, NURBSCurve | NURBSSurface):
        raise ValueError(f"expected a NURBSCurve or NURBSSurface, got {type(shape).__name__}")
    return _occ_geometry(shape, _ocp())


def _occ_geometry(shape, occ):
    c, gp, geom = occ.collections, occ.gp, occ.Geom
    points, weights = _parts(shape)
    if isinstance(shape, NURBSCurve):
        values, counts = np.unique(np.asarray(shape.knots), return_counts=True)
        return geom.Geom_BSplineCurve(
            _array1(c.Array1_gp_Pnt, [gp.gp_Pnt(*map(float, p)) for p in points]),
            _array1(c.Array1_double, [float(w) for w in weights]),
            _array1(c.Array1_double, [float(v) for v in values]),
            _array1(c.Array1_int, [int(k) for k in counts]),
            shape.degree, False,
        )  # fmt: skip
    nu, nv = points.shape[:2]
    poles, weight_grid = c.Array2_gp_Pnt(1, nu, 1, nv), c.Array2_double(1, nu, 1, nv)
    for i in range(nu):
        for j in range(nv):
            poles.SetValue(i + 1, j + 1, gp.gp_Pnt(*map(float, points[i, j])))
            weight_grid.SetValue(i + 1, j + 1, float(weights[i, j]))
    (vu, ku), (vv, kv) = (np.unique(np.asarray(k), return_counts=True) for k in shape.knots)
    return geom.Geom_BSplineSurface(
        poles, weight_grid,
        _array1(c.Array1_double, [float(v) for v in vu]),
        _array1(c.Array1_double, [float(v) for v in vv]),
        _array1(c.Array1_int, [int(k) for k in ku]),
        _array1(c.Array1_int, [int(k) for k in kv]),
        shape.degree[0], shape.degree[1], False, False,
    )  # fmt: skip


def _to_occ(shape, occ):
    """`shape` as an OpenCascade edge or face (what a STEP file holds)."""
    geometry = _occ_geometry(shape, occ)
    if isinstance(shape, NURBSCurve):
        return occ.BRepBuilderAPI.BRepBuilderAPI_MakeEdge(geometry).Edge()
    return occ.BRepBuilderAPI.BRepBuilderAPI_MakeFace(geometry, 1e-7).Face()


def _write_step(path, shapes):
    occ = _ocp()
    builder, compound = occ.BRep.BRep_Builder(), occ.TopoDS.TopoDS_Compound()
    builder.MakeCompound(compound)
    for shape in shapes:
        builder.Add(compound, _to_occ(shape, occ))
    writer = occ.STEPControl.STEPControl_Writer()
    with _quiet():
        writer.Transfer(compound, occ.STEPControl.STEPControl_StepModelType.STEPControl_AsIs)
        status = writer.Write(str(path))
    if status != occ.IFSelect.IFSelect_ReturnStatus.IFSelect_RetDone:
        raise ValueError(f"OpenCascade could not write {path}: {status}")


def _knot_vector(values, counts):
    return np.repeat(np.asarray(values), np.asarray(counts))


def _read_step(path):
    occ = _ocp()
    reader = occ.STEPControl.STEPControl_Reader()
    with _quiet():
        status = reader.ReadFile(str(path))
        if status != occ.IFSelect.IFSelect_ReturnStatus.IFSelect_RetDone:
            raise ValueError(f"OpenCascade could not read {path} as STEP: {status}")
        reader.TransferRoots()
    shape = reader.OneShape()
    explorer, abs_, tool = occ.TopExp.TopExp_Explorer, occ.TopAbs, occ.BRep.BRep_Tool
    convert, topods = occ.GeomConvert.GeomConvert, occ.TopoDS.TopoDS
    curves, surfaces = [], []
    edges = explorer(shape, abs_.TopAbs_EDGE, abs_.TopAbs_FACE)  # free edges: the curves
    while edges.More():
        curve = convert.CurveToBSplineCurve_s(tool.Curve_s(topods.Edge(edges.Current()), 0.0, 1.0))
        if curve.IsPeriodic():  # OpenCascade makes a closed curve periodic: clamp it back
            curve.SetNotPeriodic()
        n = curve.NbPoles()
        points = np.array(
            [[curve.Pole(i).X(), curve.Pole(i).Y(), curve.Pole(i).Z()] for i in range(1, n + 1)]
        )
        weights = np.array([curve.Weight(i) for i in range(1, n + 1)])
        knots = _knot_vector(
            [curve.Knot(i) for i in range(1, curve.NbKnots() + 1)],
            [curve.Multiplicity(i) for i in range(1, curve.NbKnots() + 1)],
        )
        curves.append(_from_parts(points, weights, knots, curve.Degree()))
        edges.Next()
    faces = explorer(shape, abs_.TopAbs_FACE)
    while faces.More():
        surface = convert.SurfaceToBSplineSurface_s(tool.Surface_s(topods.Face(faces.Current())))
        if surface.IsUPeriodic():
            surface.SetUNotPeriodic()
        if surface.IsVPeriodic():
            surface.SetVNotPeriodic()
        nu, nv = surface.NbUPoles(), surface.NbVPoles()
        poles = [[surface.Pole(i, j) for j in range(1, nv + 1)] for i in range(1, nu + 1)]
        points = np.array([[[p.X(), p.Y(), p.Z()] for p in row] for row in poles])
        weights = np.array(
            [[surface.Weight(i, j) for j in range(1, nv + 1)] for i in range(1, nu + 1)]
        )
        knots = (
            _knot_vector([surface.UKnot(i) for i in range(1, surface.NbUKnots() + 1)],
                         [surface.UMultiplicity(i) for i in range(1, surface.NbUKnots() + 1)]),
            _knot_vector([surface.VKnot(i) for i in range(1, surface.NbVKnots() + 1)],
                         [surface.VMultiplicity(i) for i in range(1, surface.NbVKnots() + 1)]),
        )  # fmt: skip
        degree = (surface.UDegree(), surface.VDegree())
        surfaces.append(_from_parts(points, weights, knots, degree))
        faces.Next()
    return curves + surfaces


# .3dm (openNURBS)


def _write_3dm(path, shapes):
    rhino = _import("rhino3dm", "rhino3dm")
    model = rhino.File3dm()
    for shape in shapes:
        points, weights = _parts(shape)
        homogeneous = np.concatenate([points * weights[..., None], weights[..., None]], axis=-1)
        if isinstance(shape, NURBSCurve):
            curve = rhino.NurbsCurve(3, shape.rational, shape.degree + 1, len(points))
            for i, h in enumerate(homogeneous):
                curve.Points[i] = rhino.Point4d(*map(float, h))
            for i, knot in enumerate(np.asarray(shape.knots)[1:-1]):
                curve.Knots[i] = float(knot)
            model.Objects.AddCurve(curve)
            continue
        (p, q), (nu, nv) = shape.degree, points.shape[:2]
        surface = rhino.NurbsSurface.Create(3, shape.rational, p + 1, q + 1, nu, nv)
        for i in range(nu):
            for j in range(nv):
                surface.Points[(i, j)] = rhino.Point4d(*map(float, homogeneous[i, j]))
        for knots, target in zip(shape.knots, (surface.KnotsU, surface.KnotsV), strict=True):
            for i, knot in enumerate(np.asarray(knots)[1:-1]):
                target[i] = float(knot)
        model.Objects.AddSurface(surface)
    if not model.Write(str(path), 7):
        raise ValueError(f"openNURBS could not write {path}")


def _read_3dm(path):
    rhino = _import("rhino3dm", "rhino3dm")
    model = rhino.File3dm.Read(str(path))
    if model is None:
        raise ValueError(f"openNURBS could not read {path} as .3dm")
    shapes = []
    for item in model.Objects:
        geometry = item.Geometry
        if isinstance(geometry, rhino.NurbsCurve):
            h = np.array(
                [
                    [p.X, p.Y, p.Z, p.W]
                    for p in (geometry.Points[i] for i in range(len(geometry.Points)))
                ]
            )
            inner = [geometry.Knots[i] for i in range(len(geometry.Knots))]
            knots = np.array([inner[0], *inner, inner[-1]])
            shapes.append(_from_parts(h[:, :3] / h[:, 3:], h[:, 3], knots, geometry.Order - 1))
        elif isinstance(geometry, rhino.NurbsSurface):
            nu, nv = geometry.Points.CountU, geometry.Points.CountV
            h = np.array(
                [[[*_xyzw(geometry.Points[(i, j)])] for j in range(nv)] for i in range(nu)]
            )
            knots = tuple(
                np.array([k[0], *k, k[-1]])
                for k in ([g[i] for i in range(len(g))] for g in (geometry.KnotsU, geometry.KnotsV))
            )
            degree = (geometry.OrderU - 1, geometry.OrderV - 1)
            shapes.append(_from_parts(h[..., :3] / h[..., 3:], h[..., 3], knots, degree))
    return shapes


def _xyzw(point):
    return point.X, point.Y, point.Z, point.W


_FORMATS = {".step": (_write_step, _read_step), ".stp": (_write_step, _read_step),
            ".3dm": (_write_3dm, _read_3dm)}  # fmt: skip


def _format(path):
    suffix = Path(path).suffix.lower()
    if suffix not in _FORMATS:
        raise ValueError(
            f"unknown CAD format {suffix!r} of {path}; expected one of {sorted(_FORMATS)}"
        )
    return _FORMATS[suffix]


def write_cad(path, shapes) -> None:
    """Write curves and surfaces to a CAD file; the format follows the extension: `.step` /
    `.stp` (OpenCascade) or `.3dm` (openNURBS).

    **Arguments:**

    - `path`: the file to write.
    - `shapes`: a `NURBSCurve` or `NURBSSurface`, or a sequence of them (2D or 3D).
    """
    _format(path)[0](path, _shapes(shapes))


def read_cad(path) -> list:
    """The NURBS curves and surfaces of a CAD file (`.step`, `.stp` or `.3dm`).

    **Returns:**

    A list of `NURBSCurve` (in space) and `NURBSSurface`; rational where the file's weights
    are not all 1.
    """
    if not Path(path).is_file():
        raise ValueError(f"no such CAD file: {path}")
    return _format(path)[1](path)
