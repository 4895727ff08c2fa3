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
    fixed, fixed_report = dn.fit_curve(
        points, 3, 2, rational=True, correct_parameters=False, full_output=True
    )
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


CONIC_SAMPLES = 200


def conic_samples(kind, spacing, rng):
    """200 points of a quarter circle, an elliptic or a hyperbolic arc, with the residual
    of the conic's implicit equation as the oracle: evenly spaced in the angle (or the
    hyperbolic angle), evenly spaced in arc length, or at random."""
    a, b = (1.0, 1.0) if kind == "circle" else (2.0, 0.7)
    start, stop = (0.3, 1.9) if kind != "hyperbola" else (-1.2, 0.8)
    if kind == "circle":
        start, stop = 0.0, np.pi / 2
    cos, sin, sign = (np.cosh, np.sinh, -1.0) if kind == "hyperbola" else (np.cos, np.sin, 1.0)
    if spacing == "angle":
        t = np.linspace(start, stop, CONIC_SAMPLES)
    elif spacing == "random":
        t = np.sort(np.r_[start, stop, rng.uniform(start, stop, CONIC_SAMPLES - 2)])
    else:  # arc length, from a fine polyline
        fine = np.linspace(start, stop, 100_001)
        xy = np.column_stack([a * cos(fine), b * sin(fine)])
        length = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
        t = np.interp(np.linspace(0.0, length[-1], CONIC_SAMPLES), length, fine)
    points = np.column_stack([a * cos(t), b * sin(t)])

    def residual(xy):
        x, y = np.asarray(xy).T
        return np.abs((x / a) ** 2 + sign * (y / b) ** 2 - 1)

    return points, residual


@pytest.mark.parametrize("kind", ["circle", "ellipse", "hyperbola"])
@pytest.mark.parametrize("spacing", ["angle", "arc length", "random"])
def test_a_rational_fit_recovers_a_conic_by_default(rng, kind, spacing):
    points, residual = conic_samples(kind, spacing, rng)
    curve, report = dn.fit_curve(points, 3, 2, rational=True, full_output=True)
    assert bool(report.converged)
    # Fresh points of the fitted curve lie on the conic (for the circle the implicit
    # residual is the distance to it, to first order).
    assert residual(curve(CHECK)).max() <= 1e-12
    u = np.asarray(report.parameters)
    assert np.all(np.diff(u) > 0) and u[0] == 0.0 and u[-1] == 1.0
    # Without parameter correction the same fit misses the conic by far.
    fixed = dn.fit_curve(points, 3, 2, rational=True, correct_parameters=False)
    assert residual(fixed(CHECK)).max() > 1e-6


def test_the_default_rational_cubic_recovers_a_circle_without_options(rng):
    points, residual = conic_samples("circle", "random", rng)
    curve = dn.fit_curve(points, rational=True)
    assert curve.degree == 3 and curve.control_points.shape == (4, 2)
    assert residual(curve(CHECK)).max() <= 1e-12


def periodic_rational_curve(rng, n_control=8, degree=3):
    """A random closed rational curve on non-uniform periodic knots over [0, 1]."""
    steps = rng.uniform(0.7, 1.3, n_control)
    knots = np.asarray(dn.periodic_knots(np.r_[0.0, np.cumsum(steps) / steps.sum()], degree))
    angle = 2 * np.pi * np.arange(n_control) / n_control
    control = 2 * np.column_stack([np.cos(angle), np.sin(angle)])
    control += rng.uniform(-0.5, 0.5, (n_control, 2))
    weights = rng.uniform(0.6, 1.6, n_control)
    wrap = np.r_[np.arange(n_control), np.arange(degree)]
    return dn.NURBSCurve(control[wrap], degree, knots, weights[wrap]), knots


@pytest.mark.parametrize("correct", [False, True])
def test_a_closed_rational_fit_recovers_a_periodic_rational_curve(rng, correct):
    truth, knots = periodic_rational_curve(rng)
    u = np.r_[0.0, np.sort(rng.uniform(0.0, 1.0, 59)), 1.0]
    points = truth(u[:-1])
    # With correction the parameters start from the centripetal ones, not the true ones.
    parametrization = "centripetal" if correct else u
    curve, report = dn.fit_curve(
        points,
        8,
        3,
        rational=True,
        closed=True,
        correct_parameters=correct,
        parametrization=parametrization,
        knots=knots,
        full_output=True,
    )
    assert bool(report.converged) and float(report.max_residual) <= 1e-12
    assert curve.control_points.shape == (11, 2)
    np.testing.assert_array_equal(curve.knots, knots)
    if not correct:
        np.testing.assert_allclose(curve(CHECK), truth(CHECK), atol=1e-12)
        np.testing.assert_allclose(curve.weights, truth.weights / truth.weights[0], rtol=1e-10)
    else:
        # The same curve, possibly met at other parameters: every fresh point of the fit
        # lies on the truth (its nearest point there, by point inversion, is itself).
        fresh = curve(CHECK[::20])
        np.testing.assert_allclose(truth(truth.closest_point(fresh)), fresh, atol=1e-10)


