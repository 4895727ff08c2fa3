"""fit_curve: gradient-based fitting of control points, weights and parameters.

Oracles: the exact radius of a circle and the implicit equation of an ellipse, a known
random curve sampled, the `approximate` starting guess, rational Bezier evaluation by
Bernstein polynomials in NumPy, the orthogonality of residuals at the optimum, and central
finite differences. Most fits share one shape (20 points in 2D, a quadratic with 3
control points), so they share one compilation.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffnurbs as dn

SAMPLES = 20
ARC = 2 * np.pi / 3  # 120 degrees


@pytest.fixture
def rng():
    return np.random.default_rng(6)


def arc_angles(rng):
    """Non-uniformly spaced angles over the arc, both ends included."""
    return np.sort(np.concatenate([[0.0, ARC], rng.uniform(0.0, ARC, SAMPLES - 2)]))


def noisy_arc(rng):
    theta = arc_angles(rng)
    return np.column_stack([np.cos(theta), np.sin(theta)]) + 1e-2 * rng.standard_normal(
        (SAMPLES, 2)
    )


def bezier_points(control, weights, u):
    """Rational Bezier curve by its Bernstein sum (single segment on [0, 1])."""
    n = control.shape[0] - 1
    basis = np.stack([math.comb(n, i) * u**i * (1 - u) ** (n - i) for i in range(n + 1)], -1)
    weighted = basis * weights
    return weighted @ control / weighted.sum(-1, keepdims=True)


CHECK = np.linspace(0.0, 1.0, 2001)


def test_rational_quadratic_recovers_a_circular_arc_exactly(rng):
    theta = arc_angles(rng)
    points = np.column_stack([np.cos(theta), np.sin(theta)])
    curve, report = dn.fit_curve(
        points, 3, 2, rational=True, correct_parameters=True, full_output=True
    )
    radius_error = np.abs(np.linalg.norm(curve(CHECK), axis=1) - 1).max()
    assert radius_error <= 1e-10
    assert bool(report.converged) and float(report.max_residual) <= 1e-10
    # The arc in standard form: middle weight cos(60 deg), middle point where the end
    # tangents meet.
    np.testing.assert_allclose(curve.weights, [1.0, 0.5, 1.0], atol=1e-9)
    np.testing.assert_allclose(curve.control_points[1], [1.0, np.sqrt(3)], atol=1e-9)
    # The polynomial quadratic with the same control count, parameters corrected too.
    poly = dn.fit_curve(points, 3, 2, correct_parameters=True)
    assert not poly.rational
    poly_error = np.abs(np.linalg.norm(poly(CHECK), axis=1) - 1).max()
    assert poly_error > 1e6 * max(radius_error, 1e-16)
    assert poly_error > 1e-3


def test_rational_quadratic_recovers_an_elliptic_arc_exactly(rng):
    a, b, phase = 2.0, 0.7, 0.4
    theta = arc_angles(rng) + phase
    points = np.column_stack([a * np.cos(theta), b * np.sin(theta)])
    curve = dn.fit_curve(points, 3, 2, rational=True, correct_parameters=True)
    x, y = np.asarray(curve(CHECK)).T
    assert np.abs((x / a) ** 2 + (y / b) ** 2 - 1).max() <= 1e-10
    poly = dn.fit_curve(points, 3, 2, correct_parameters=True)
    x, y = np.asarray(poly(CHECK)).T
    assert np.abs((x / a) ** 2 + (y / b) ** 2 - 1).max() > 1e-3


@pytest.mark.parametrize("rational", [False, True])
def test_recovers_a_known_curve_from_its_samples_with_its_knots(rng, rational):
    degree, n_control = 3, 7
    inner = np.sort(rng.uniform(0.1, 0.9, n_control - degree - 1))
    knots = np.concatenate([np.zeros(degree + 1), inner, np.ones(degree + 1)])
    control = rng.uniform(-1.0, 1.0, (n_control, 3))
    weights = rng.uniform(0.6, 1.6, n_control) if rational else None
    truth = dn.NURBSCurve(control, degree, knots, weights)
    u = np.sort(np.concatenate([[0.0, 1.0], rng.uniform(0.0, 1.0, 58)]))
    points = truth(u)
    curve, report = dn.fit_curve(
        points,
        n_control,
        degree,
        rational=rational,
        parametrization=u,
        full_output=True,
        knots=knots,
    )
    np.testing.assert_array_equal(curve.knots, knots)
    np.testing.assert_allclose(curve(CHECK), truth(CHECK), atol=1e-9)
    np.testing.assert_allclose(curve.control_points, control, atol=1e-8)
    if rational:  # the weights up to the common scale, fixed by the first
        np.testing.assert_allclose(curve.weights, weights / weights[0], rtol=1e-8)
    assert float(report.max_residual) <= 1e-10


@pytest.mark.parametrize(
    "rational, correct", [(False, False), (True, False), (False, True), (True, True)]
)
def test_never_worse_than_the_starting_guess_and_report_recomputed(rng, rational, correct):
    points = noisy_arc(rng)
    start = dn.approximate(points, 3, 2)
    u0 = np.asarray(dn.parametrize(points))
    start_rms = np.sqrt(np.mean(np.sum((np.asarray(start(u0)) - points) ** 2, -1)))
    curve, report = dn.fit_curve(
        points, 3, 2, rational=rational, correct_parameters=correct, full_output=True
    )
    weights = np.ones(3) if curve.weights is None else np.asarray(curve.weights)
    u = np.asarray(report.parameters)
    distances = np.linalg.norm(
        bezier_points(np.asarray(curve.control_points), weights, u) - points, axis=1
    )
    np.testing.assert_allclose(float(report.rms_residual), np.sqrt(np.mean(distances**2)))
    np.testing.assert_allclose(float(report.max_residual), distances.max())
    assert bool(report.converged) and int(report.steps) > 0
    assert float(report.rms_residual) < start_rms  # strictly: ends are not interpolated now
    if not correct:
        np.testing.assert_array_equal(u, u0)


def test_parameter_correction_reduces_the_residual_to_orthogonal_errors(rng):
    points = noisy_arc(rng)
    fixed, fixed_report = dn.fit_curve(points, 3, 2, rational=True, full_output=True)
    curve, report = dn.fit_curve(
        points, 3, 2, rational=True, correct_parameters=True, full_output=True
    )
    assert float(report.rms_residual) < 0.5 * float(fixed_report.rms_residual)

    def orthogonality(curve, u):
        ders = np.asarray(curve.derivatives(u, 1))
        tangent = ders[:, 1] / np.linalg.norm(ders[:, 1], axis=1, keepdims=True)
        return np.abs(np.sum(tangent * (ders[:, 0] - points), axis=1))[1:-1]

    u = np.asarray(report.parameters)
    assert np.all((u >= 0) & (u <= 1))
    assert orthogonality(curve, u).max() <= 1e-9
    # Without correction the errors are not orthogonal: the check has teeth.
    assert orthogonality(fixed, np.asarray(fixed_report.parameters)).max() > 1e-3


@pytest.mark.parametrize(
    "options, h",
    [
        # weights and parameters as unknowns (one segment: the last weight held too)
        (dict(n_control=3, rational=True, correct_parameters=True), 1e-3),
        # fixed centripetal parameters and knots from them, both depending on the points;
        # a small step, since the loss is only C^1 where a knot crosses an evaluation point
        (dict(n_control=5), 1e-4),
    ],
)
def test_gradient_with_respect_to_the_points_matches_finite_differences(rng, options, h):
    points = jnp.asarray(noisy_arc(rng))
    at = jnp.linspace(0.0, 1.0, 9)

    def loss(q):
        # A tight tol: the finite differences divide the solver's error by the step.
        curve = dn.fit_curve(q, degree=2, tol=1e-12, **options)
        return jnp.sum(jnp.sin(3 * curve(at)))

    grad = np.asarray(jax.grad(loss)(points))
    assert np.all(np.isfinite(grad))
    for k, d in [(0, 0), (9, 1), (SAMPLES - 1, 1)]:

        def shifted(s, k=k, d=d):
            return float(loss(points.at[k, d].add(s)))

        # Fourth-order central difference: truncation ~h^4, solver error / h <~1e-7.
        central = (8 * (shifted(h) - shifted(-h)) - (shifted(2 * h) - shifted(-2 * h))) / (12 * h)
        np.testing.assert_allclose(grad[k, d], central, rtol=1e-6)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(points=np.zeros((2, 2)), n_control=3), r"at most 2 control points \(the number of"),
        (dict(n_control=2), "control points"),
        (dict(points=np.full((20, 2), np.nan)), "finite"),
        (dict(degree=0, rational=True), "degree"),
        (dict(max_steps=0), "max_steps"),
        (dict(max_steps=2.5), "max_steps"),
        (dict(tol=0.0), "tol"),
        (dict(tol=-1e-8), "tol"),
        (dict(rational="yes"), "rational"),
        (dict(points=np.zeros(6)), "dimensions"),
        (dict(knots=np.linspace(0, 1, 6)), "clamped"),
        (dict(knots=np.linspace(0, 1, 5)), "knots"),
    ],
)
def test_bad_input_raises_value_error(rng, kwargs, message):
    arguments = dict(points=noisy_arc(rng), degree=2, n_control=3) | kwargs
    with pytest.raises(ValueError, match=message):
        dn.fit_curve(**arguments)
