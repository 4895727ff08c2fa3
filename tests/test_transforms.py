"""jit, vmap and grad through curves and surfaces, including traced construction."""

import subprocess
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import central_difference, nine_point_circle, random_curve, random_surface

import diffnurbs as dn


@pytest.fixture
def curve():
    return random_curve(np.random.default_rng(5), 3, n_control=7, dim=2)


def loss_of(curve, field, u):
    """Sum of squares of the points and their first two derivatives at `u`."""

    def loss(value):
        c = dn.NURBSCurve(
            value if field == "control_points" else curve.control_points,
            curve.degree,
            value if field == "knots" else curve.knots,
            value if field == "weights" else curve.weights,
        )
        return jnp.sum(c(u) ** 2) + jnp.sum(c.derivatives(u, 2) ** 2)

    return loss


@pytest.mark.parametrize("field", ["control_points", "weights", "knots"])
def test_gradients_match_finite_differences(curve, field):
    value = getattr(curve, field)
    # At the ends and at the knots themselves the gradient must be finite ...
    at_knots = loss_of(curve, field, jnp.concatenate([curve.knots, jnp.linspace(0, 1, 13)]))
    assert np.all(np.isfinite(jax.jit(jax.grad(at_knots))(value)))
    # ... and between knots (where the loss is smooth in the knots) it must be right.
    loss = loss_of(curve, field, jnp.array([0.03, 0.1, 0.2, 0.4, 0.6, 0.75, 0.95]))
    grad = jax.jit(jax.grad(loss))(value)
    if field == "knots":  # perturb only the interior knots: the ends must stay sorted
        interior = slice(4, -4)

        def interior_loss(k):
            return float(loss(jnp.asarray(value).at[interior].set(k)))

        expected = central_difference(interior_loss, value[interior])
        np.testing.assert_allclose(grad[interior], expected, rtol=1e-5, atol=1e-5)
    else:
        expected = central_difference(lambda x: float(loss(jnp.asarray(x))), value)
        np.testing.assert_allclose(grad, expected, rtol=1e-5, atol=1e-5)


def test_parameter_gradient_is_the_tangent_at_ends_and_repeated_knots():
    curve = dn.NURBSCurve(
        np.random.default_rng(6).normal(size=(6, 2)), 2, [0, 0, 0, 0.5, 0.5, 0.7, 1, 1, 1]
    )
    for u in [0.0, 0.5, 0.7, 1.0]:
        jacobian = jax.jacfwd(curve)(jnp.asarray(u))
        np.testing.assert_allclose(jacobian, curve.derivatives(u, 1)[1], atol=1e-12)
        assert np.all(np.isfinite(jax.grad(lambda x: jnp.sum(curve(x)))(jnp.asarray(u))))


def test_vmap_over_curves_built_from_traced_arrays():
    rng = np.random.default_rng(8)
    batch = rng.normal(size=(5, 6, 3))
    knots = jnp.array([0, 0, 0, 0.2, 0.6, 0.9, 1, 1, 1.0])
    u = jnp.linspace(0, 1, 11)
    points = jax.vmap(lambda p: dn.NURBSCurve(p, 2, knots)(u))(batch)
    for i in range(5):
        np.testing.assert_allclose(points[i], dn.NURBSCurve(batch[i], 2, knots)(u), atol=1e-14)


def test_jit_with_curve_as_argument_and_vmap_over_parameters(curve):
    u = jnp.linspace(0, 1, 17)
    np.testing.assert_allclose(jax.jit(lambda c, x: c(x))(curve, u), curve(u), atol=1e-14)
    np.testing.assert_allclose(jax.vmap(curve)(u), curve(u), atol=1e-14)
    np.testing.assert_allclose(eqx.filter_jit(lambda c: c.curvature(u))(curve), curve.curvature(u))


def test_surface_gradients_with_respect_to_everything():
    surface = random_surface(np.random.default_rng(9), (2, 3), counts=(4, 5))
    u, v = jnp.array([0.0, 0.3, 1.0]), jnp.array([1.0, 0.5, 0.0])

    def loss(points, weights, knots_u, knots_v, u, v):
        s = dn.NURBSSurface(points, (2, 3), (knots_u, knots_v), weights)
        return jnp.sum(s(u, v) ** 2) + jnp.sum(s.normal(u, v)) + jnp.sum(s.grid(u, v))

    args = (surface.control_points, surface.weights, *surface.knots, u, v)
    grads = jax.jit(jax.grad(loss, argnums=tuple(range(6))))(*args)
    assert all(np.all(np.isfinite(g)) for g in grads)
    expected = central_difference(
        lambda w: float(loss(args[0], jnp.asarray(w), *args[2:])), args[1]
    )
    np.testing.assert_allclose(grads[1], expected, rtol=1e-5, atol=1e-6)


def test_invalid_traced_input_fails_at_run_time():
    @jax.jit
    def evaluate(weights):
        return dn.NURBSCurve(jnp.ones((3, 2)), 2, weights=weights)(0.5)

    assert np.all(np.isfinite(evaluate(jnp.ones(3))))
    with pytest.raises(Exception, match="weights must be finite and positive"):
        evaluate(jnp.array([1.0, -1.0, 1.0])).block_until_ready()


def test_float32_surface_and_gradient():
    circle = nine_point_circle()
    profile = np.asarray(circle.control_points, np.float32)
    net = np.stack([np.column_stack([profile, np.full(9, z)]) for z in (0.0, 1.0)], 1)
    weights = np.repeat(np.asarray(circle.weights, np.float32)[:, None], 2, 1)
    knots = (np.asarray(circle.knots, np.float32), np.array([0, 0, 1, 1], np.float32))
    cylinder = dn.NURBSSurface(net.astype(np.float32), (2, 1), knots, weights)
    u = jnp.linspace(0, 1, 50, dtype=jnp.float32)
    points = cylinder(u, 0.5)
    assert points.dtype == jnp.float32
    np.testing.assert_allclose(jnp.linalg.norm(points[:, :2], axis=-1), 1.0, atol=1e-6)
    grad = jax.grad(lambda p: jnp.sum(dn.NURBSSurface(p, (2, 1), cylinder.knots, weights)(u, u)))(
        cylinder.control_points
    )
    assert grad.dtype == jnp.float32 and np.all(np.isfinite(grad))


def test_library_never_changes_global_config():
    code = (
        "import jax, diffnurbs as dn; dn.NURBSCurve([[0.0, 0], [1, 1]], 1)(0.5); "
        "assert not jax.config.jax_enable_x64"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
