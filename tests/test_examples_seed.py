"""The worked examples of seed 000 (B-spline curve, 9-point NURBS circle, 5x3 surface).

Every expected value here is computed independently of the library: the curve example
against its two quadratic pieces derived by hand from the Cox-de Boor recursion, the
circle against exact geometry, the surface against a naive double sum of `cox_de_boor`.
"""

import math

import jax
import numpy as np
import pytest

import diffnurbs as dn

jax.config.update("jax_enable_x64", True)

# ---------------------------------------------------------------------------------------
# Seed 000 §1.4.1: P = (0,0), (0,1), (1,2), (3,0); U = {0,0,0,1/4,1,1,1}; p = 2.
#
# On [0, 1/4):  N_{0,2} = (1 - 4u)^2,  N_{1,2} = 8u - 20u^2,  N_{2,2} = 4u^2
#               C(u) = (4u^2, 8u - 12u^2)
# On [1/4, 1]:  N_{1,2} = 4(1 - u)^2 / 3,  N_{2,2} = 4(1 - u)(7u - 1) / 9,  N_{3,2} = (4u - 1)^2 / 9
#               C(u) = ((20u^2 + 8u - 1) / 9, 4(1 - u)(11u + 1) / 9)
# Both pieces meet at C(1/4) = (1/4, 5/4) with the common tangent C'(1/4) = (2, 2): C^1.
# ---------------------------------------------------------------------------------------
CURVE_POINTS = np.array([(0, 0), (0, 1), (1, 2), (3, 0)], dtype=float)
CURVE_KNOTS = np.array([0, 0, 0, 0.25, 1, 1, 1])


def seed_curve_by_hand(u):
    """The piecewise polynomial of the seed's B-spline curve, and its first derivative."""
    u = np.asarray(u, dtype=float)
    left = u < 0.25
    x = np.where(left, 4 * u**2, (20 * u**2 + 8 * u - 1) / 9)
    y = np.where(left, 8 * u - 12 * u**2, 4 * (1 - u) * (11 * u + 1) / 9)
    dx = np.where(left, 8 * u, (40 * u + 8) / 9)
    dy = np.where(left, 8 - 24 * u, 4 * (10 - 22 * u) / 9)
    return np.stack([x, y], -1), np.stack([dx, dy], -1)


@pytest.mark.parametrize(
    "u, expected",
    [(0.0, (0, 0)), (0.25, (1 / 4, 5 / 4)), (0.5, (8 / 9, 13 / 9)), (1.0, (3, 0))],
)
def test_seed_bspline_curve_values(u, expected):
    curve = dn.NURBSCurve(CURVE_POINTS, 2, CURVE_KNOTS)
    np.testing.assert_allclose(curve(u), expected, rtol=0, atol=1e-15)
    np.testing.assert_allclose(seed_curve_by_hand(u)[0], expected, rtol=0, atol=1e-15)


def test_seed_bspline_curve_matches_pieces_everywhere():
    curve = dn.NURBSCurve(CURVE_POINTS, 2, CURVE_KNOTS)
    u = np.concatenate([np.linspace(0, 1, 401), [0.25 - 1e-12, 0.25 + 1e-12]])
    points, tangents = seed_curve_by_hand(u)
    np.testing.assert_allclose(curve(u), points, atol=1e-14)
    np.testing.assert_allclose(curve.derivatives(u, 1)[:, 1], tangents, atol=1e-13)


def test_seed_bspline_curve_basis_by_hand():
    """The hand-derived basis functions against the library's non-zero ones."""
    u = np.array([0.0, 0.1, 0.2, 0.25, 0.5, 0.9, 1.0])
    span, funs = dn.basis_funs(CURVE_KNOTS, 2, u)
    left = u < 0.25
    by_hand = np.where(
        left[:, None],
        np.stack([(1 - 4 * u) ** 2, 8 * u - 20 * u**2, 4 * u**2], -1),
        np.stack([4 * (1 - u) ** 2 / 3, 4 * (1 - u) * (7 * u - 1) / 9, (4 * u - 1) ** 2 / 9], -1),
    )
    np.testing.assert_array_equal(span, np.where(left, 2, 3))
    np.testing.assert_allclose(funs, by_hand, atol=1e-15)


