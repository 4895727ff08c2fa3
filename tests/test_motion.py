import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import random_curve

import diffnurbs as dn

UV = np.meshgrid(np.linspace(0, 1, 31), np.linspace(0, 1, 29), indexing="ij")


def test_extrusion_is_the_profile_translated():
    profile = random_curve(np.random.default_rng(1), 3, dim=3)
    direction, length = np.array([1.0, -2.0, 0.5]), 2.5
    surface = dn.extrude(profile, direction, length)
    u, v = UV
    step = length * direction / np.linalg.norm(direction)
    np.testing.assert_allclose(surface(u, v), profile(u) + v[..., None] * step, atol=1e-13)


@pytest.mark.parametrize("angle", [2 * math.pi, math.pi / 3, -2.0, 4.0])
def test_revolution_about_any_axis_is_exact(angle):
    rng = np.random.default_rng(2)
    profile = random_curve(rng, 2, dim=3)
    origin, axis = rng.normal(size=3), rng.normal(size=3)
    axis_unit = axis / np.linalg.norm(axis)
    surface = dn.revolve(profile, origin, axis, angle)
    u, v = UV
    points, start = np.asarray(surface(u, v)), np.asarray(profile(u))

    def cylindrical(x):
        offset = x - origin
        height = offset @ axis_unit
        radial = offset - height[..., None] * axis_unit
        return height, radial

    height, radial = cylindrical(points)
    height0, radial0 = cylindrical(start)
    np.testing.assert_allclose(height, height0, atol=1e-12)  # moves on circles about the axis
    np.testing.assert_allclose(
        np.linalg.norm(radial, axis=-1), np.linalg.norm(radial0, axis=-1), atol=1e-12
    )
    # The signed angle turned (right-handed about the axis) runs from 0 to `angle`.
    cos = np.sum(radial * radial0, -1)
    sin = np.sum(np.cross(radial0, radial) * axis_unit, -1)
    turned = np.unwrap(np.arctan2(sin, cos), axis=1)
    np.testing.assert_allclose(turned[:, -1], angle, atol=1e-10)
    np.testing.assert_allclose(turned[:, 0], 0.0, atol=1e-12)


def test_sphere_by_revolving_a_half_circle():
    half = dn.arc(2.0, -math.pi / 2, math.pi / 2, center=(0.0, 0.0, 0.0))
    sphere = dn.revolve(half, (0, 0, 0), (0, 1, 0))
    np.testing.assert_allclose(np.linalg.norm(sphere(*UV), axis=-1), 2.0, atol=1e-14)


def test_gradient_through_the_profile():
    profile = random_curve(np.random.default_rng(3), 3, dim=3)

    @jax.jit
    def area_proxy(points):
        curve = dn.NURBSCurve(points, 3, profile.knots, profile.weights)
        return jnp.sum(dn.revolve(curve, jnp.zeros(3), jnp.array([0.0, 0, 1]))(*UV) ** 2)

    assert np.all(np.isfinite(jax.grad(area_proxy)(profile.control_points)))


@pytest.mark.parametrize("rational", [(False, False), (True, False), (True, True)])
def test_translational_sweep_is_exact(rational):
    rng = np.random.default_rng(5)
    profile = random_curve(rng, 3, dim=3, rational=rational[0])
    path = random_curve(rng, 2, dim=3, rational=rational[1], domain=(1.0, 3.0))
    surface = dn.sweep(profile, path)
    u, v = UV
    v = 1.0 + 2.0 * v
    expected = profile(u) + path(v) - path(1.0)
    np.testing.assert_allclose(surface(u, v), expected, atol=1e-12)


def test_bad_motion_input():
    curve = random_curve(np.random.default_rng(4), 2, dim=3)
    with pytest.raises(ValueError, match="direction must be non-zero"):
        dn.extrude(curve, (0.0, 0.0, 0.0), 1.0)
    with pytest.raises(ValueError, match="vector of length 3"):
        dn.extrude(curve, (1.0, 0.0), 1.0)
    with pytest.raises(ValueError, match="axis_direction must be non-zero"):
        dn.revolve(curve, (0, 0, 0), (0, 0, 0))
    with pytest.raises(ValueError, match="profile in 3D"):
        dn.revolve(dn.circle(1.0), (0, 0, 0), (0, 0, 1))
    with pytest.raises(ValueError, match="sweep angle"):
        dn.revolve(curve, (0, 0, 0), (0, 0, 1), 0.0)
    with pytest.raises(ValueError, match="same dimension"):
        dn.sweep(curve, dn.circle(1.0))
