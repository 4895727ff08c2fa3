"""CAD exchange through OpenCascade (STEP) and openNURBS (.3dm): curves and surfaces,
rational or not, 2D or 3D, go out and come back with their degrees, knots and weights.

Oracles: the shapes themselves, evaluated at 201 (or 201 x 201) parameters before and after;
each library's own evaluation of what it read (OpenCascade's `D0`, openNURBS's `PointAt`).
"""

import numpy as np
import pytest

import diffnurbs as dn

RNG = np.random.default_rng(0)
SPACE = dn.NURBSCurve(
    RNG.normal(size=(7, 3)), 3, knots=np.array([0, 0, 0, 0, 1 / 3, 0.5, 0.5, 1, 1, 1, 1.0]),
    weights=RNG.uniform(0.5, 2.0, 7),
)  # fmt: skip
PLANAR = dn.NURBSCurve(RNG.normal(size=(5, 2)), 2)
SURFACE = dn.NURBSSurface(RNG.normal(size=(5, 4, 3)), (3, 2), weights=RNG.uniform(0.5, 2.0, (5, 4)))
U = np.linspace(0.0, 1.0, 201)


@pytest.mark.parametrize("suffix", [".step", ".stp", ".3dm"])
def test_round_trip(tmp_path, suffix):
    path = tmp_path / f"shapes{suffix}"
    # Closed shapes too: OpenCascade reads them as periodic, read_cad clamps them back.
    closed = dn.revolve(SPACE, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    dn.io.write_cad(path, [SPACE, PLANAR, dn.circle(1.0), SURFACE, closed])  # curves first
    space, planar, circle, surface, revolved = dn.io.read_cad(path)
    # STEP writes 12 significant digits; openNURBS stores doubles.
    atol = 1e-12 * (1 + np.abs(SURFACE.control_points).max()) if "st" in suffix else 0.0
    assert space.degree == 3 and space.rational
    np.testing.assert_allclose(space.knots, SPACE.knots, atol=atol)
    np.testing.assert_allclose(space(U), SPACE(U), atol=atol)
    assert planar.dim == 3 and not planar.rational
    np.testing.assert_allclose(planar(U), np.c_[PLANAR(U), np.zeros(201)], atol=atol)
    uu, vv = np.meshgrid(U, U, indexing="ij")
    assert surface.degree == (3, 2)
    np.testing.assert_allclose(surface(uu, vv), SURFACE(uu, vv), atol=atol)
    np.testing.assert_allclose(np.linalg.norm(circle(U)[:, :2], axis=1), 1.0, atol=atol + 1e-15)
    np.testing.assert_allclose(circle.knots, dn.circle(1.0).knots, atol=atol)
    np.testing.assert_allclose(circle.weights, dn.circle(1.0).weights, atol=atol)
    for got, want in zip(revolved.knots, closed.knots, strict=True):
        np.testing.assert_allclose(got, want, atol=atol)
    np.testing.assert_allclose(revolved.weights, closed.weights, atol=atol)
    np.testing.assert_allclose(revolved(uu, vv), closed(uu, vv), atol=atol)


def test_the_other_libraries_read_the_same_points(tmp_path):
    import rhino3dm
    from OCP.BRep import BRep_Tool
    from OCP.STEPControl import STEPControl_Reader
    from OCP.TopAbs import TopAbs_EDGE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    dn.io.write_cad(tmp_path / "c.3dm", SPACE)
    curve = rhino3dm.File3dm.Read(str(tmp_path / "c.3dm")).Objects[0].Geometry
    for u in (0.1, 1 / 3, 0.5, 0.9):
        point = curve.PointAt(u)
        np.testing.assert_allclose([point.X, point.Y, point.Z], SPACE(u), atol=1e-14)
    dn.io.write_cad(tmp_path / "c.step", SPACE)
    reader = STEPControl_Reader()
    reader.ReadFile(str(tmp_path / "c.step"))
    reader.TransferRoots()
    edge = TopoDS.Edge(TopExp_Explorer(reader.OneShape(), TopAbs_EDGE).Current())
    occ = BRep_Tool.Curve_s(edge, 0.0, 1.0)
    for u in (0.1, 1 / 3, 0.5, 0.9):
        point = occ.Value(u)
        np.testing.assert_allclose([point.X(), point.Y(), point.Z()], SPACE(u), atol=1e-11)


def test_bad_input_is_named(tmp_path):
    with pytest.raises(ValueError, match=r"unknown CAD format '\.iges'"):
        dn.io.write_cad(tmp_path / "x.iges", SPACE)
    with pytest.raises(ValueError, match="no such CAD file"):
        dn.io.read_cad(tmp_path / "missing.step")
    with pytest.raises(ValueError, match="must be NURBSCurve or NURBSSurface"):
        dn.io.write_cad(tmp_path / "x.3dm", [np.eye(3)])
    line = dn.NURBSCurve(np.eye(4), 1)
    with pytest.raises(ValueError, match="2D or 3D, got dim = 4"):
        dn.io.write_cad(tmp_path / "x.step", line)


@pytest.mark.parametrize("shape", [SPACE, PLANAR, SURFACE], ids=["space", "planar", "surface"])
def test_to_occ_evaluates_as_the_shape(shape):
    # OpenCascade's own evaluation (D0) of the geometry handed to it.
    from OCP.gp import gp_Pnt

    geometry = dn.io.to_occ(shape)
    point = gp_Pnt()
    if isinstance(shape, dn.NURBSCurve):
        expected = np.asarray(shape(U))
        expected = np.pad(expected, ((0, 0), (0, 3 - expected.shape[1])))
        params = [(u,) for u in U]
    else:
        grid = np.linspace(0.0, 1.0, 21)
        params = [(u, v) for u in grid for v in grid]
        expected = np.asarray(shape(*np.array(params).T))
    got = []
    for args in params:
        geometry.D0(*args, point)
        got.append([point.X(), point.Y(), point.Z()])
    assert np.allclose(got, expected, atol=1e-12)


def test_to_occ_rejects_other_objects():
    with pytest.raises(ValueError, match="NURBSCurve or NURBSSurface"):
        dn.io.to_occ([SPACE])
