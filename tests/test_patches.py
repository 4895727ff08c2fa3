"""Bicubic patches in matrix form against tensor-product Bezier and B-spline surfaces."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffnurbs as dn

rng = np.random.default_rng(7)
GEOMETRY = rng.normal(size=(4, 4, 3))
U = np.array([0.0, 1.0, 0.0, 1.0, 0.25, 0.6, 0.9])
V = np.array([0.0, 0.0, 1.0, 1.0, 0.8, 0.3, 0.55])


def test_matrices_are_the_seed_matrices():
    np.testing.assert_array_equal(dn.cubic_matrix("bezier"), dn.bezier_matrix(3))
    np.testing.assert_allclose(
        6 * dn.cubic_matrix("bspline"), [[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 0, 3, 0], [1, 4, 1, 0]]
    )
    np.testing.assert_allclose(
        2 * dn.cubic_matrix("catmull-rom"),
        [[-1, 3, -3, 1], [2, -5, 4, -1], [-1, 0, 1, 0], [0, 2, 0, 0]],
    )
    # Every basis reproduces constants: the blending functions sum to one.
    for kind in ("bezier", "bspline", "catmull-rom"):
        np.testing.assert_allclose(
            np.asarray(dn.cubic_matrix(kind)).sum(axis=1), [0, 0, 0, 1], atol=1e-15
        )


def test_bezier_patch_equals_de_casteljau_and_nurbs_surface():
    expected = dn.NURBSSurface(GEOMETRY, (3, 3))(U, V)
    np.testing.assert_allclose(dn.bicubic_patch(GEOMETRY, U, V), expected, atol=1e-12)
    bernstein_sum = np.einsum("ki,kj,ijd->kd", dn.bernstein(3, U), dn.bernstein(3, V), GEOMETRY)
    np.testing.assert_allclose(dn.bicubic_patch(GEOMETRY, U, V), bernstein_sum, atol=1e-12)


def test_bspline_patch_is_the_middle_piece_of_a_uniform_bspline_surface():
    # A uniform bicubic B-spline on 4 x 4 points with knots 0..7 has one span [3, 4].
    knots = np.arange(8.0)
    surface = dn.NURBSSurface(GEOMETRY, (3, 3), knots=(knots, knots))
    np.testing.assert_allclose(
        dn.bicubic_patch(GEOMETRY, U, V, "bspline"), surface(3 + U, 3 + V), atol=1e-12
    )


def test_catmull_rom_patch_interpolates_the_middle_points():
    corners = dn.bicubic_patch(
        GEOMETRY, np.array([0.0, 1, 0, 1]), np.array([0.0, 0, 1, 1]), "catmull-rom"
    )
    np.testing.assert_allclose(
        corners, [GEOMETRY[1, 1], GEOMETRY[2, 1], GEOMETRY[1, 2], GEOMETRY[2, 2]], atol=1e-12
    )
    # Each curve u -> S(u, v) is a Catmull-Rom segment: C(t) = 0.5 (2 P1 + (-P0 + P2) t + ...).
    t = 0.37
    p = dn.bicubic_patch(GEOMETRY, t, 0.0, "catmull-rom")
    g = GEOMETRY[:, 1]
    explicit = 0.5 * (
        2 * g[1]
        + (-g[0] + g[2]) * t
        + (2 * g[0] - 5 * g[1] + 4 * g[2] - g[3]) * t**2
        + (-g[0] + 3 * g[1] - 3 * g[2] + g[3]) * t**3
    )
    np.testing.assert_allclose(p, explicit, atol=1e-12)


def test_broadcasting_and_custom_matrix():
    u = np.linspace(0, 1, 5)[:, None]
    v = np.linspace(0, 1, 3)[None, :]
    out = dn.bicubic_patch(GEOMETRY, u, v)
    assert out.shape == (5, 3, 3)
    np.testing.assert_allclose(out, dn.bicubic_patch(GEOMETRY, u, v, dn.cubic_matrix("bezier")))
    assert dn.bicubic_patch(GEOMETRY, 0.5, 0.5).shape == (3,)


def test_bad_input_raises():
    with pytest.raises(ValueError, match="one of"):
        dn.bicubic_patch(GEOMETRY, 0.5, 0.5, "bogus")
    with pytest.raises(ValueError, match=r"\(4, 4, dim\)"):
        dn.bicubic_patch(np.zeros((3, 4, 3)), 0.5, 0.5)
    with pytest.raises(ValueError, match=r"\(4, 4\)"):
        dn.bicubic_patch(GEOMETRY, 0.5, 0.5, np.eye(3))
    with pytest.raises(ValueError, match="v must lie"):
        dn.bicubic_patch(GEOMETRY, 0.5, 1.2)


def test_gradients_are_finite():
    def loss(geometry, u, v):
        return jnp.sum(dn.bicubic_patch(geometry, u, v, "catmull-rom") ** 2)

    grad = jax.jit(jax.grad(loss, argnums=(0, 1, 2)))
    for u, v in ((0.0, 0.0), (1.0, 1.0), (0.3, 0.8)):
        grads = grad(jnp.asarray(GEOMETRY), u, v)
        assert all(bool(jnp.all(jnp.isfinite(g))) for g in grads)
