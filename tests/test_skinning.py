"""`loft` (skinning through sections) and `gordon` (through a curve network).

Oracles: the defining property (each section, each network curve lies on the surface, to
rounding, checked at 101 parameters), exact geometry (circles lofted into a cone stay circles,
a ruled loft of two lines is the bilinear patch), and a network cut from a known surface.
"""

import jax.numpy as jnp
import numpy as np
import pytest

import diffnurbs as dn

U = np.linspace(0.0, 1.0, 101)


def on_unit_domain(curve):
    lower, upper = curve.domain
    return dn.NURBSCurve(
        curve.control_points, curve.degree, (curve.knots - lower) / (upper - lower), curve.weights
    )


def test_sections_of_any_degree_and_knots_lie_on_the_loft():
    rng = np.random.default_rng(0)
    sections = [
        dn.NURBSCurve(np.c_[rng.normal(size=(5 + k, 2)), np.full(5 + k, float(k))], 2 + k % 2)
        for k in range(4)
    ]
    surface, v = dn.loft(sections, full_output=True)
    assert surface.degree == (3, 3) and v[0] == 0 and v[-1] == 1
    for k, section in enumerate(sections):
        on = surface(U, np.full_like(U, v[k]))
        np.testing.assert_allclose(on, on_unit_domain(section)(U), atol=1e-13)


def test_rational_sections_stay_exact():
    circles = [dn.circle(1.0 + 0.5 * k, center=(0.0, 0.0, 2.0 * k)) for k in range(3)]
    surface = dn.loft(circles, degree_v=1, parameters=[0.0, 0.5, 1.0])
    uu, vv = np.meshgrid(U, np.linspace(0, 1, 21), indexing="ij")
    points = np.asarray(surface(uu, vv))
    # A ruled loft of coaxial circles with radius linear in height is a cone: radius 1 + z / 4.
    radius = np.linalg.norm(points[..., :2], axis=-1)
    np.testing.assert_allclose(radius, 1 + points[..., 2] / 4, atol=1e-14)


def test_rational_and_polynomial_sections_together():
    # The polynomial section gets weights 1: all sections interpolated in homogeneous form.
    circle = dn.circle(1.0)
    lift = [
        np.c_[np.asarray(circle.control_points) * r, np.full(9, z)] for r, z in ((1, 0), (1.5, 2))
    ]
    sections = [
        dn.NURBSCurve(lift[0], 2, circle.knots, circle.weights),
        dn.NURBSCurve(np.c_[np.random.default_rng(1).normal(size=(6, 2)), np.ones(6)], 3),
        dn.NURBSCurve(lift[1], 2, circle.knots, circle.weights),
    ]
    surface, v = dn.loft(sections, degree_v=2, full_output=True)
    for section, v_k in zip(sections, np.asarray(v), strict=True):
        np.testing.assert_allclose(surface(U, v_k), section(U), atol=1e-14)


def test_two_lines_give_the_bilinear_patch():
    bottom = dn.NURBSCurve(np.array([[0.0, 0, 0], [2, 0, 0]]), 1)
    top = dn.NURBSCurve(np.array([[0.0, 1, 1], [2, 1, -1]]), 1)
    surface = dn.loft([bottom, top])
    bilinear = dn.bilinear_patch([0.0, 0, 0], [2, 0, 0], [0.0, 1, 1], [2, 1, -1])
    uu, vv = np.meshgrid(U, U, indexing="ij")
    np.testing.assert_allclose(surface(uu, vv), bilinear(uu, vv), atol=1e-15)


def isocurves(surface):
    """The curves v = v0 and u = u0 of a non-rational surface, as NURBS curves."""
    points = np.asarray(surface.control_points)
    (p, q), (knots_u, knots_v) = surface.degree, surface.knots

    def along_u(v0):
        row = np.asarray(dn.basis_matrix(knots_v, q, jnp.asarray([v0])))[0]
        return dn.NURBSCurve(np.einsum("j,ijd->id", row, points), p, knots_u)

    def along_v(u0):
        row = np.asarray(dn.basis_matrix(knots_u, p, jnp.asarray([u0])))[0]
        return dn.NURBSCurve(np.einsum("i,ijd->jd", row, points), q, knots_v)

    return along_u, along_v


@pytest.mark.parametrize(("us", "vs"), [([0, 0.3, 0.7, 1], [0, 0.5, 1]), ([0, 1], [0, 0.2, 1])])
def test_every_curve_of_the_network_lies_on_the_gordon_surface(us, vs):
    base = dn.NURBSSurface(np.random.default_rng(1).normal(size=(5, 4, 3)), (3, 2))
    along_u, along_v = isocurves(base)
    u_curves, v_curves = [along_u(v) for v in vs], [along_v(u) for u in us]
    surface = dn.gordon(u_curves, v_curves)
    for v0, curve in zip(vs, u_curves, strict=True):
        np.testing.assert_allclose(surface(U, np.full_like(U, v0)), curve(U), atol=1e-13)
    for u0, curve in zip(us, v_curves, strict=True):
        np.testing.assert_allclose(surface(np.full_like(U, u0), U), curve(U), atol=1e-13)


def test_a_dense_network_of_a_bilinear_surface_gives_it_back():
    base = dn.bilinear_patch([0.0, 0, 0], [1, 0, 0.3], [0, 1, -0.2], [1, 1, 1])
    along_u, along_v = isocurves(base)
    grid = [0.0, 0.5, 1.0]
    surface = dn.gordon([along_u(v) for v in grid], [along_v(u) for u in grid])
    uu, vv = np.meshgrid(U, U, indexing="ij")
    np.testing.assert_allclose(surface(uu, vv), base(uu, vv), atol=1e-14)


def test_bad_networks_are_named():
    base = dn.NURBSSurface(np.random.default_rng(2).normal(size=(4, 4, 3)), (2, 2))
    along_u, along_v = isocurves(base)
    lifted = np.asarray(along_v(0.5).control_points) + np.array([0, 0, 1.0])
    apart = dn.NURBSCurve(lifted, 2, base.knots_v)
    with pytest.raises(ValueError, match=r"do not meet: they pass"):
        dn.gordon([along_u(0.0), along_u(1.0)], [along_v(0.0), apart])
    with pytest.raises(ValueError, match="at least 2 NURBSCurve"):
        dn.loft([along_u(0.0)])
    with pytest.raises(ValueError, match="one dimension"):
        dn.loft([along_u(0.0), dn.NURBSCurve(np.eye(2), 1)])
    rational = dn.circle(1.0, center=(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="non-rational"):
        dn.gordon([rational, rational], [along_v(0.0), along_v(1.0)])
