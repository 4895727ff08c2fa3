"""Rational Bezier curves (seed 000 §1.3, seed 002): the worked examples of chapter 03 as tests."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffnurbs as dn

ARC_P = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
ARC_W = np.array([1.0, 1.0, 2.0])
T = np.linspace(0.0, 1.0, 101)


def naive_rational_bezier(points, weights, t):
    """Eq. 1.11 term by term with math.comb: the oracle."""
    n = len(points) - 1
    t = np.asarray(t, dtype=float)[..., None]
    basis = np.concatenate(
        [math.comb(n, i) * t**i * (1 - t) ** (n - i) for i in range(n + 1)], axis=-1
    )
    return (basis * weights) @ points / (basis @ weights)[..., None]


def test_seed_arc_is_the_exact_quarter_circle():
    # Seed 000 §1.3.1: P = (1,0), (1,1), (0,1), w = (1,1,2). C(t) = ((1 - t^2), 2t) / (1 + t^2).
    points = np.asarray(dn.de_casteljau(ARC_P, T, ARC_W))
    exact = np.stack([1 - T**2, 2 * T], -1) / (1 + T**2)[:, None]
    np.testing.assert_allclose(points, exact, atol=1e-15)
    np.testing.assert_allclose(np.hypot(*points.T), 1.0, atol=4e-16)
    np.testing.assert_allclose(np.arctan2(points[:, 1], points[:, 0]), 2 * np.arctan(T), atol=4e-16)
    np.testing.assert_allclose(points[50], [0.6, 0.8], atol=1e-15)


def test_seed_arc_equals_symmetric_arc_after_moebius_reparametrisation():
    c = math.sqrt(2.0)  # (1, sqrt2/2, 1) -> (1, 1, 2) by w_i -> c^i w_i
    symmetric = np.asarray(dn.de_casteljau(ARC_P, T, [1.0, math.sqrt(0.5), 1.0]))
    moved = np.asarray(dn.de_casteljau(ARC_P, T / (T + c * (1 - T)), ARC_W))
    np.testing.assert_allclose(symmetric, moved, atol=1e-15)


@pytest.mark.parametrize("degree", [1, 2, 3, 5])
def test_three_evaluations_agree(degree):
    rng = np.random.default_rng(degree)
    points = rng.normal(size=(degree + 1, 3))
    weights = rng.uniform(0.1, 10.0, size=degree + 1)
    expected = naive_rational_bezier(points, weights, T)
    by_casteljau = dn.de_casteljau(points, T, weights)
    by_homogeneous = dn.from_homogeneous(dn.de_casteljau(dn.to_homogeneous(points, weights), T))
    by_nurbs = dn.NURBSCurve(points, degree, weights=weights)(T)
    for got in (by_casteljau, by_homogeneous, by_nurbs):
        np.testing.assert_allclose(got, expected, atol=1e-13)
    np.testing.assert_allclose(np.asarray(by_casteljau)[[0, -1]], points[[0, -1]], atol=1e-14)


@pytest.mark.parametrize("scale", [1e-9, 0.3, 1e9])
def test_scaling_all_weights_changes_nothing(scale):
    points = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 2.0], [3.0, 0.0]])
    weights = np.array([1.0, 30.0, 30.0, 1.0])
    np.testing.assert_allclose(
        dn.de_casteljau(points, T, scale * weights), dn.de_casteljau(points, T, weights), atol=1e-14
    )


@pytest.mark.parametrize("weights", [(1, 1, 1, 1), (1, 1, 10, 1), (1, 30, 30, 1), (1, 1000, 1, 1)])
def test_seed_002_weight_examples(weights):
    points = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 2.0], [3.0, 0.0]])
    weights = np.asarray(weights, dtype=float)
    curve = dn.NURBSCurve(points, 3, weights=weights)
    np.testing.assert_allclose(curve(T), naive_rational_bezier(points, weights, T), atol=1e-13)
    # derivatives: library (Leibniz rule) vs autodiff of de Casteljau
    autodiff = jax.vmap(jax.jacfwd(lambda u: dn.de_casteljau(points, u, weights)))(jnp.asarray(T))
    library = curve.derivatives(T, 1)[:, 1]
    np.testing.assert_allclose(library, autodiff, atol=1e-11 * np.abs(autodiff).max())
    np.testing.assert_allclose(library[0], 3 * weights[1] / weights[0] * (points[1] - points[0]))
    np.testing.assert_allclose(library[-1], 3 * weights[2] / weights[3] * (points[3] - points[2]))


@pytest.mark.parametrize("theta", [1e-3, 0.5, math.pi / 2, 2.0, 3.0])
def test_circular_arc_of_any_angle(theta):
    points = np.array([[1.0, 0.0], [1.0, math.tan(theta / 2)], [math.cos(theta), math.sin(theta)]])
    weights = np.array([1.0, math.cos(theta / 2), 1.0])
    curve = dn.NURBSCurve(points, 2, weights=weights)
    np.testing.assert_allclose(np.hypot(*np.asarray(curve(T)).T), 1.0, atol=1e-14)
    np.testing.assert_allclose(curve.curvature(T), 1.0, atol=1e-9)


def test_rational_cylinder_surface():
    # Seed 000 §1.3.2 (Figure 1.5): the arc moved along z. Eq. 1.13 needs w_ij in the numerator.
    net = np.stack([np.c_[ARC_P, np.zeros(3)], np.c_[ARC_P, np.ones(3)]], axis=1)
    weights = np.stack([ARC_W, ARC_W], axis=1)
    surface = dn.NURBSSurface(net, (2, 1), weights=weights)
    u, v = np.linspace(0, 1, 9), np.linspace(0, 1, 4)
    grid = np.asarray(surface.grid(u, v))
    np.testing.assert_allclose(np.hypot(grid[..., 0], grid[..., 1]), 1.0, atol=1e-15)
    np.testing.assert_allclose(grid[..., 2], np.broadcast_to(v, (9, 4)), atol=1e-15)
    np.testing.assert_allclose(
        np.ravel(dn.de_casteljau_surface(net, 0.3, 0.7, weights)), surface(0.3, 0.7), atol=1e-15
    )


def test_de_casteljau_surface_array_parameters():
    net = np.random.default_rng(0).normal(size=(3, 2, 3))
    surface = dn.NURBSSurface(net, (2, 1))
    assert dn.de_casteljau_surface(net, 0.3, 0.6).shape == (3,)
    u, v = np.full((4, 5), 0.3), np.full((4, 5), 0.6)
    np.testing.assert_allclose(dn.de_casteljau_surface(net, u, v), surface(u, v), atol=1e-14)