def test_a_closed_fit_is_c_p_minus_1_at_the_seam(rng):
    angle = np.sort(rng.uniform(0.0, 2 * np.pi, 40))
    points = np.column_stack([np.cos(angle), 0.6 * np.sin(angle) + 0.2 * np.cos(3 * angle)])
    curve = dn.fit_curve(points, 7, 3, rational=True, closed=True)
    ders = np.asarray(curve.derivatives(jnp.asarray([0.0, 1.0]), 3))
    scale = np.abs(ders).max(axis=(0, 2))[:, None]
    np.testing.assert_allclose(ders[0, :3] / scale[:3], ders[1, :3] / scale[:3], atol=1e-10)
    assert np.abs(ders[0, 3] - ders[1, 3]).max() > 1e-3 * scale[3, 0]  # not C^p: teeth


def test_closed_fit_with_a_control_point_per_point_and_fixed_parameters_interpolates(rng):
    points = noisy_arc(rng)[:12] + np.array([[0.0, 0.3]]) * np.arange(12)[:, None] % 1.0
    fit = dn.fit_curve(points, 12, 3, closed=True)
    interpolant = dn.interpolate(points, 3, closed=True)
    np.testing.assert_allclose(fit.control_points, interpolant.control_points, atol=1e-10)


def test_parameter_correction_stays_linear_in_the_points(rng):
    """10^3 points go through the structured steps (a dense step would be O(m^3)): a
    quarter circle from 1000 random samples, recovered to rounding."""
    theta = np.sort(np.r_[0.0, np.pi / 2, rng.uniform(0.0, np.pi / 2, 998)])
    points = np.column_stack([np.cos(theta), np.sin(theta)])
    curve, report = dn.fit_curve(points, 3, 2, rational=True, full_output=True)
    assert bool(report.converged) and int(report.steps) <= 30
    assert np.abs(np.linalg.norm(curve(CHECK), axis=1) - 1).max() <= 1e-12


def test_gradient_of_a_closed_rational_fit_with_parameter_correction(rng):
    # Noisy samples of a closed rational cubic, fitted with its knots: a well-posed fit
    # (a rational fit of data no such curve is near can drive weights to 0 or infinity).
    truth, knots = periodic_rational_curve(rng, 5, 3)
    u = np.r_[0.0, np.sort(rng.uniform(0.0, 1.0, 39))]
    points = jnp.asarray(truth(u) + 1e-3 * rng.normal(size=(40, 2)))
    at = jnp.linspace(0.0, 1.0, 9)

    def loss(q):
        curve = dn.fit_curve(q, 5, 3, rational=True, closed=True, knots=knots, tol=1e-13)
        return jnp.sum(jnp.sin(3 * curve(at)))

    grad = np.asarray(jax.grad(loss)(points))
    assert np.all(np.isfinite(grad))
    # Forward mode (the implicit JVP) and reverse mode (its transpose) agree, at one optimum:
    # separate runs stop within ~1e-9 of each other along the flattest direction.
    _, jvp = jax.linearize(loss, points)
    (vjp,) = jax.linear_transpose(jvp, points)(1.0)
    tangent = jnp.zeros_like(points).at[3, 1].set(1.0)
    np.testing.assert_allclose(jvp(tangent), vjp[3, 1], rtol=1e-12)
    np.testing.assert_allclose(vjp, grad, rtol=1e-7, atol=1e-9)
    # The optimum is found to about 1e-9 along its flattest direction (the loss can no
    # longer tell better from worse there), so the step stays large: solver error / h
    # ~1e-6 of the derivative, fourth-order truncation less.
    h = 1e-3
    for k, d in [(0, 0), (3, 1), (39, 1)]:

        def shifted(s, k=k, d=d):
            return float(loss(points.at[k, d].add(s)))

        central = (8 * (shifted(h) - shifted(-h)) - (shifted(2 * h) - shifted(-2 * h))) / (12 * h)
        np.testing.assert_allclose(grad[k, d], central, rtol=1e-6)


LOOP = np.column_stack([np.cos(np.arange(20) * 0.3), np.sin(np.arange(20) * 0.3)])


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
        (dict(correct_parameters="yes"), "correct_parameters"),
        (dict(closed=1), "closed"),
        (dict(points=np.zeros((2, 2)), closed=True), r"at most 2 control points"),
        (dict(n_control=21, closed=True), r"at most 20 control points"),
        (dict(n_control=2, closed=True), r"at least p \+ 1 = 3 control points"),
        (dict(points=np.r_[np.full((1, 2), np.nan), np.ones((19, 2))], closed=True), "finite"),
        (
            dict(points=np.r_[LOOP[:19], LOOP[:1]], closed=True),
            "without repeating the first",
        ),
        (dict(closed=True, knots=np.linspace(-1, 2, 9)), r"n_control \+ 2 p \+ 1 = 8 periodic"),
        (dict(closed=True, knots=np.r_[-0.5, -0.2, 0, 0.3, 0.5, 1, 1.3, 1.8]), "period"),
        (dict(closed=True, parametrization=np.linspace(0, 1, 20)), "21 parameters"),
    ],
)
def test_bad_input_raises_value_error(rng, kwargs, message):
    arguments = dict(points=noisy_arc(rng), degree=2, n_control=3) | kwargs
    with pytest.raises(ValueError, match=message):
        dn.fit_curve(**arguments)
