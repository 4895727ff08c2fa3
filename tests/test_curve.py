import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import (
    central_difference,
    naive_curve,
    nine_point_circle,
    partial_derivative,
    random_curve,
    sample_parameters,
)
from scipy.interpolate import BSpline

import diffnurbs as dn

DEGREES = [1, 2, 3, 4, 5]


@pytest.mark.parametrize("degree", DEGREES)
@pytest.mark.parametrize("rational", [False, True])
def test_evaluation_matches_naive_sum(degree, rational):
    rng = np.random.default_rng(degree + 10 * rational)
    curve = random_curve(rng, degree, dim=3, rational=rational)
    u = sample_parameters(rng, curve.knots, degree)
    np.testing.assert_allclose(curve(u), naive_curve(curve, u), atol=1e-12)


def test_any_parameter_shape():
    curve = random_curve(np.random.default_rng(0), 3, dim=3)
    assert curve(0.5).shape == (3,)
    assert curve(jnp.full((2, 5, 4), 0.3)).shape == (2, 5, 4, 3)
    assert curve.derivatives(jnp.full((2, 5), 0.3), 4).shape == (2, 5, 5, 3)


def test_bezier_through_de_casteljau_equals_curve():
    rng = np.random.default_rng(1)
    points, weights = rng.normal(size=(6, 2)), rng.uniform(0.5, 2, 6)
    t = np.linspace(0, 1, 21)
    np.testing.assert_allclose(dn.de_casteljau(points, t), dn.NURBSCurve(points, 5)(t), atol=1e-13)
    np.testing.assert_allclose(
        dn.de_casteljau(points, t, weights),
        dn.NURBSCurve(points, 5, weights=weights)(t),
        atol=1e-13,
    )


def nested_derivative(function, order):
    for _ in range(order):
        function = partial_derivative(function)
    return function


@pytest.mark.parametrize("degree", DEGREES)
@pytest.mark.parametrize("rational", [False, True])
def test_derivatives_match_autodiff(degree, rational):
    rng = np.random.default_rng(100 + degree + 10 * rational)
    curve = random_curve(rng, degree, dim=2, rational=rational)
    u = sample_parameters(rng, curve.knots, degree, count=10)
    order = min(degree + 1, 4)  # above the degree (p <= 3): zero for B-splines, not for NURBS
    analytic = curve.derivatives(u, order)
    for k in range(order + 1):
        autodiff = jax.jit(jax.vmap(nested_derivative(curve, k)))(jnp.asarray(u))
        scale = max(1.0, float(np.abs(autodiff).max()))
        np.testing.assert_allclose(analytic[:, k], autodiff, atol=1e-9 * scale)
    if not rational:
        assert np.all(np.asarray(analytic[:, degree + 1 :]) == 0.0)


