"""Arc length as the parameter: `parameter_at_length`, `equal_arc_parameters`,
`reparametrize_by_arc_length`, and the exact PH versions.

Oracles: exact geometry (the circle's angle is its arc length, a polyline's length is
piecewise linear), scipy (the speed from `scipy.interpolate.BSpline`, integrated by
`scipy.integrate.quad`), the PH cubic's closed-form length, finite differences.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, interpolate

import diffnurbs as dn

QUARTER = dn.NURBSCurve(
    np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]), 2, weights=np.array([1, np.sqrt(0.5), 1])
)


def random_curve(seed: int, n: int = 12, dim: int = 3, degree: int = 3) -> dn.NURBSCurve:
    rng = np.random.default_rng(seed)
    inner = np.sort(rng.uniform(size=n - degree - 1))
    inner[2] = inner[3]  # a double knot: the speed is only continuous there
    knots = np.concatenate([np.zeros(degree + 1), inner, np.ones(degree + 1)])
    return dn.NURBSCurve(rng.normal(size=(n, dim)), degree, knots)


def scipy_length(curve: dn.NURBSCurve, a: float, b: float) -> float:
    """The length from `a` to `b` with scipy's B-spline derivative and adaptive quadrature."""
    spline = interpolate.BSpline(
        np.asarray(curve.knots), np.asarray(curve.control_points), curve.degree
    )
    velocity = spline.derivative()
    knots = np.asarray(curve.knots)
    breaks = [k for k in np.unique(knots) if a < k < b]
    value, _ = integrate.quad(
        lambda u: np.linalg.norm(velocity(u)), a, b, points=breaks or None,
        epsabs=0.0, epsrel=2e-14, limit=500,
    )  # fmt: skip
    return value


def test_the_circle_s_angle_is_its_length():
    s = np.linspace(0.0, np.pi / 2, 41)
    points = np.asarray(QUARTER(QUARTER.parameter_at_length(s)))
    angle = np.arctan2(points[:, 1], points[:, 0])
    assert np.abs(angle - s).max() < 1e-14


@pytest.mark.parametrize("seed", [0, 1])
def test_the_inverse_of_arc_length_against_scipy(seed):
    curve = random_curve(seed)
    total = scipy_length(curve, 0.0, 1.0)
    assert np.isclose(float(curve.arc_length()), total, rtol=1e-13, atol=0)
    s = np.random.default_rng(seed).uniform(0.0, total, 12)
    u = np.asarray(curve.parameter_at_length(s))
    reached = np.array([scipy_length(curve, 0.0, x) for x in u])
    np.testing.assert_allclose(reached, s, rtol=1e-12, atol=1e-13 * total)


def test_equal_arc_parameters_cut_equal_pieces():
    curve = random_curve(3, dim=2)
    u = np.asarray(curve.equal_arc_parameters(9))
    assert u[0] == 0.0 and u[-1] == 1.0 and np.all(np.diff(u) > 0)
    pieces = np.array([scipy_length(curve, a, b) for a, b in itertools.pairwise(u)])
    np.testing.assert_allclose(pieces, pieces.mean(), rtol=1e-11)


def test_a_polyline_that_stands_still_gives_the_start_of_the_pause():
    # Degree 1 through (0,0), (1,0), (1,0), (1,2): the middle span has length 0.
    line = dn.NURBSCurve(
        np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.0], [1.0, 2.0]]), 1,
        knots=np.array([0.0, 0.0, 0.25, 0.5, 1.0, 1.0]),
    )  # fmt: skip
    u = np.asarray(line.parameter_at_length(np.array([0.0, 0.5, 1.0, 2.0, 3.0])))
    np.testing.assert_allclose(u, [0.0, 0.125, 0.25, 0.75, 1.0], atol=1e-15)
    slope = jax.grad(lambda s: line.parameter_at_length(s))(2.0)
    assert np.isclose(slope, 1 / 4), "du/ds = 1 / speed on the last span (speed 2 / 0.5)"