def test_seed_bspline_curve_is_c1_not_c2_at_the_knot():
    curve = dn.NURBSCurve(CURVE_POINTS, 2, CURVE_KNOTS)
    eps = 1e-9
    before, after = curve.derivatives(np.array([0.25 - eps, 0.25 + eps]), 2)
    np.testing.assert_allclose(before[1], (2, 2), atol=1e-7)
    np.testing.assert_allclose(after[1], (2, 2), atol=1e-7)
    # Second derivatives of the two pieces: (8, -24) on the left, (40/9, -88/9) on the right.
    np.testing.assert_allclose(before[2], (8, -24), atol=1e-12)
    np.testing.assert_allclose(after[2], (40 / 9, -88 / 9), atol=1e-12)


# ---------------------------------------------------------------------------------------
# Seed 000 §1.5.1: the circle from 9 control points (square vertices and edge midpoints),
# knots {0,0,0,1/4,1/4,1/2,1/2,3/4,3/4,1,1,1}, weights 1 (even i) and sqrt(2)/2 (odd i).
# ---------------------------------------------------------------------------------------
SQUARE = np.array(
    [(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0)], dtype=float
)
CIRCLE_KNOTS = np.array([0, 0, 0, 0.25, 0.25, 0.5, 0.5, 0.75, 0.75, 1, 1, 1])
CIRCLE_WEIGHTS = np.where(np.arange(9) % 2 == 0, 1.0, math.sqrt(2) / 2)


def circle(radius=1.0, center=(0.0, 0.0)):
    return dn.NURBSCurve(radius * SQUARE + np.asarray(center), 2, CIRCLE_KNOTS, CIRCLE_WEIGHTS)


CIRCLES = [(1.0, (0.0, 0.0)), (2.5, (3.0, -1.0)), (1e-3, (10.0, 20.0))]


@pytest.mark.parametrize("radius, center", CIRCLES)
def test_nine_point_circle_radius(radius, center):
    u = np.linspace(0, 1, 10_001)
    distance = np.linalg.norm(np.asarray(circle(radius, center)(u)) - center, axis=-1)
    scale = max(radius, np.linalg.norm(center))  # rounding is relative to the coordinates
    assert np.max(np.abs(distance - radius)) <= 1e-14 * scale


@pytest.mark.parametrize("radius, center", CIRCLES)
def test_nine_point_circle_curvature(radius, center):
    u = np.concatenate([np.linspace(0, 1, 1001), CIRCLE_KNOTS])
    # Counter-clockwise, so the signed curvature is +1/r. The derivatives lose the digits of
    # the coordinates that the radius does not use: the tolerance scales with |center| / r.
    rtol = 1e-13 * max(1.0, np.linalg.norm(center) / radius)
    np.testing.assert_allclose(circle(radius, center).curvature(u), 1 / radius, rtol=rtol)


# Compiled once for all the circles (same structure): the quadrature is the costly part.
_arc_length = jax.jit(lambda curve, a, b: curve.arc_length(a, b))


@pytest.mark.parametrize("radius, center", CIRCLES)
def test_nine_point_circle_arc_length(radius, center):
    curve = circle(radius, center)
    np.testing.assert_allclose(_arc_length(curve, 0.0, 1.0), 2 * math.pi * radius, rtol=1e-12)
    # Each quarter (one rational Bezier arc between double knots) is a quarter of it.
    np.testing.assert_allclose(_arc_length(curve, 0.25, 0.5), math.pi * radius / 2, rtol=1e-12)


