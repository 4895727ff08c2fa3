import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import (
    naive_surface,
    nine_point_circle,
    partial_derivative,
    random_surface,
    sample_parameters,
)

import diffnurbs as dn

DEGREE_PAIRS = [(1, 1), (2, 3), (3, 2), (4, 1), (5, 2)]


@pytest.mark.parametrize("degrees", DEGREE_PAIRS)
@pytest.mark.parametrize("rational", [False, True])
def test_evaluation_matches_naive_double_sum(degrees, rational):
    rng = np.random.default_rng(sum(degrees) + 10 * rational)
    surface = random_surface(rng, degrees, rational=rational)
    u = sample_parameters(rng, surface.knots_u, degrees[0], count=15)
    v = sample_parameters(rng, surface.knots_v, degrees[1], count=15)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    expected = naive_surface(surface, uu, vv)
    np.testing.assert_allclose(surface(uu, vv), expected, atol=1e-12)
    np.testing.assert_allclose(surface.grid(u, v), expected, atol=1e-12)


def test_grid_banded_path_for_large_nets():
    # 70 control points along u: above the dense-matrix limit, so the banded path runs.
    rng = np.random.default_rng(7)
    surface = random_surface(rng, (3, 2), counts=(70, 5))
    u, v = np.linspace(0, 1, 33), np.linspace(0, 1, 9)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    np.testing.assert_allclose(surface.grid(u, v), naive_surface(surface, uu, vv), atol=1e-12)


def test_broadcasting_shapes():
    surface = random_surface(np.random.default_rng(1), (2, 2))
    assert surface(0.3, 0.4).shape == (3,)
    assert surface(jnp.full((4, 1), 0.3), jnp.full((1, 5), 0.2)).shape == (4, 5, 3)
    assert surface.derivatives(jnp.full(6, 0.5), 0.5, 2).shape == (6, 3, 3, 3)
    assert surface.normal(jnp.full((2, 3), 0.5), 0.1).shape == (2, 3, 3)


def test_bezier_patch_equals_de_casteljau_surface():
    rng = np.random.default_rng(2)
    net, weights = rng.normal(size=(4, 3, 3)), rng.uniform(0.5, 2, (4, 3))
    u, v = rng.uniform(size=20), rng.uniform(size=20)
    patch = dn.NURBSSurface(net, (3, 2), weights=weights)
    np.testing.assert_allclose(dn.de_casteljau_surface(net, u, v, weights), patch(u, v), atol=1e-13)


@pytest.mark.parametrize("degrees", DEGREE_PAIRS)
@pytest.mark.parametrize("rational", [False, True])
def test_derivatives_match_autodiff(degrees, rational):
    rng = np.random.default_rng(50 + sum(degrees) + 10 * rational)
    surface = random_surface(rng, degrees, rational=rational)
    u = jnp.asarray(sample_parameters(rng, surface.knots_u, degrees[0], count=4))
    v = jnp.asarray(rng.uniform(0, 1, size=u.shape))
    order = 2
    analytic = surface.derivatives(u, v, order)

    def partial(k, l):
        function = surface
        for _ in range(k):
            function = partial_derivative(function, argnum=0)
        for _ in range(l):
            function = partial_derivative(function, argnum=1)
        return jax.jit(jax.vmap(function))(u, v)

    for k, l in itertools.product(range(order + 1), repeat=2):
        expected = partial(k, l)
        scale = max(1.0, float(np.abs(expected).max()))
        np.testing.assert_allclose(analytic[:, k, l], expected, atol=1e-9 * scale)


def test_derivatives_match_finite_differences():
    rng = np.random.default_rng(60)
    surface = random_surface(rng, (3, 3), counts=(4, 4))  # one patch: smooth everywhere
    u, v, h = np.array([0.2, 0.55]), np.array([0.7, 0.35]), 1e-5
    ders = surface.derivatives(u, v, 1)
    s_u = (surface(u + h, v) - surface(u - h, v)) / (2 * h)
    s_v = (surface(u, v + h) - surface(u, v - h)) / (2 * h)
    s_uv = (
        surface(u + h, v + h)
        - surface(u + h, v - h)
        - surface(u - h, v + h)
        + surface(u - h, v - h)
    ) / (4 * h * h)
    np.testing.assert_allclose(ders[:, 1, 0], s_u, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(ders[:, 0, 1], s_v, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(ders[:, 1, 1], s_uv, rtol=1e-4, atol=1e-4)


def sphere(radius=2.0):
    """Half circle in the xz-plane (u) revolved by the 9-point circle (v)."""
    # Meridian from the south pole to the north pole, as (distance from the axis, height).
    profile = radius * np.array([(0, -1), (1, -1), (1, 0), (1, 1), (0, 1)], dtype=float)
    profile_w = np.array([1, np.sqrt(2) / 2, 1, np.sqrt(2) / 2, 1])
    circle = nine_point_circle(1.0)
    ring, ring_w = np.asarray(circle.control_points), np.asarray(circle.weights)
    points = np.zeros((5, 9, 3))
    points[..., 0] = profile[:, 0, None] * ring[None, :, 0]
    points[..., 1] = profile[:, 0, None] * ring[None, :, 1]
    points[..., 2] = profile[:, 1, None]
    weights = profile_w[:, None] * ring_w[None, :]
    knots_u = [0, 0, 0, 0.5, 0.5, 1, 1, 1]
    return dn.NURBSSurface(points, (2, 2), (knots_u, circle.knots), weights)


def test_sphere_is_exact_and_its_normals_are_radial():
    surface = sphere(2.0)
    u, v = np.meshgrid(np.linspace(0, 1, 41), np.linspace(0, 1, 41), indexing="ij")
    points = np.asarray(surface(u, v))
    np.testing.assert_allclose(np.linalg.norm(points, axis=-1), 2.0, atol=1e-14)
    inner = (u > 0) & (u < 1)  # the poles are degenerate: S_v = 0 there
    normals = np.asarray(surface.normal(u, v))
    np.testing.assert_allclose(np.abs(np.sum(normals * points / 2.0, -1))[inner], 1.0, atol=1e-12)
    np.testing.assert_allclose(normals[~inner], 0.0)  # zero, not a rounding-noise direction
    ders = np.asarray(surface.derivatives(u, v, 1))
    np.testing.assert_allclose(np.sum(normals * ders[..., 1, 0, :], -1), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.sum(normals * ders[..., 0, 1, :], -1), 0.0, atol=1e-12)


def test_out_of_domain_and_jit_clamping():
    surface = random_surface(np.random.default_rng(3), (2, 2))
    with pytest.raises(ValueError, match="domain"):
        surface(1.5, 0.5)
    with pytest.raises(ValueError, match="domain"):
        surface.grid(np.array([0.0, 1.0]), np.array([-0.1]))
    clamped = jax.jit(lambda s, u, v: s(u, v))(surface, 1.5, -2.0)
    np.testing.assert_allclose(clamped, surface(1.0, 0.0), atol=1e-15)


def test_normal_needs_3d():
    with pytest.raises(ValueError, match="3D"):
        dn.NURBSSurface(np.zeros((2, 2, 2)), (1, 1)).normal(0.5, 0.5)
