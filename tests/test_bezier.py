"""Bezier matrix form, subdivision, hodographs and volumes against independent oracles."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffnurbs as dn

T = np.concatenate([[0.0, 1.0], np.linspace(0.0, 1.0, 13), [1e-12, 1 - 1e-12]])


def power_row(t, n):
    return np.stack([np.asarray(t) ** (n - r) for r in range(n + 1)], axis=-1)


def test_bezier_matrix_cubic_is_the_seed_matrix():
    expected = [[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 3, 0, 0], [1, 0, 0, 0]]
    np.testing.assert_array_equal(dn.bezier_matrix(3), expected)
    np.testing.assert_array_equal(dn.cubic_matrix("bezier"), expected)


@pytest.mark.parametrize("degree", [0, 1, 2, 5, 9])
def test_bezier_matrix_reproduces_bernstein(degree):
    # Row vector [t^n ... 1] @ M_B gives every B_{j,n}(t): compare with dn.bernstein.
    values = power_row(T, degree) @ np.asarray(dn.bezier_matrix(degree))
    np.testing.assert_allclose(values, dn.bernstein(degree, T), atol=1e-12)


@pytest.mark.parametrize("degree", [1, 3, 6])
def test_bezier_matrix_form_equals_de_casteljau(degree):
    points = np.random.default_rng(degree).normal(size=(degree + 1, 3))
    matrix_form = power_row(T, degree) @ np.asarray(dn.bezier_matrix(degree)) @ points
    np.testing.assert_allclose(matrix_form, dn.de_casteljau(points, T), atol=1e-12)


def test_bezier_matrix_rejects_bad_degree():
    with pytest.raises(ValueError, match="degree"):
        dn.bezier_matrix(-1)
    with pytest.raises(ValueError, match="int"):
        dn.bezier_matrix(2.0)


@pytest.mark.parametrize("degree", [1, 2, 3, 7])
@pytest.mark.parametrize("split", [0.0, 0.3, 0.5, 1.0])
def test_subdivision_reproduces_both_halves(degree, split):
    points = np.random.default_rng(degree).normal(size=(degree + 1, 2))
    left, right = dn.subdivide(points, split)
    s = np.linspace(0, 1, 11)
    np.testing.assert_allclose(
        dn.de_casteljau(left, s), dn.de_casteljau(points, split * s), atol=1e-12
    )
    np.testing.assert_allclose(
        dn.de_casteljau(right, s), dn.de_casteljau(points, split + (1 - split) * s), atol=1e-12
    )
    # The halves share the split point and keep the end points.
    np.testing.assert_allclose(left[-1], right[0], atol=1e-14)
    np.testing.assert_allclose(left[0], points[0])
    np.testing.assert_allclose(right[-1], points[-1])


def test_rational_subdivision_reproduces_quarter_circle():
    # w = (1, 1, 2) on (1, 0), (1, 1), (0, 1) is C(t) = ((1 - t^2), 2t) / (1 + t^2), exactly.
    points, weights = np.array([[1.0, 0], [1, 1], [0, 1]]), np.array([1.0, 1, 2])
    (left, wl), (right, wr) = dn.subdivide(points, 0.5, weights)
    s = np.linspace(0, 1, 11)

    def exact(t):
        return np.stack([1 - t**2, 2 * t], axis=-1) / (1 + t**2)[:, None]

    np.testing.assert_allclose(dn.de_casteljau(left, s, wl), exact(0.5 * s), atol=1e-14)
    np.testing.assert_allclose(dn.de_casteljau(right, s, wr), exact(0.5 + 0.5 * s), atol=1e-14)


def test_subdivision_vectorises_over_t():
    points = np.random.default_rng(0).normal(size=(4, 3))
    ts = np.array([[0.2, 0.7], [0.5, 1.0]])
    left, right = dn.subdivide(points, ts)
    assert left.shape == right.shape == (2, 2, 4, 3)
    np.testing.assert_allclose(left[0, 1], dn.subdivide(points, 0.7)[0])


def test_subdivision_rejects_bad_input():
    points = np.zeros((4, 2))
    with pytest.raises(ValueError, match=r"domain \[0.0, 1.0\]"):
        dn.subdivide(points, 1.5)
    with pytest.raises(ValueError, match=r"\(n_control, dim\)"):
        dn.subdivide(np.zeros(4), 0.5)
    with pytest.raises(ValueError, match="positive"):
        dn.subdivide(points, 0.5, weights=[1, -1, 1, 1])


@pytest.mark.parametrize("degree", [1, 3, 8])
def test_hodograph_matches_autodiff_and_nurbs(degree):
    points = np.random.default_rng(degree).normal(size=(degree + 1, 2))
    hodograph = dn.bezier_derivative_points(points)
    assert hodograph.shape == (degree, 2)
    derivative = jax.vmap(jax.jacfwd(lambda t: dn.de_casteljau(points, t)))(jnp.asarray(T))
    np.testing.assert_allclose(dn.de_casteljau(hodograph, T), derivative, atol=1e-10)
    if degree > 3:
        return  # the B-spline oracle below is slow to compile for high orders
    ders = dn.NURBSCurve(points, degree).derivatives(T, degree)
    for k in range(1, degree + 1):
        kth = dn.de_casteljau(dn.bezier_derivative_points(points, k), T)
        np.testing.assert_allclose(kth, ders[:, k], atol=1e-9 * math.factorial(degree))


def test_hodograph_rejects_bad_order():
    with pytest.raises(ValueError, match="<= the degree"):
        dn.bezier_derivative_points(np.zeros((3, 2)), 3)
    with pytest.raises(ValueError, match="order"):
        dn.bezier_derivative_points(np.zeros((3, 2)), 0)


def naive_volume(points, u, v, w):
    l, m, n = (s - 1 for s in points.shape[:3])
    bu, bv, bw = dn.bernstein(l, u), dn.bernstein(m, v), dn.bernstein(n, w)
    return np.einsum("...i,...j,...k,ijkd->...d", bu, bv, bw, points)


def test_volume_matches_bernstein_sum():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(2, 3, 4, 3))
    u, v, w = rng.uniform(size=(3, 25))
    u[:3], v[:3], w[:3] = [0, 1, 1], [0, 0, 1], [1, 1, 0]
    np.testing.assert_allclose(
        dn.de_casteljau_volume(points, u, v, w), naive_volume(points, u, v, w), atol=1e-12
    )
    # Corners of the parameter cube are corner control points.
    np.testing.assert_allclose(dn.de_casteljau_volume(points, 1.0, 0.0, 1.0), points[-1, 0, -1])


def test_volume_broadcasts_and_fixed_w_is_a_surface():
    rng = np.random.default_rng(4)
    points, weights = rng.normal(size=(3, 3, 2, 3)), rng.uniform(0.5, 2, (3, 3, 2))
    u = np.linspace(0, 1, 5)[:, None]
    v = np.linspace(0, 1, 4)[None, :]
    out = dn.de_casteljau_volume(points, u, v, 0.0, weights)
    assert out.shape == (5, 4, 3)
    bu, bv = dn.bernstein(2, u[:, 0]), dn.bernstein(2, v[0])
    num = np.einsum("ai,bj,ij,ijd->abd", bu, bv, weights[:, :, 0], points[:, :, 0])
    den = np.einsum("ai,bj,ij->ab", bu, bv, weights[:, :, 0])
    np.testing.assert_allclose(out, num / den[..., None], atol=1e-12)


def test_volume_rejects_bad_input():
    with pytest.raises(ValueError, match="4 dimensions"):
        dn.de_casteljau_volume(np.zeros((2, 2, 3)), 0.5, 0.5, 0.5)
    with pytest.raises(ValueError, match="w must lie"):
        dn.de_casteljau_volume(np.zeros((2, 2, 2, 3)), 0.5, 0.5, -0.1)


def test_gradients_are_finite():
    points = jnp.asarray(np.random.default_rng(5).normal(size=(4, 2)))
    weights = jnp.array([1.0, 2.0, 0.5, 1.0])

    def loss(points, weights, t):
        (left, wl), (right, wr) = dn.subdivide(points, t, weights)
        hodo = dn.bezier_derivative_points(points)
        vol = dn.de_casteljau_volume(jnp.stack([points, points + 1])[:, :, None], t, t, t)
        return (
            jnp.sum(left**2)
            + jnp.sum(wl)
            + jnp.sum(right)
            + jnp.sum(wr)
            + jnp.sum(hodo**2)
            + jnp.sum(vol)
        )

    grad = jax.jit(jax.grad(loss, argnums=(0, 1, 2)))
    for t in (0.0, 0.4, 1.0):
        grads = grad(points, weights, t)
        assert all(bool(jnp.all(jnp.isfinite(g))) for g in grads)


def test_de_casteljau_surface_shape_is_the_broadcast_shape():
    points = np.arange(12.0).reshape(2, 3, 2)
    assert dn.de_casteljau_surface(points, 0.5, 0.5).shape == (2,)
    assert dn.de_casteljau_surface(points, [0.0, 1.0], [0.0, 1.0]).shape == (2, 2)
