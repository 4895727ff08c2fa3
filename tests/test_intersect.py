"""`curve_intersections`: every intersection of two curves.

Oracles: exact geometry (line and circle, two circles, a tangent line, two space curves
through a known point), a dense brute force on random curves (every sign change of a
crossing test between fine polylines is one intersection found), an overlap of a curve with
its own piece, finite differences for the gradient.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffnurbs as dn

CIRCLE = dn.circle(1.0)


def test_a_line_meets_the_circle_where_the_geometry_says():
    line = dn.NURBSCurve(np.array([[-2.0, 0.5], [2.0, 0.5]]), 1)
    u1, u2 = dn.curve_intersections(line, CIRCLE)
    np.testing.assert_allclose(line(u1), [[-np.sqrt(0.75), 0.5], [np.sqrt(0.75), 0.5]], atol=1e-15)
    np.testing.assert_allclose(CIRCLE(u2), line(u1), atol=1e-15)


def test_two_circles_and_a_tangent():
    other = dn.circle(1.0, center=(1.0, 0.0))
    u1, u2 = dn.curve_intersections(CIRCLE, other)
    points = np.asarray(CIRCLE(u1))
    np.testing.assert_allclose(sorted(points[:, 1]), [-np.sqrt(0.75), np.sqrt(0.75)], atol=1e-15)
    np.testing.assert_allclose(points[:, 0], 0.5, atol=1e-15)
    np.testing.assert_allclose(other(u2), points, atol=1e-15)
    tangent = dn.NURBSCurve(np.array([[-2.0, 1.0], [2.0, 1.0]]), 1)
    u1, _ = dn.curve_intersections(tangent, CIRCLE)
    assert u1.shape == (1,)
    np.testing.assert_allclose(tangent(u1), [[0.0, 1.0]], atol=1e-7)  # a double root: sqrt(eps)


def test_space_curves_through_a_known_point():
    a = dn.NURBSCurve(np.array([[0.0, 0, 0], [1, 1, 1], [2, 0, 2]]), 2)
    point = np.asarray(a(0.3))
    step = np.array([1.0, -1, 0.5])
    b = dn.NURBSCurve(np.array([point - step, point + step]), 1)
    u1, u2 = dn.curve_intersections(a, b)
    np.testing.assert_allclose(u1, [0.3], atol=1e-14)
    np.testing.assert_allclose(u2, [0.5], atol=1e-14)
    far = dn.NURBSCurve(np.array([[0.0, 5, 0], [1, 5, 1]]), 1)
    assert dn.curve_intersections(a, far)[0].shape == (0,)


def crossings(a, b, samples=4000):
    """Brute force: pairs of segments of two fine polylines that cross (2D)."""
    p, q = np.asarray(a(np.linspace(0, 1, samples))), np.asarray(b(np.linspace(0, 1, samples)))
    p0, p1, q0, q1 = p[:-1, None], p[1:, None], q[None, :-1], q[None, 1:]

    def side(o, x, y):
        return np.sign((x[..., 0] - o[..., 0]) * (y[..., 1] - o[..., 1])
                       - (x[..., 1] - o[..., 1]) * (y[..., 0] - o[..., 0]))  # fmt: skip

    hits = (side(p0, p1, q0) != side(p0, p1, q1)) & (side(q0, q1, p0) != side(q0, q1, p1))
    return np.argwhere(hits) / (samples - 1)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_curves_against_a_dense_brute_force(seed):
    rng = np.random.default_rng(seed)
    a = dn.NURBSCurve(rng.normal(size=(10, 2)), 3)
    b = dn.NURBSCurve(rng.normal(size=(10, 2)), 3, weights=rng.uniform(0.5, 2.0, 10))
    u1, u2 = dn.curve_intersections(a, b)
    assert np.abs(np.asarray(a(u1)) - np.asarray(b(u2))).max(initial=0) < 1e-13
    brute = crossings(a, b)
    assert len(u1) == len(brute), (len(u1), len(brute))
    found = np.stack([u1, u2], axis=1)
    for hit in brute:  # each brute-force crossing has a found intersection next to it
        assert np.abs(found - hit).max(axis=1).min() < 2e-3, hit


@pytest.mark.parametrize("shift", [0.0, 0.37])
def test_a_tangential_contact_is_a_point_not_an_overlap(shift):
    # y = (x - shift)^2 against y = 0 (the x axis, and a space version lifted to z = 1):
    # the curves stay within tol over a stretch of about sqrt(tol), yet meet at one point.
    bezier = np.array([[-1.0, 1.0], [0.0, -1.0], [1.0, 1.0]])
    parabola = dn.NURBSCurve(bezier + np.array([shift, 0.0]), 2)
    axis = dn.NURBSCurve(np.array([[-2.0, 0.0], [2.0, 0.0]]), 1)
    for a, b in ((parabola, axis), (axis, parabola)):
        u1, u2, overlaps = dn.curve_intersections(a, b, full_output=True)
        assert overlaps == [] and u1.shape == (1,), (overlaps, u1)
        np.testing.assert_allclose(a(u1), [[shift, 0.0]], atol=1e-7)  # a double root
        np.testing.assert_allclose(b(u2), [[shift, 0.0]], atol=1e-7)
    lift = np.array([0.0, 0.0, 1.0])
    space = [dn.NURBSCurve(np.pad(c.control_points, [(0, 0), (0, 1)]) + lift, c.degree)
             for c in (parabola, axis)]  # fmt: skip
    u1, _, overlaps = dn.curve_intersections(*space, full_output=True)
    assert overlaps == [] and u1.shape == (1,)
    np.testing.assert_allclose(space[0](u1), [[shift, 0.0, 1.0]], atol=1e-7)


def test_a_rotated_tangential_contact_is_one_point():
    # Away from the axes, starts near a contact stop at many points about sqrt(tol) apart
    # (linear convergence, rounding in every coordinate): they must come back as one.
    # y = (x - a)^2 touches y = 0 at x = a; within `tol` of the line for |x - a| <= sqrt(tol).
    rng = np.random.default_rng(5)
    tol = 1e-9
    for _ in range(20):
        a, angle = rng.uniform(0.1, 0.9), rng.uniform(0.0, np.pi)
        turn = np.array([[np.cos(angle), np.sin(angle)], [-np.sin(angle), np.cos(angle)]])
        parabola = np.array([[0.0, a**2], [0.5, a**2 - a], [1.0, (1 - a) ** 2]]) @ turn
        line = np.array([[-0.2, 0.0], [1.2, 0.0]]) @ turn
        c1, c2 = dn.NURBSCurve(parabola, 2), dn.NURBSCurve(line, 1)
        u1, u2, overlaps = dn.curve_intersections(c1, c2, tol, full_output=True)
        assert overlaps == [] and u1.shape == (1,), (a, angle, u1, overlaps)
        assert np.linalg.norm(c1(u1) - c2(u2)) <= tol
        assert abs(float(u1[0]) - a) <= np.sqrt(tol), (a, u1)  # the parabola's x is u


def test_an_overlap_is_reported_as_an_interval():
    rng = np.random.default_rng(4)
    curve = dn.NURBSCurve(rng.normal(size=(4, 2)), 3)  # one Bezier piece
    middle = curve.insert_knot(0.3, 3).insert_knot(0.6, 3).decompose()[1]  # C on [0.3, 0.6]
    u1, _, overlaps = dn.curve_intersections(curve, middle, full_output=True)
    assert len(overlaps) == 1 and len(u1) == 0, (overlaps, u1)
    (start, end), (v_start, v_end) = overlaps[0]
    assert abs(start - 0.3) < 1e-3 and abs(end - 0.6) < 1e-3
    assert abs(v_start - 0.3) < 1e-3 and abs(v_end - 0.6) < 1e-3


def test_gradient_by_the_implicit_function_theorem():
    line_points = jnp.array([[-2.0, 0.5], [2.0, 0.3]])
    start = dn.curve_intersections(dn.NURBSCurve(line_points, 1), CIRCLE)

    def first_x(points):
        line = dn.NURBSCurve(points, 1)
        u1, _ = dn.curve_intersections(line, CIRCLE, start=start)
        return line(u1)[0, 0]

    gradient = jax.grad(first_x)(line_points)
    step, direction = 1e-6, np.random.default_rng(5).normal(size=(2, 2))
    central = (
        first_x(line_points + step * direction) - first_x(line_points - step * direction)
    ) / (2 * step)
    assert np.isclose(np.sum(gradient * direction), central, rtol=1e-6)


def test_bad_input_is_named():
    space = dn.NURBSCurve(np.eye(3), 2)
    with pytest.raises(ValueError, match="one dimension"):
        dn.curve_intersections(CIRCLE, space)
    with pytest.raises(ValueError, match="tol must be a positive"):
        dn.curve_intersections(CIRCLE, CIRCLE, tol=0.0)
    with pytest.raises(ValueError, match="must be a NURBSCurve"):
        dn.curve_intersections(CIRCLE, np.eye(2))