def test_nine_point_circle_passes_through_even_control_points():
    u = np.array([0, 0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(circle()(u), SQUARE[::2], atol=1e-15)


def test_nine_point_circle_speed_is_not_constant():
    """The circle is exact, but its parametrization is not by arc length."""
    u = np.linspace(0, 1, 401)
    speed = np.linalg.norm(circle().derivatives(u, 1)[:, 1], axis=-1)
    # On a quarter: |C'| = 4 sqrt(2) at the knots (the points of the circle on the sides of
    # the square) and 16 (sqrt(2) - 1) in the middle of the span: a ratio of 4 - 2 sqrt(2).
    np.testing.assert_allclose(speed.min(), 4 * math.sqrt(2), rtol=1e-12)
    np.testing.assert_allclose(speed.max(), 16 * (math.sqrt(2) - 1), rtol=1e-12)
    np.testing.assert_allclose(speed[50], speed.max(), rtol=1e-12)  # u = 1/8, mid-span


# ---------------------------------------------------------------------------------------
# Seed 000 §1.4.4: the 5x3 B-spline surface, U = {0,0,0,1/2,1/2,1,1,1}, V = {0,0,0,1,1,1}.
# ---------------------------------------------------------------------------------------
SURFACE_POINTS = np.array(
    [
        [(0, 0, 0), (1, 0, 0), (2, 0, 0)],
        [(0, 0.5, 1.3), (1, 0.5, 1.2), (2, 0.5, 1.3)],
        [(0, 1, 0), (1, 1, 0), (2, 1, 0)],
        [(0, 1.5, 1.3), (1, 1.5, 1.2), (2, 1.5, 1.3)],
        [(0, 2, 0), (1, 2, 0), (2, 2, 0)],
    ],
    dtype=float,
)
SURFACE_KNOTS = (np.array([0, 0, 0, 0.5, 0.5, 1, 1, 1]), np.array([0, 0, 0, 1, 1, 1]))


def seed_surface():
    return dn.NURBSSurface(SURFACE_POINTS, (2, 2), SURFACE_KNOTS)


# Compiled once per (degree, i): the eager recursion would dispatch 2^p tiny operations.
_cox_de_boor = jax.jit(dn.cox_de_boor, static_argnums=(1, 2))


def naive_surface(u, v):
    """`sum_i sum_j N_{i,2}(u) N_{j,2}(v) P_ij` with the recursive Cox-de Boor functions."""
    knots_u, knots_v = SURFACE_KNOTS
    nu = np.stack([np.asarray(_cox_de_boor(knots_u, 2, i, u)) for i in range(5)], -1)
    nv = np.stack([np.asarray(_cox_de_boor(knots_v, 2, j, v)) for j in range(3)], -1)
    return np.einsum("...i,...j,ijd->...d", nu, nv, SURFACE_POINTS)


def test_seed_surface_interpolates_corners():
    surface = seed_surface()
    u, v = np.array([0.0, 0.0, 1.0, 1.0]), np.array([0.0, 1.0, 0.0, 1.0])
    corners = SURFACE_POINTS[[0, 0, 4, 4], [0, 2, 0, 2]]
    np.testing.assert_allclose(surface(u, v), corners, atol=1e-15)


def test_seed_surface_interpolates_middle_row_at_double_knot():
    """At the double knot u = 1/2 only N_{2,2}(u) = 1 is non-zero: S(1/2, v) is the
    quadratic Bezier curve of the middle row, the straight line (2v, 1, 0)."""
    v = np.linspace(0, 1, 11)
    row = np.stack([2 * v, np.ones_like(v), np.zeros_like(v)], -1)
    np.testing.assert_allclose(seed_surface()(np.full_like(v, 0.5), v), row, atol=1e-15)
    np.testing.assert_allclose(seed_surface()(0.5, 0.5), SURFACE_POINTS[2, 1], atol=1e-15)


def test_seed_surface_matches_naive_double_sum():
    rng = np.random.default_rng(0)
    u = np.concatenate([[0, 0.5, 1, 0.5 - 1e-12, 0.5 + 1e-12], rng.uniform(0, 1, 60)])
    v = np.concatenate([[0, 0.5, 1, 1, 0], rng.uniform(0, 1, 60)])
    np.testing.assert_allclose(seed_surface()(u, v), naive_surface(u, v), atol=1e-14)


def test_seed_surface_is_symmetric():
    """The net is symmetric under x -> 2 - x and y -> 2 - y, and so is the surface."""
    rng = np.random.default_rng(1)
    u, v = rng.uniform(0, 1, 50), rng.uniform(0, 1, 50)
    surface = seed_surface()
    s = np.asarray(surface(u, v))
    mirrored_v = np.asarray(surface(u, 1 - v))
    mirrored_u = np.asarray(surface(1 - u, v))
    np.testing.assert_allclose(mirrored_v, s * [-1, 1, 1] + [2, 0, 0], atol=1e-14)
    np.testing.assert_allclose(mirrored_u, s * [1, -1, 1] + [0, 2, 0], atol=1e-14)
