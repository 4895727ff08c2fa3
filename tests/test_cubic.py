"""Cubic splines in matrix form: Hermite, cardinal / Catmull-Rom and uniform B-spline curves
against their matrix forms, closed-form blending functions and autodiff."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from diffnurbs import (
    cardinal_spline,
    catmull_rom,
    cubic_matrix,
    hermite_segment,
    matrix_segment,
    uniform_cubic_bspline,
)

rng = np.random.default_rng(2)
POINTS = rng.normal(size=(6, 3))
T = np.concatenate([[0.0, 1.0], rng.uniform(size=9)])


def cardinal_matrix(tension):
    """The cardinal basis matrix for geometry `(P_{k-1}, P_k, P_{k+1}, P_{k+2})`, written out."""
    s = (1 - tension) / 2
    return np.array(
        [[-s, 2 - s, s - 2, s], [2 * s, s - 3, 3 - 2 * s, -s], [-s, 0, s, 0], [0, 1, 0, 0]]
    )


def tangents(points, tension, closed):
    """`m_i = (1 - tension) / 2 (P_{i+1} - P_{i-1})`, one-sided at the ends of an open spline."""
    s = (1 - tension) / 2
    if closed:
        return s * (np.roll(points, -1, 0) - np.roll(points, 1, 0))
    m = np.empty_like(points)
    m[1:-1] = s * (points[2:] - points[:-2])
    m[0] = 2 * s * (points[1] - points[0])
    m[-1] = 2 * s * (points[-1] - points[-2])
    return m


def velocity(curve, u):
    """`C'(u)` at each of the parameters `u` by forward-mode autodiff of the evaluation."""
    return jax.vmap(jax.jacfwd(curve))(jnp.asarray(u, dtype=jnp.float64))


SEED_BSPLINE = np.array([[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 0, 3, 0], [1, 4, 1, 0]]) / 6.0


def power_derivative(order, t):
    """`d^order/dt^order [t^3, t^2, t, 1]`, written out."""
    rows = [[t**3, t**2, t, 1.0], [3 * t**2, 2 * t, 1.0, 0.0], [6 * t, 2.0, 0.0, 0.0]]
    return np.array(rows[order] if order < 3 else [6.0, 0.0, 0.0, 0.0])


def segments(geometries, basis, t=T):
    """`matrix_segment` of each geometry in `geometries` (shape `(count, 4, dim)`)."""
    return jax.vmap(lambda g: matrix_segment(g, basis, t))(jnp.asarray(geometries))


def on_segments(curve, count, t=T):
    """The curve on `k + t` for every segment `k`, shape `(count, len(t), dim)`."""
    return curve(np.arange(count)[:, None] + t)


# --- matrix forms -------------------------------------------------------------------------


def test_hermite_matrix_reproduces_the_hermite_blending_functions():
    g = rng.normal(size=(4, 2))
    h00, h01 = 2 * T**3 - 3 * T**2 + 1, -2 * T**3 + 3 * T**2
    h10, h11 = T**3 - 2 * T**2 + T, T**3 - T**2
    expected = np.outer(h00, g[0]) + np.outer(h01, g[1]) + np.outer(h10, g[2]) + np.outer(h11, g[3])
    np.testing.assert_allclose(matrix_segment(g, "hermite", T), expected, atol=1e-14)
    np.testing.assert_array_equal(cubic_matrix("Hermite"), cubic_matrix("hermite"))


def test_matrix_segment_bases_and_explicit_matrix():
    g = rng.normal(size=(4, 2))
    bernstein = np.stack([(1 - T) ** 3, 3 * T * (1 - T) ** 2, 3 * T**2 * (1 - T), T**3], -1)
    np.testing.assert_allclose(matrix_segment(g, "bezier", T), bernstein @ g, atol=1e-14)
    bspline = (
        np.stack(
            [(1 - T) ** 3, 3 * T**3 - 6 * T**2 + 4, -3 * T**3 + 3 * T**2 + 3 * T + 1, T**3], -1
        )
        / 6
    )
    np.testing.assert_allclose(matrix_segment(g, "bspline", T), bspline @ g, atol=1e-14)
    np.testing.assert_allclose(
        matrix_segment(g, "catmull-rom", T), matrix_segment(g, cardinal_matrix(0.0), T), atol=1e-14
    )
    grid = rng.uniform(size=(3, 5))
    assert matrix_segment(g, "bezier", grid).shape == (3, 5, 2)


def test_matrix_segment_float32():
    g = rng.normal(size=(4, 2)).astype(np.float32)
    out = matrix_segment(g, "hermite", np.float32(0.5))
    assert out.dtype == jnp.float32
    np.testing.assert_allclose(out, matrix_segment(g.astype(float), "hermite", 0.5), rtol=1e-6)


# --- Hermite segment ----------------------------------------------------------------------


def test_hermite_segment_equals_matrix_form_with_end_derivatives():
    p0, p1, m0, m1 = rng.normal(size=(4, 3))
    curve = hermite_segment(p0, p1, m0, m1)
    np.testing.assert_allclose(curve.control_points[1], p0 + m0 / 3, atol=1e-15)
    np.testing.assert_allclose(
        curve(T), matrix_segment(np.stack([p0, p1, m0, m1]), "hermite", T), atol=1e-13
    )
    ders = curve.derivatives(np.array([0.0, 1.0]), 1)
    np.testing.assert_allclose(ders[:, 0], [p0, p1], atol=1e-14)
    np.testing.assert_allclose(ders[:, 1], [m0, m1], atol=1e-13)


# --- cardinal / Catmull-Rom ---------------------------------------------------------------


@pytest.mark.parametrize(
    "tension, closed", [(0.35, False), (-0.5, False), (0.0, True), (0.6, True)]
)
def test_cardinal_spline_equals_its_matrix_form_segment_by_segment(tension, closed):
    curve = cardinal_spline(POINTS, tension, closed)
    n = len(POINTS)
    count = n if closed else n - 1
    assert curve.degree == 3
    np.testing.assert_allclose(curve.domain, [0, count])
    m = tangents(POINTS, tension, closed)
    k = np.arange(count)
    actual = on_segments(curve, count)
    hermite = np.stack([POINTS[k], POINTS[(k + 1) % n], m[k], m[(k + 1) % n]], axis=1)
    np.testing.assert_allclose(actual, segments(hermite, "hermite"), atol=1e-12)
    # The four-point cardinal matrix applies wherever both neighbours exist.
    inner = k if closed else k[1:-1]
    four = POINTS[(inner[:, None] + np.arange(-1, 3)) % n]
    expected = segments(four, cardinal_matrix(tension))
    np.testing.assert_allclose(actual[inner], expected, atol=1e-12)


@pytest.mark.parametrize("closed", [False, True])
def test_catmull_rom_interpolates_and_matches_the_seed_matrix(closed):
    curve = catmull_rom(POINTS, closed)
    np.testing.assert_allclose(curve(np.arange(len(POINTS))), POINTS, atol=1e-13)
    k = np.arange(1, len(POINTS) - 2)
    np.testing.assert_allclose(
        on_segments(curve, len(POINTS) - 2)[1:],
        segments(POINTS[k[:, None] + np.arange(-1, 3)], "catmull-rom"),
        atol=1e-12,
    )


def test_knots_have_multiplicity_three_at_the_joints():
    knots = np.asarray(catmull_rom(POINTS).knots)
    np.testing.assert_array_equal(knots, [0] * 4 + [1] * 3 + [2] * 3 + [3] * 3 + [4] * 3 + [5] * 4)


@pytest.mark.parametrize("tension, closed", [(0.0, False), (0.6, True)])
def test_tangents_at_the_joints_are_the_formula_from_both_sides(tension, closed):
    curve = cardinal_spline(POINTS, tension, closed)
    m = tangents(POINTS, tension, closed)
    n = len(POINTS)
    k = np.arange(n, dtype=float)
    np.testing.assert_allclose(velocity(curve, k), m, atol=1e-12)
    # Left limits: the previous segment's Hermite form at t = 1, and the curve just before.
    g = np.stack([POINTS[:-1], POINTS[1:], m[:-1], m[1:]], axis=1)
    left = np.einsum("i,ij,kjd->kd", power_derivative(1, 1.0), cubic_matrix("hermite"), g)
    np.testing.assert_allclose(left, m[1:], atol=1e-12)
    np.testing.assert_allclose(velocity(curve, k[1:] - 1e-9), m[1:], atol=1e-6)


def test_tension_one_gives_zero_tangents():
    curve = cardinal_spline(POINTS, 1.0)
    ders = curve.derivatives(np.arange(len(POINTS), dtype=float), 1)
    np.testing.assert_allclose(ders[:, 0], POINTS, atol=1e-13)
    np.testing.assert_allclose(ders[:, 1], 0.0, atol=1e-13)


def test_two_points_give_a_straight_segment_at_uniform_speed():
    a, b = rng.normal(size=(2, 2))
    curve = catmull_rom(np.stack([a, b]))
    np.testing.assert_allclose(curve(T), a + T[:, None] * (b - a), atol=1e-14)


def test_closed_cardinal_closes_with_matching_tangent():
    curve = cardinal_spline(POINTS, 0.2, closed=True)
    end = float(len(POINTS))
    np.testing.assert_allclose(curve(end), curve(0.0), atol=1e-13)
    ders = curve.derivatives(np.array([0.0, end]), 1)
    np.testing.assert_allclose(ders[0, 1], ders[1, 1], atol=1e-12)


# --- uniform cubic B-spline ---------------------------------------------------------------


@pytest.mark.parametrize("closed", [False, True])
def test_uniform_bspline_equals_the_seed_matrix_segment_by_segment(closed):
    curve = uniform_cubic_bspline(POINTS, closed)
    n = len(POINTS)
    count = n if closed else n - 3
    np.testing.assert_allclose(curve.domain, [0, count])
    four = POINTS[(np.arange(count)[:, None] + np.arange(4)) % n]
    np.testing.assert_allclose(on_segments(curve, count), segments(four, "bspline"), atol=1e-12)


@pytest.mark.parametrize("closed", [False, True])
def test_uniform_bspline_is_c2_at_the_joints(closed):
    curve = uniform_cubic_bspline(POINTS, closed)
    n = len(POINTS)
    count = n if closed else n - 3
    joints = np.arange(1.0, count)
    four = POINTS[(np.arange(count)[:, None] + np.arange(4)) % n]

    def derivative(order, t):
        # d^order/dt^order of each segment's matrix form (seed matrix) at t.
        return np.einsum("i,ij,kjd->kd", power_derivative(order, t), SEED_BSPLINE, four)

    at_joints = curve.derivatives(joints, 2)
    for order in (1, 2):
        left, right = derivative(order, 1.0)[:-1], derivative(order, 0.0)[1:]
        np.testing.assert_allclose(left, right, atol=1e-12)
        np.testing.assert_allclose(at_joints[:, order], right, atol=1e-12)
    # Just left of each joint the curve's own derivatives agree too (C2: no jump).
    np.testing.assert_allclose(curve.derivatives(joints - 1e-9, 2), at_joints, atol=1e-7)
    # The third derivative does jump: the curve is not C3.
    assert not np.allclose(derivative(3, 1.0)[:-1], derivative(3, 0.0)[1:])


def test_closed_uniform_bspline_closes_c2():
    triangle = rng.normal(size=(3, 2))
    for points in (POINTS, triangle):
        curve = uniform_cubic_bspline(points, closed=True)
        ders = curve.derivatives(np.array([0.0, float(len(points))]), 2)
        np.testing.assert_allclose(ders[0], ders[1], atol=1e-12)


# --- differentiability --------------------------------------------------------------------


@pytest.mark.parametrize(
    "build",
    [
        lambda p: catmull_rom(p),
        lambda p: cardinal_spline(p, 0.3, closed=True),
        lambda p: uniform_cubic_bspline(p, closed=True),
        lambda p: hermite_segment(p[0], p[1], p[2], p[3]),
    ],
)
def test_gradients_wrt_points_are_finite_and_match_finite_differences(build):
    u = jnp.linspace(0.0, 1.0, 7)

    def loss(p):
        curve = build(p)
        lo, hi = curve.domain
        return jnp.sum(curve(lo + u * (hi - lo)) ** 2)

    grad = jax.jit(jax.grad(loss))(jnp.asarray(POINTS))
    assert np.all(np.isfinite(grad))
    direction = rng.normal(size=POINTS.shape)
    h = 1e-6
    fd = (loss(POINTS + h * direction) - loss(POINTS - h * direction)) / (2 * h)
    np.testing.assert_allclose(np.sum(grad * direction), fd, rtol=1e-6)


def test_gradient_wrt_traced_tension_matches_finite_differences():
    def loss(tension):
        return jnp.sum(cardinal_spline(POINTS, tension)(jnp.array([0.5, 2.3, 4.7])) ** 2)

    g = jax.jit(jax.grad(loss))(0.25)
    h = 1e-6
    np.testing.assert_allclose(g, (loss(0.25 + h) - loss(0.25 - h)) / (2 * h), rtol=1e-6)


def test_float32_curves_stay_float32():
    points = POINTS.astype(np.float32)
    for curve in (catmull_rom(points), uniform_cubic_bspline(points, closed=True)):
        assert curve.control_points.dtype == jnp.float32
        assert curve.knots.dtype == jnp.float32
        assert curve(np.float32(0.5)).dtype == jnp.float32


# --- bad input ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: cardinal_spline(POINTS[:1]), "a cardinal spline needs at least 2 points, got 1"),
        (lambda: catmull_rom(POINTS[:2], closed=True), "closed cardinal spline needs at least 3"),
        (lambda: cardinal_spline(POINTS[0]), r"points must have 2 dimensions"),
        (lambda: cardinal_spline(POINTS, np.array([0.1, 0.2])), "tension must be a scalar"),
        (lambda: cardinal_spline(POINTS, np.inf), "tension must be finite"),
        (lambda: uniform_cubic_bspline(POINTS[:3]), "B-spline needs at least 4 points, got 3"),
        (lambda: uniform_cubic_bspline(POINTS[:2], closed=True), "at least 3 points, got 2"),
        (lambda: uniform_cubic_bspline(POINTS[None]), r"points must have 2 dimensions"),
        (lambda: catmull_rom(np.array([[0.0, np.nan], [1.0, 1.0]])), "must be finite"),
        (lambda: hermite_segment(POINTS[:2], POINTS[1], POINTS[2], POINTS[3]), "p0 must have 1"),
        (lambda: hermite_segment(POINTS[0], POINTS[1, :2], POINTS[2], POINTS[3]), "p1 must have"),
        (lambda: matrix_segment(POINTS[:4], "hermit", 0.5), "kind must be one of"),
        (lambda: matrix_segment(POINTS[:4], 3, 0.5), r"shape \(4, 4\), got \(\)"),
        (lambda: matrix_segment(POINTS[:4], np.eye(3), 0.5), r"shape \(4, 4\), got \(3, 3\)"),
        (lambda: matrix_segment(POINTS[:3], "bezier", 0.5), r"shape \(4, dim\), got \(3, 3\)"),
        (lambda: matrix_segment(POINTS[0], "bezier", 0.5), "geometry must have 2 dimensions"),
        (lambda: matrix_segment(POINTS[:4], "bezier", 1.5), r"t must lie in the domain"),
        (lambda: cubic_matrix(None), "kind must be one of"),
    ],
)
def test_value_errors(call, match):
    with pytest.raises(ValueError, match=match):
        call()