def test_gradients_by_the_implicit_function_theorem():
    curve = random_curve(4)
    s = 0.37 * float(curve.arc_length())
    u = curve.parameter_at_length(s)
    du_ds = jax.grad(lambda s: curve.parameter_at_length(s))(s)
    assert np.isclose(du_ds, 1 / np.linalg.norm(curve.derivatives(u, 1)[1]), rtol=1e-12)

    def at(points):
        return dn.NURBSCurve(points, curve.degree, curve.knots).parameter_at_length(s)

    gradient = np.asarray(jax.grad(at)(curve.control_points))
    step, direction = 1e-6, np.random.default_rng(4).normal(size=curve.control_points.shape)
    points = np.asarray(curve.control_points)
    central = (at(points + step * direction) - at(points - step * direction)) / (2 * step)
    assert np.isclose(np.sum(gradient * direction), central, rtol=1e-6)


def test_it_runs_under_jit():
    @jax.jit
    def middle(points):
        curve = dn.NURBSCurve(points, 2, weights=QUARTER.weights)
        return curve(curve.parameter_at_length(curve.arc_length() / 2))

    assert np.allclose(middle(QUARTER.control_points), [np.sqrt(0.5)] * 2, atol=1e-15)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: QUARTER.parameter_at_length(-0.1), "s must lie in"),
        (lambda: QUARTER.parameter_at_length(2.0), "s must lie in"),
        (lambda: QUARTER.parameter_at_length(np.nan), "s must be finite"),
        (lambda: QUARTER.equal_arc_parameters(1), "count must be >= 2"),
        (lambda: QUARTER.equal_arc_parameters(2.5), "count must be a Python int"),
        (lambda: QUARTER.reparametrize_by_arc_length(0.0), "tol must be a positive number"),
        (lambda: dn.ph.parameter_at_length([1.0, 0.0, 0.0, 0.0], 1.5), "s must lie in"),
    ],
)
def test_bad_input_is_named(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_a_unit_speed_circle():
    tol = 1e-8
    unit = QUARTER.reparametrize_by_arc_length(tol)
    assert np.allclose(unit.domain, [0.0, np.pi / 2], atol=1e-15)
    s = np.linspace(0.0, np.pi / 2, 2001)
    ders = np.asarray(unit.derivatives(s, 1))
    assert np.abs(ders[:, 0] - np.c_[np.cos(s), np.sin(s)]).max() <= tol * np.pi / 2
    assert np.abs(np.linalg.norm(ders[:, 1], axis=1) - 1).max() <= tol


def test_a_unit_speed_rational_space_curve():
    rng = np.random.default_rng(5)
    curve = dn.NURBSCurve(rng.normal(size=(8, 3)), 3, weights=rng.uniform(0.5, 2.0, 8))
    tol, total = 1e-5, float(curve.arc_length())
    unit = curve.reparametrize_by_arc_length(tol)
    s = rng.uniform(0.0, total, 3000)
    ders = np.asarray(unit.derivatives(s, 1))
    on_curve = np.asarray(curve(curve.parameter_at_length(s)))
    assert np.abs(np.linalg.norm(ders[:, 1], axis=1) - 1).max() <= tol
    assert np.linalg.norm(ders[:, 0] - on_curve, axis=1).max() <= tol * total
    assert np.allclose(unit(np.array([0.0, total])), curve(np.array([0.0, 1.0])), atol=1e-14)


def test_ph_lengths_are_inverted_exactly():
    coeffs = jnp.array([[1.0, 1.0, 2.0, -2.0], [0.3, -1.2, 0.5, 0.4]])
    count = 7
    u = np.asarray(dn.ph.equal_arc_parameters(coeffs, count))
    a0, a1, b0, b1 = np.asarray(coeffs).T[:, :, None]
    c0, c1, c2 = a0**2 + b0**2, 2 * (a0 * a1 + b0 * b1), a1**2 + b1**2
    length = u * (c0 + u * (c1 / 2 + u * c2 / 3))  # the exact polynomial s(u)
    total = np.asarray(dn.ph.arc_length(coeffs))[:, None]
    np.testing.assert_allclose(length, total * np.linspace(0, 1, count), rtol=1e-14, atol=1e-15)
    # The same parameters as the general, quadrature-based inversion of the PH curve.
    for row, parameters in zip(coeffs, u, strict=True):
        curve = dn.ph.ph_cubic(row, jnp.zeros(2))
        np.testing.assert_allclose(curve.equal_arc_parameters(count), parameters, atol=1e-13)
    slope = jax.grad(lambda s: dn.ph.parameter_at_length(coeffs[0], s))(1.0)
    at = dn.ph.parameter_at_length(coeffs[0], 1.0)
    assert np.isclose(slope, 1 / dn.ph.speed(coeffs[0], at), rtol=1e-14)