@pytest.mark.parametrize("degree", [2, 3, 5])
def test_derivatives_match_finite_differences(degree):
    rng = np.random.default_rng(200 + degree)
    curve = random_curve(rng, degree, n_control=degree + 1, dim=3)  # one span: smooth everywhere
    u = np.array([0.0, 0.3, 0.71, 1.0])
    h = 1e-5
    inner = np.clip(u, h, 1 - h)  # central differences need room on both sides
    ders = curve.derivatives(inner, 2)
    first = (curve(inner + h) - curve(inner - h)) / (2 * h)
    second = (curve(inner + h) - 2 * curve(inner) + curve(inner - h)) / h**2
    np.testing.assert_allclose(ders[:, 1], first, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(ders[:, 2], second, rtol=1e-3, atol=1e-3)


def scipy_derivatives(curve, u, order):
    """`C^(0..order)` from scipy's `BSpline` (of the homogeneous points and the Leibniz rule
    written out here, for a rational curve): an oracle independent of diffnurbs's evaluation."""
    knots, p = np.asarray(curve.knots), curve.degree
    points = np.asarray(curve.control_points)
    if curve.weights is not None:
        points = np.column_stack([points * np.asarray(curve.weights)[:, None], curve.weights])
    spline = BSpline(knots, points, p)
    a = [
        spline(u, nu=k) if k <= p else np.zeros((len(u), points.shape[1])) for k in range(order + 1)
    ]
    if curve.weights is None:
        return np.stack(a, axis=1)
    ders = []
    for k in range(order + 1):
        v = a[k][:, :-1]
        for i in range(1, k + 1):
            v = v - math.comb(k, i) * a[i][:, -1:] * ders[k - i]
        ders.append(v / a[0][:, -1:])
    return np.stack(ders, axis=1)


@pytest.mark.parametrize("degree", DEGREES)
@pytest.mark.parametrize("rational", [False, True])
def test_derivatives_at_many_parameters_match_scipy(degree, rational):
    # Enough parameters per span that the curve evaluates from per-span Taylor tables
    # (NURBSCurve._horner_columns); every knot and both ends included.
    rng = np.random.default_rng(300 + degree + 10 * rational)
    curve = random_curve(rng, degree, dim=3, rational=rational)
    u = sample_parameters(rng, curve.knots, degree, count=400)
    order = degree + 1
    expected = scipy_derivatives(curve, u, order)
    ders = curve.derivatives(u, order)
    for k in range(order + 1):
        scale = max(1.0, float(np.abs(expected[:, k]).max()))
        np.testing.assert_allclose(ders[:, k], expected[:, k], atol=1e-11 * scale)
    np.testing.assert_allclose(curve(u), expected[:, 0], atol=1e-12)


def test_derivatives_at_many_parameters_have_gradients():
    rng = np.random.default_rng(7)
    knots = [0, 0, 0, 0, 0.25, 0.5, 0.7, 1, 1, 1, 1]  # distinct interior knots to move
    curve = dn.NURBSCurve(rng.normal(size=(7, 2)), 3, knots, rng.uniform(0.5, 2, 7))
    u = jnp.asarray(np.sort(rng.uniform(0.01, 0.99, 200)))
    u = u[jnp.all(jnp.abs(u[:, None] - curve.knots) > 1e-3, axis=1)]  # smooth in the knots
    assert len(u) >= 32 * 4  # the Taylor-table evaluation
    direction = jnp.asarray(rng.normal(size=(3, 2)))

    def loss(points, weights, knots):
        ders = dn.NURBSCurve(points, 3, knots, weights).derivatives(u, 2)
        return jnp.sum(ders * direction)

    arguments = [curve.control_points, curve.weights, curve.knots]
    grads = jax.grad(loss, argnums=(0, 1, 2))(*arguments)
    inner = slice(4, -4)  # interior knots: moving an end knot would unclamp the knots
    for i, (grad, part) in enumerate(zip(grads, [slice(None)] * 2 + [inner], strict=True)):

        def along(x, i=i, part=part):
            value = jnp.asarray(arguments[i]).at[part].set(x)
            return float(loss(*arguments[:i], value, *arguments[i + 1 :]))

        expected = central_difference(along, np.asarray(arguments[i])[part])
        np.testing.assert_allclose(grad[part], expected, rtol=1e-6, atol=1e-6)


def test_circle_geometry_is_exact():
    circle = nine_point_circle(radius=2.5, center=(1.0, -2.0))
    u = np.linspace(0, 1, 10_001)
    radius = np.linalg.norm(np.asarray(circle(u)) - [1.0, -2.0], axis=-1)
    np.testing.assert_allclose(radius, 2.5, atol=1e-14 * 2.5)
    np.testing.assert_allclose(circle.curvature(u), 1 / 2.5, rtol=1e-12)  # counterclockwise: +
    np.testing.assert_allclose(circle.arc_length(), 2 * np.pi * 2.5, rtol=1e-13)
    np.testing.assert_allclose(circle.arc_length(0.25, 0.5), np.pi * 2.5 / 2, rtol=1e-13)
    tangent = np.asarray(circle.tangent(u))
    normal = (np.asarray(circle(u)) - [1.0, -2.0]) / 2.5
    np.testing.assert_allclose(np.sum(tangent * normal, -1), 0.0, atol=1e-13)
    np.testing.assert_allclose(np.linalg.norm(tangent, axis=-1), 1.0, atol=1e-14)


def test_curvature_in_3d_and_reversed_orientation():
    planar = nine_point_circle(radius=3.0)
    points = np.asarray(planar.control_points)
    tilted = (
        np.column_stack([points, np.zeros(len(points))])
        @ np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))[0]
    )
    space = dn.NURBSCurve(tilted, 2, planar.knots, planar.weights)
    u = np.linspace(0, 1, 101)
    np.testing.assert_allclose(space.curvature(u), 1 / 3.0, rtol=1e-12)
    flipped = dn.NURBSCurve(points * [1, -1], 2, planar.knots, planar.weights)
    np.testing.assert_allclose(flipped.curvature(u), -1 / 3.0, rtol=1e-12)
    four_d = dn.NURBSCurve(np.pad(tilted, ((0, 0), (0, 1))), 2, planar.knots, planar.weights)
    np.testing.assert_allclose(four_d.curvature(u), 1 / 3.0, rtol=1e-7)


