"""Adaptive approximation of functions (seed 003 §5): error bounds checked on independent grids."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.interpolate import make_interp_spline

import diffnurbs as dn


def independent_error(curve, f, a, b, rng, count=200_001):
    """Largest error on a fine uniform grid plus random points: none of them is a point the
    method sampled or checked (those sit at fixed fractions of its spans)."""
    t = np.concatenate([np.linspace(a, b, count), rng.uniform(a, b, 20_000)])
    values = np.asarray(curve(jnp.asarray(t)))[:, 0]
    return np.abs(values - np.asarray(jax.vmap(f)(jnp.asarray(t)))).max()


@pytest.fixture
def rng():
    return np.random.default_rng(3)


def tanh_front(t):
    return jnp.tanh(40 * (t - 0.3))


def test_tanh_front_meets_the_tolerance_with_far_fewer_points_than_uniform_knots(rng):
    tol = 1e-6
    curve, report = dn.fit_function(tanh_front, 0.0, 1.0, tol, full_output=True)
    assert independent_error(curve, tanh_front, 0.0, 1.0, rng) <= tol
    assert curve.control_points.shape == (report.n_control, 1)
    assert report.degree == 3 and curve.degree == 3
    np.testing.assert_array_equal(report.knots, curve.knots)
    assert report.max_error <= tol
    np.testing.assert_allclose(report.features, [0.3], atol=1e-12)  # the inflection point
    assert float(curve.knots[0]) == 0.0 and float(curve.knots[-1]) == 1.0
    # Uniform-knot cubic interpolation (scipy, an independent method) with 400 points is
    # still above the tolerance; the adaptive fit needs well under half of that.
    t = np.linspace(0.0, 1.0, 400)
    uniform = make_interp_spline(t, np.tanh(40 * (t - 0.3)), k=3)
    fine = np.linspace(0.0, 1.0, 200_001)
    assert np.abs(uniform(fine) - np.tanh(40 * (fine - 0.3))).max() > tol
    assert report.n_control < 200


def test_sine_knots_start_at_its_extrema_and_inflection(rng):
    tol = 1e-7
    curve, report = dn.fit_function(jnp.sin, 0.0, 2 * np.pi, tol, full_output=True)
    np.testing.assert_allclose(report.features, [np.pi / 2, np.pi, 3 * np.pi / 2], atol=1e-12)
    assert report.kinks.shape == (0,)
    assert independent_error(curve, jnp.sin, 0.0, 2 * np.pi, rng) <= tol
    knots = np.asarray(curve.knots)
    for feature in report.features:
        assert np.any(knots == feature)


def test_an_inflection_on_a_grid_point_is_found():
    """On [-1, 1] the scan grid holds t = 0 exactly, where f'' = -9 sin 3t is exactly zero:
    the sign change passes through a grid point, not inside a cell (it was missed)."""
    grid = np.asarray(jnp.linspace(-1.0, 1.0, 4097))
    assert grid[2048] == 0.0
    _, report = dn.fit_function(lambda t: jnp.sin(3 * t), -1.0, 1.0, 1e-6, full_output=True)
    np.testing.assert_allclose(report.features, [-np.pi / 6, 0.0, np.pi / 6], atol=1e-12)
    assert report.kinks.shape == (0,)
    _, report = dn.fit_function(
        lambda t: jnp.abs(t - 0.3) + jnp.sin(3 * t), -1.0, 1.0, 1e-6, full_output=True
    )
    assert np.any(report.features == 0.0)
    np.testing.assert_allclose(report.kinks, [0.3], atol=1e-12)


def test_a_kink_with_a_sign_change_of_the_slope_is_fitted_exactly_at_degree_1(rng):
    def f(t):
        return jnp.abs(t - 0.3)

    curve, report = dn.fit_function(f, -1.0, 1.0, 1e-9, full_output=True)
    assert report.degree == 1 and report.n_control == 3
    assert independent_error(curve, f, -1.0, 1.0, rng) <= 1e-12


def test_a_kink_without_a_sign_change_gets_a_multiple_knot(rng):
    """f' jumps from 3 cos(0.9) - 1 to 3 cos(0.9) + 1 at 0.3 without changing sign: no
    extremum there, but the jump is found and the knot made p-fold (C^0)."""

    def f(t):
        return jnp.abs(t - 0.3) + jnp.sin(3 * t)

    tol = 1e-6
    curve, report = dn.fit_function(f, -1.0, 1.0, tol, full_output=True)
    np.testing.assert_allclose(report.kinks, [0.3], atol=1e-12)
    assert np.sum(np.asarray(curve.knots) == report.kinks[0]) == 3
    assert independent_error(curve, f, -1.0, 1.0, rng) <= tol
    assert report.n_control < 100


def test_polynomials_are_reproduced(rng):
    def f(t):
        return t**3 - 2 * t**2 + t - 1

    curve, report = dn.fit_function(f, -1.0, 2.0, 1e-10, full_output=True)
    assert report.degree == 3 and report.steps == 3  # degrees 1, 2, 3 tried, no refinement
    assert independent_error(curve, f, -1.0, 2.0, rng) <= 1e-12


def test_a_straight_line_stays_linear(rng):
    def f(t):
        return 2.0 * t - 1.0

    curve, report = dn.fit_function(f, 0.0, 1.0, 1e-12, full_output=True)
    assert (report.degree, report.n_control, report.steps) == (1, 2, 1)
    assert report.features.shape == (0,)
    assert independent_error(curve, f, 0.0, 1.0, rng) <= 1e-13


def test_max_degree_1_refines_a_polyline(rng):
    tol = 1e-4
    curve, report = dn.fit_function(jnp.cos, -2.0, 3.0, tol, max_degree=1, full_output=True)
    assert report.degree == 1
    assert independent_error(curve, jnp.cos, -2.0, 3.0, rng) <= tol


def test_returns_a_curve_without_full_output():
    curve = dn.fit_function(jnp.exp, 0.0, 1.0, 1e-6)
    assert isinstance(curve, dn.NURBSCurve)
    assert curve.control_points.shape[1] == 1


def test_a_jump_cannot_be_fitted():
    def step(t):
        return jnp.where(t < 0.5, 0.0, 1.0)

    with pytest.raises(RuntimeError, match=r"did not reach tol = 0\.001"):
        dn.fit_function(step, 0.0, 1.0, 1e-3, max_steps=12)


@pytest.mark.parametrize(
    ("args", "kwargs", "message"),
    [
        ((jnp.sin, 0.0, 1.0, 0.0), {}, "tol must be > 0, got 0.0"),
        ((jnp.sin, 0.0, 1.0, -1e-3), {}, "tol must be > 0"),
        ((jnp.sin, 0.0, 1.0, float("nan")), {}, "tol must be a finite number"),
        ((jnp.sin, 1.0, 0.0, 1e-3), {}, "a < b"),
        ((jnp.sin, float("nan"), 1.0, 1e-3), {}, "a must be a finite number"),
        ((jnp.sin, 0.0, 1.0, 1e-3), {"max_degree": 0}, "max_degree must be >= 1"),
        (("sin", 0.0, 1.0, 1e-3), {}, "f must be a callable"),
        ((lambda t: jnp.stack([t, t]), 0.0, 1.0, 1e-3), {}, "scalar to a scalar"),
        ((jnp.log, 0.0, 1.0, 1e-3), {}, "f is not finite at t = 0.0"),
    ],
)
def test_bad_input(args, kwargs, message):
    with pytest.raises(ValueError, match=message):
        dn.fit_function(*args, **kwargs)
