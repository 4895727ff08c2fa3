"""Knot removal (NURBS Book A5.8), `simplify` and degree reduction, of curves and of
surfaces in either direction.

Oracles: knot insertion and degree elevation (removal and reduction must give back exactly
what they started from, control points and knots), the tolerance itself (the curve or
surface, sampled densely, moves by at most `tol`), finite differences for the forced
removal's gradient.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffnurbs as dn

U = np.linspace(0.0, 1.0, 2001)


def random_curve(seed: int, degree: int, rational: bool, n: int = 9) -> dn.NURBSCurve:
    rng = np.random.default_rng(seed)
    weights = rng.uniform(0.5, 2.0, n) if rational else None
    return dn.NURBSCurve(rng.normal(size=(n, 3)), degree, weights=weights)


@pytest.mark.parametrize("rational", [False, True])
@pytest.mark.parametrize("degree", [2, 3, 4])
def test_removal_undoes_insertion(degree, rational):
    curve = random_curve(degree, degree, rational)
    existing = float(curve.knots[degree + 2])  # a simple knot already there
    for u, room in [(0.37, degree), (existing, degree - 1)]:
        for times in range(1, room + 1):
            inserted = curve.insert_knot(u, times)
            back, removed = inserted.remove_knot(u, times)
            assert removed == times, (u, times)
            np.testing.assert_allclose(back.knots, curve.knots, atol=0)
            np.testing.assert_allclose(back.control_points, curve.control_points, atol=1e-12)
            if rational:
                np.testing.assert_allclose(back.weights, curve.weights, atol=1e-12)


def test_a_knot_the_curve_needs_stays():
    curve = random_curve(0, 3, rational=True)
    u = float(curve.knots[5])
    same, removed = curve.remove_knot(u)
    assert removed == 0 and same is curve


@pytest.mark.parametrize("rational", [False, True])
def test_removal_within_a_tolerance_moves_the_curve_by_less(rational):
    curve = random_curve(7, 3, rational).insert_knot(0.4)
    points = np.asarray(curve.control_points).copy()
    points[5] += [0.02, -0.01, 0.015]  # a point the removal solves for: now a little off
    bent = dn.NURBSCurve(points, 3, curve.knots, curve.weights)
    assert bent.remove_knot(0.4, tol=1e-4)[1] == 0
    tol = 0.2  # for the rational curve the test is made on weighted points (eq. 5.30)
    simpler, removed = bent.remove_knot(0.4, tol=tol)
    assert removed == 1 and simpler.control_points.shape[0] == points.shape[0] - 1
    assert np.linalg.norm(simpler(U) - bent(U), axis=1).max() <= tol


def test_simplify_finds_every_inserted_knot():
    rng = np.random.default_rng(3)
    curve = random_curve(3, 3, rational=True)
    refined = curve.refine(np.sort(rng.uniform(size=150)))
    simple = refined.simplify(1e-9)
    np.testing.assert_allclose(simple.knots, curve.knots, atol=0)
    np.testing.assert_allclose(simple.control_points, curve.control_points, atol=1e-9)


@pytest.mark.parametrize("rational", [False, True])
def test_simplify_stays_within_its_tolerance(rational):
    # A fine interpolant of a smooth curve: most of its knots can go within 1e-3.
    t = np.linspace(0.0, 1.0, 80)
    points = np.stack([np.cos(3 * t), np.sin(2 * t), t**2], axis=1)
    curve = dn.interpolate(points, 3)
    if rational:
        curve = dn.NURBSCurve(curve.control_points, 3, curve.knots, np.ones(80))
    tol = 1e-3
    simple = curve.simplify(tol)
    assert simple.control_points.shape[0] < 40, simple.control_points.shape
    assert np.linalg.norm(simple(U) - curve(U), axis=1).max() <= tol


def test_forced_removal_is_differentiable():
    curve = random_curve(5, 3, rational=False)

    def moved(points):
        simpler, _ = dn.NURBSCurve(points, 3, curve.knots).remove_knot(
            float(curve.knots[5]), tol=np.inf
        )
        return jnp.sum(simpler(jnp.linspace(0.0, 1.0, 7)) ** 2)

    points = np.asarray(curve.control_points)
    gradient = np.asarray(jax.grad(moved)(jnp.asarray(points)))
    direction = np.random.default_rng(5).normal(size=points.shape)
    step = 1e-6
    central = (moved(points + step * direction) - moved(points - step * direction)) / (2 * step)
    assert np.isclose(np.sum(gradient * direction), central, rtol=1e-7)


CURVE = random_curve(1, 3, rational=False)
KNOTS, KNOT = np.asarray(CURVE.knots), float(CURVE.knots[5])


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: CURVE.remove_knot(0.123), "is not a knot"),
        (lambda: CURVE.remove_knot(0.0), "is an end of the domain"),
        (lambda: CURVE.remove_knot(float(CURVE.knots[5]), times=0), "times must be >= 1"),
        (lambda: CURVE.remove_knot(float(CURVE.knots[5]), tol=-1.0), "tol must be a positive"),
        (lambda: CURVE.simplify(0.0), "tol must be a positive"),
        (
            lambda: jax.jit(
                lambda p: dn.NURBSCurve(p, 3, KNOTS).remove_knot(KNOT, tol=1e-3)[0].control_points
            )(CURVE.control_points),
            "needs concrete",
        ),
    ],
)
def test_bad_input_is_named(call, message):
    with pytest.raises(ValueError, match=message):
        call()


@pytest.mark.parametrize("rational", [False, True])
@pytest.mark.parametrize("degree", [2, 3, 4])
def test_reduction_undoes_elevation(degree, rational):
    curve = random_curve(10 + degree, degree, rational)
    back = curve.elevate_degree(1).reduce_degree()
    assert back.degree == degree
    np.testing.assert_allclose(back.knots, curve.knots, atol=0)
    np.testing.assert_allclose(back.control_points, curve.control_points, atol=1e-12)


def test_reduction_within_a_tolerance():
    curve = random_curve(20, 3, rational=False).refine(np.linspace(0.05, 0.95, 30))
    tol = 1e-2
    lower = curve.reduce_degree(tol)
    assert lower.degree == 2
    assert np.linalg.norm(lower(U) - curve(U), axis=1).max() <= tol
    with pytest.raises(ValueError, match=r"no curve of degree 2 is within tol = 0\.001"):
        curve.reduce_degree(1e-3)
    line = dn.NURBSCurve(np.eye(2), 1)
    with pytest.raises(ValueError, match="needs degree >= 2"):
        line.reduce_degree(1.0)


@pytest.mark.parametrize("direction", ["u", "v"])
def test_surfaces_in_either_direction(direction):
    rng = np.random.default_rng(30)
    surface = dn.NURBSSurface(
        rng.normal(size=(6, 5, 3)), (3, 2), weights=rng.uniform(0.5, 2.0, (6, 5))
    )
    inserted = surface.insert_knot(0.3, 2, direction=direction)
    back, removed = inserted.remove_knot(0.3, 2, direction=direction)
    assert removed == 2
    np.testing.assert_allclose(back.control_points, surface.control_points, atol=1e-12)
    elevated = surface.elevate_degree(1, direction=direction)
    lowered = elevated.reduce_degree(direction=direction)
    assert lowered.degree == surface.degree
    np.testing.assert_allclose(lowered.control_points, surface.control_points, atol=1e-12)
    refined = surface.refine(np.linspace(0.1, 0.9, 9), direction=direction)
    simple = refined.simplify(1e-9, direction=direction)
    np.testing.assert_allclose(simple.knots_u, surface.knots_u, atol=0)
    np.testing.assert_allclose(simple.knots_v, surface.knots_v, atol=0)
    np.testing.assert_allclose(simple.weights, surface.weights, atol=1e-12)
    # Within a tolerance: fewer control points, and no point of the surface moves more.
    x, y = np.meshgrid(np.linspace(0, 1, 30), np.linspace(0, 1, 30), indexing="ij")
    wavy = dn.interpolate_surface(np.stack([x, y, np.sin(3 * (x + y))], axis=-1), (3, 3))
    tol = 1e-3
    lighter = wavy.simplify(tol, direction=direction)
    assert lighter.control_points.size < wavy.control_points.size
    uu, vv = np.meshgrid(np.linspace(0, 1, 101), np.linspace(0, 1, 101), indexing="ij")
    assert np.linalg.norm(lighter(uu, vv) - wavy(uu, vv), axis=-1).max() <= tol
