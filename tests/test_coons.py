"""Bilinear and Coons patches against their boundary curves, corners and closed forms."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffnurbs as dn
from diffnurbs import CoonsPatch, bilinear_patch

rng = np.random.default_rng(2)
T = np.array([0.0, 0.13, 0.5, 0.77, 1.0])
CORNERS = rng.normal(size=(4, 3))  # p00, p10, p01, p11


def test_bilinear_corners_and_ruled_edges():
    p00, p10, p01, p11 = CORNERS
    patch = bilinear_patch(p00, p10, p01, p11)
    assert patch.degree == (1, 1)
    np.testing.assert_allclose(patch([0, 1, 0, 1], [0, 0, 1, 1]), CORNERS, atol=1e-14)
    u, v = np.meshgrid(T, T, indexing="ij")
    # The seed's formula: R0, R1 along u, then blend in v.
    r0 = (1 - u)[..., None] * p00 + u[..., None] * p10
    r1 = (1 - u)[..., None] * p01 + u[..., None] * p11
    expected = (1 - v)[..., None] * r0 + v[..., None] * r1
    np.testing.assert_allclose(patch(u, v), expected, atol=1e-14)
    # Every isoparametric line is straight: its second derivative vanishes.
    second = patch.derivatives(u, v, 2)
    np.testing.assert_allclose(second[..., 2, 0, :], 0, atol=1e-13)
    np.testing.assert_allclose(second[..., 0, 2, :], 0, atol=1e-13)


def test_bilinear_rejects_bad_corners():
    with pytest.raises(ValueError, match="same dimension"):
        bilinear_patch([0, 0], [1, 0], [0, 1], [1, 1, 0])
    with pytest.raises(ValueError, match="p10 must have 1 dimensions"):
        bilinear_patch([0, 0], [[1, 0]], [0, 1], [1, 1])


def _random_curve(start, end, n, degree, domain, rational):
    points = rng.normal(size=(n, len(start)))
    points[0], points[-1] = start, end
    a, b = domain
    knots = np.concatenate(
        [[a] * (degree + 1), np.sort(rng.uniform(a, b, n - degree - 1)), [b] * (degree + 1)]
    )
    weights = rng.uniform(0.5, 2.0, n) if rational else None
    return dn.NURBSCurve(points, degree, knots, weights)


def _random_boundary(rational=True):
    """Curves of mixed degrees and domains; `c0` and `d0` rational unless told otherwise."""
    p00, p10, p01, p11 = CORNERS
    c0 = _random_curve(p00, p10, 6, 3, (2.0, 5.0), rational)
    c1 = _random_curve(p01, p11, 4, 2, (-1.0, 0.5), False)
    d0 = _random_curve(p00, p01, 5, 2, (0.0, 1.0), rational)
    d1 = _random_curve(p10, p11, 7, 4, (3.0, 3.25), False)
    return c0, c1, d0, d1


def _on_unit(curve, t):
    a, b = curve.domain
    return curve(jnp.clip((1 - t) * a + t * b, a, b))


# The four boundary oracles in one compiled function (compiling is most of the test time).
_on_unit_all = eqx.filter_jit(lambda curves, t: [_on_unit(c, t) for c in curves])


def test_coons_reproduces_the_boundary_curves():
    c0, c1, d0, d1 = _random_boundary()
    patch = CoonsPatch(c0, c1, d0, d1)
    assert isinstance(patch, CoonsPatch)
    on_c0, on_c1, on_d0, on_d1 = _on_unit_all((c0, c1, d0, d1), T)
    np.testing.assert_allclose(patch(T, 0.0), on_c0, atol=1e-13)
    np.testing.assert_allclose(patch(T, 1.0), on_c1, atol=1e-13)
    np.testing.assert_allclose(patch(0.0, T), on_d0, atol=1e-13)
    np.testing.assert_allclose(patch(1.0, T), on_d1, atol=1e-13)
    np.testing.assert_allclose(
        patch([0, 1, 0, 1, 0], [0, 0, 1, 1, 0]), CORNERS[[0, 1, 2, 3, 0]], atol=1e-13
    )


def test_coons_interior_is_the_naive_formula_and_grid_matches_call():
    c0, c1, d0, d1 = _random_boundary()
    patch = CoonsPatch(c0, c1, d0, d1)
    p00, p10, p01, p11 = CORNERS
    u, v = np.meshgrid(T, T, indexing="ij")
    on_c0, on_c1, on_d0, on_d1 = _on_unit_all((c0, c1, d0, d1), T)
    expected = (
        (1 - v)[..., None] * on_c0[:, None]
        + v[..., None] * on_c1[:, None]
        + (1 - u)[..., None] * on_d0[None, :]
        + u[..., None] * on_d1[None, :]
        - ((1 - u) * (1 - v))[..., None] * p00
        - ((1 - u) * v)[..., None] * p01
        - (u * (1 - v))[..., None] * p10
        - (u * v)[..., None] * p11
    )
    np.testing.assert_allclose(patch(u, v), expected, atol=1e-13)
    np.testing.assert_allclose(patch.grid(T, T), expected, atol=1e-13)
    np.testing.assert_allclose(patch(T[:, None], T[None, :]), expected, atol=1e-13)


def test_coons_of_straight_edges_is_the_bilinear_patch():
    p00, p10, p01, p11 = CORNERS

    def line(a, b):
        return dn.NURBSCurve([a, b], 1)

    patch = CoonsPatch(line(p00, p10), line(p01, p11), line(p00, p01), line(p10, p11))
    u, v = np.meshgrid(T, T, indexing="ij")
    np.testing.assert_allclose(patch(u, v), bilinear_patch(*CORNERS)(u, v), atol=1e-14)


def test_coons_annular_sector_is_exact():
    # Arcs of radius 1 and 2 joined by radial segments: L_d equals the corner blend, so
    # S(u, v) = (1 + v) c0(u) and |S| = 1 + v exactly.
    inner, outer = dn.arc(1.0, 0.0, math.pi / 2), dn.arc(2.0, 0.0, math.pi / 2)
    left = dn.NURBSCurve([[1.0, 0.0], [2.0, 0.0]], 1)
    right = dn.NURBSCurve([[0.0, 1.0], [0.0, 2.0]], 1)
    patch = CoonsPatch(inner, outer, left, right)
    grid = patch.grid(T, T)
    np.testing.assert_allclose(np.linalg.norm(grid, axis=-1), np.broadcast_to(1 + T, (5, 5)))
    np.testing.assert_allclose(grid, (1 + T)[None, :, None] * inner(T)[:, None, :], atol=1e-14)


def test_coons_of_four_circle_arcs():
    # The square (-1, 0), (1, 0), (-1, 2), (1, 2) with bulging sides: the four quarters of
    # the circle of radius sqrt(2) about (0, 1), so the patch fills the disc. Edges stay on
    # the circle; the centre of the patch is the centre by the two mirror symmetries.
    r = math.sqrt(2.0)
    q = math.pi / 4
    bottom = dn.arc(r, -3 * q, -q, center=(0.0, 1.0))  # from (-1, 0) to (1, 0)
    top = dn.arc(r, 3 * q, q, center=(0.0, 1.0))  # from (-1, 2) to (1, 2)
    left = dn.arc(r, 5 * q, 3 * q, center=(0.0, 1.0))  # from (-1, 0) to (-1, 2)
    right = dn.arc(r, -q, q, center=(0.0, 1.0))  # from (1, 0) to (1, 2)
    patch = CoonsPatch(bottom, top, left, right, tol=1e-12)
    np.testing.assert_allclose(
        patch([0, 1, 0, 1], [0, 0, 1, 1]), [[-1, 0], [1, 0], [-1, 2], [1, 2]], atol=1e-14
    )
    for points in (patch(T, 0.0), patch(T, 1.0), patch(0.0, T), patch(1.0, T)):
        np.testing.assert_allclose(np.linalg.norm(points - np.array([0.0, 1.0]), axis=-1), r)
    np.testing.assert_allclose(patch(0.5, 0.5), [0.0, 1.0], atol=1e-14)
    # Mirror x -> -x maps u -> 1 - u; mirror y -> 2 - y maps v -> 1 - v.
    u, v = np.meshgrid(T, T, indexing="ij")
    s, mirrored_u, mirrored_v = patch(u, v), patch(1 - u, v), patch(u, 1 - v)
    np.testing.assert_allclose(mirrored_u, s * np.array([-1, 1]), atol=1e-13)
    np.testing.assert_allclose(mirrored_v, np.array([0, 2]) + s * np.array([1, -1]), atol=1e-13)


def test_coons_gradient_matches_finite_differences_and_jits():
    c0, c1, d0, d1 = _random_boundary()

    @jax.jit
    def loss(points):
        curve = dn.NURBSCurve(points, c0.degree, c0.knots, c0.weights)
        # The corners move with c0's ends, so a loose tolerance keeps the patch valid.
        return jnp.sum(CoonsPatch(curve, c1, d0, d1, tol=1.0)(0.3, 0.6) ** 2)

    points = c0.control_points
    grad = jax.grad(loss)(points)
    assert np.all(np.isfinite(grad))
    h, direction = 1e-6, rng.normal(size=points.shape)
    fd = (loss(points + h * direction) - loss(points - h * direction)) / (2 * h)
    np.testing.assert_allclose(np.sum(grad * direction), fd, rtol=1e-6)


def test_coons_checks_corners_under_tracing():
    c0, c1, d0, d1 = _random_boundary()

    @jax.jit
    def build(points):
        curve = dn.NURBSCurve(points, c0.degree, c0.knots, c0.weights)
        return CoonsPatch(curve, c1, d0, d1).corners

    build(c0.control_points)
    with pytest.raises(Exception, match="do not meet"):
        build(c0.control_points.at[0].add(1.0))


def test_coons_float32():
    with jax.enable_x64(False):
        left = dn.NURBSCurve(np.array([[1.0, 0.0], [2.0, 0.0]], np.float32), 1)
        right = dn.NURBSCurve(np.array([[0.0, 1.0], [0.0, 2.0]], np.float32), 1)
        inner, outer = dn.arc(1.0, 0.0, math.pi / 2), dn.arc(2.0, 0.0, math.pi / 2)
        patch = CoonsPatch(inner, outer, left, right, tol=1e-6)
        values = patch.grid(np.float32(T), np.float32(T))
        assert values.dtype == jnp.float32
        np.testing.assert_allclose(np.linalg.norm(values, axis=-1)[0], 1 + T, rtol=1e-6)


def test_coons_errors():
    c0, c1, d0, d1 = _random_boundary()
    moved = dn.NURBSCurve(d1.control_points.at[0, 0].add(0.01), d1.degree, d1.knots)
    with pytest.raises(ValueError, match=r"corner \(u, v\) = \(1, 0\): c0 at its end and d1"):
        CoonsPatch(c0, c1, d0, moved)
    with pytest.raises(ValueError, match=r"0\.01 apart"):
        CoonsPatch(c0, c1, d0, moved)
    flipped = dn.NURBSCurve(c1.control_points[::-1], c1.degree)
    with pytest.raises(ValueError, match=r"corner \(u, v\) = \(0, 1\)"):
        CoonsPatch(c0, flipped, d0, d1)
    with pytest.raises(ValueError, match="d0 must be a NURBSCurve"):
        CoonsPatch(c0, c1, d0.control_points, d1)
    flat = dn.NURBSCurve(d0.control_points[:, :2], d0.degree, d0.knots)
    with pytest.raises(ValueError, match="same dimension"):
        CoonsPatch(c0, c1, flat, d1)
    with pytest.raises(ValueError, match="tol must be a number >= 0"):
        CoonsPatch(c0, c1, d0, d1, tol=-1.0)
    patch = CoonsPatch(c0, c1, d0, d1)
    with pytest.raises(ValueError, match=r"u must lie in the domain \[0.0, 1.0\]"):
        patch(1.5, 0.5)
    with pytest.raises(ValueError, match="v must lie in the domain"):
        patch.grid(T, [-0.1])
    with pytest.raises(ValueError, match="us must have 1 dimensions"):
        patch.grid(T[:, None], T)


def test_to_nurbs_is_the_same_patch():
    c0, c1, d0, d1 = _random_boundary(rational=False)
    patch = CoonsPatch(c0, c1, d0, d1)
    surface = patch.to_nurbs()
    assert isinstance(surface, dn.NURBSSurface)
    assert surface.degree == (3, 4)
    np.testing.assert_allclose(surface.grid(T, T), patch.grid(T, T), atol=1e-12)


def test_to_nurbs_refuses_rational_boundaries():
    with pytest.raises(ValueError, match="non-rational boundary curves"):
        CoonsPatch(*_random_boundary()).to_nurbs()