def test_straight_line_has_zero_curvature_and_finite_gradient():
    line = dn.NURBSCurve([[0.0, 0, 0], [1, 1, 1], [2, 2, 2]], 2)
    assert np.allclose(line.curvature(np.linspace(0, 1, 5)), 0.0)
    grad = jax.grad(lambda p: dn.NURBSCurve(p, 2).curvature(0.5))(line.control_points)
    assert np.all(np.isfinite(grad))


def fine_composite_length(curve, panels_per_span=1024):
    """Reference length: a 32-point Gauss rule on 1024 equal panels of every knot span."""
    nodes, weights = np.polynomial.legendre.leggauss(32)
    speed = jax.jit(lambda u: jnp.linalg.norm(curve.derivatives(u, 1)[..., 1, :], axis=-1))
    total = 0.0
    for a, b in itertools.pairwise(np.unique(np.asarray(curve.knots))):
        edges = np.linspace(a, b, panels_per_span + 1)
        half = np.diff(edges)[:, None] / 2
        x = (edges[:-1, None] + half) + half * nodes
        total += np.sum(half[:, 0] * (np.asarray(speed(x)) @ weights))
    return total


@pytest.mark.parametrize("seed", range(8))
def test_arc_length_matches_fine_composite_quadrature(seed):
    rng = np.random.default_rng(300 + seed)
    curve = random_curve(rng, int(rng.integers(1, 6)), dim=3)
    np.testing.assert_allclose(curve.arc_length(), fine_composite_length(curve), rtol=1e-10)
    a, b = 0.13, 0.77
    np.testing.assert_allclose(
        curve.arc_length(a, b), curve.arc_length(0, b) - curve.arc_length(0, a), rtol=1e-10
    )


def test_arc_length_of_a_jitted_traced_curve_is_differentiable():
    circle = nine_point_circle()

    @jax.jit
    def length(scale):
        return dn.NURBSCurve(
            circle.control_points * scale, 2, circle.knots, circle.weights
        ).arc_length()

    np.testing.assert_allclose(length(2.0), 4 * np.pi, rtol=1e-12)
    np.testing.assert_allclose(jax.grad(length)(2.0), 2 * np.pi, rtol=1e-10)


def test_out_of_domain_parameters():
    curve = random_curve(np.random.default_rng(4), 3)
    with pytest.raises(ValueError, match="domain"):
        curve(jnp.array([0.5, 1.2]))
    with pytest.raises(ValueError, match="domain"):
        curve.derivatives(-0.1, 1)
    # Under jit the parameter is clamped to the nearest end of the domain.
    clamped = jax.jit(lambda c, u: c(u))(curve, jnp.array([-0.5, 1.5]))
    np.testing.assert_allclose(clamped, curve(jnp.array([0.0, 1.0])), atol=1e-15)


def test_float32_curves():
    circle = nine_point_circle()
    single = dn.NURBSCurve(
        np.asarray(circle.control_points, np.float32),
        2,
        np.asarray(circle.knots, np.float32),
        np.asarray(circle.weights, np.float32),
    )
    u = jnp.linspace(0, 1, 101, dtype=jnp.float32)
    points = single(u)
    assert points.dtype == jnp.float32 and single.derivatives(u, 2).dtype == jnp.float32
    np.testing.assert_allclose(jnp.linalg.norm(points, axis=-1), 1.0, atol=1e-6)
    np.testing.assert_allclose(single.arc_length(), 2 * np.pi, rtol=1e-6)
