import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import naive_curve, naive_surface, nine_point_circle, random_curve, random_surface

import diffnurbs as dn


@pytest.mark.parametrize("degree", [1, 2, 3, 5])
@pytest.mark.parametrize("rational", [False, True])
def test_curve_insertion_keeps_the_shape(degree, rational):
    rng = np.random.default_rng(degree + 10 * rational)
    curve = random_curve(rng, degree, dim=3, rational=rational)
    u = np.linspace(0, 1, 401)
    value = 0.4321
    inserted = curve.insert_knot(value, times=degree)
    assert inserted.control_points.shape[0] == curve.control_points.shape[0] + degree
    assert int(np.sum(np.asarray(inserted.knots) == value)) == degree
    np.testing.assert_allclose(inserted(u), curve(u), atol=1e-12)
    refined = curve.refine(rng.uniform(0.05, 0.95, size=6))
    np.testing.assert_allclose(refined(u), curve(u), atol=1e-12)


def test_decomposition_into_bezier_pieces():
    circle = nine_point_circle(2.0)
    pieces = circle.decompose()
    assert len(pieces) == 4
    for piece in pieces:
        a, b = piece.domain
        t = np.linspace(float(a), float(b), 33)
        np.testing.assert_allclose(piece(t), circle(t), atol=1e-14)
        local = (t - float(a)) / (float(b) - float(a))
        bezier = dn.de_casteljau(piece.control_points, local, piece.weights)
        np.testing.assert_allclose(bezier, circle(t), atol=1e-14)


@pytest.mark.parametrize("direction", ["u", "v"])
def test_surface_insertion_and_decomposition(direction):
    rng = np.random.default_rng(3)
    surface = random_surface(rng, (2, 3), counts=(5, 6))
    u, v = rng.uniform(size=100), rng.uniform(size=100)
    inserted = surface.insert_knot(0.61, times=2, direction=direction)
    np.testing.assert_allclose(inserted(u, v), surface(u, v), atol=1e-12)
    refined = surface.refine([0.2, 0.2, 0.9], direction=direction)
    np.testing.assert_allclose(refined(u, v), surface(u, v), atol=1e-12)
    for row in surface.decompose():
        for patch in row:
            (a, b), (c, d) = patch.domain
            uu, vv = np.meshgrid(
                np.linspace(float(a), float(b), 5), np.linspace(float(c), float(d), 5)
            )
            np.testing.assert_allclose(patch(uu, vv), surface(uu, vv), atol=1e-12)


def test_inserted_knot_value_does_not_move_the_curve():
    curve = random_curve(np.random.default_rng(4), 3, n_control=7, dim=2)
    t = jnp.linspace(0, 1, 9)

    @jax.jit
    def loss(value):
        return jnp.sum(curve.insert_knot(value)(t) ** 2)

    np.testing.assert_allclose(loss(0.45), jnp.sum(curve(t) ** 2), rtol=1e-12)
    np.testing.assert_allclose(jax.grad(loss)(0.45), 0.0, atol=1e-9)


def test_bad_insertions():
    curve = dn.NURBSCurve(np.zeros((5, 2)), 2, [0, 0, 0, 0.5, 0.5, 1, 1, 1])
    with pytest.raises(ValueError, match="multiplicity 2; at most degree = 2"):
        curve.insert_knot(0.5)
    with pytest.raises(ValueError, match="domain"):
        curve.insert_knot(1.5)
    with pytest.raises(ValueError, match="times must be >= 1"):
        curve.insert_knot(0.3, times=0)
    with pytest.raises(ValueError, match="clamped end knots"):
        dn.NURBSCurve(np.zeros((4, 2)), 2, [0, 1, 2, 3, 4, 5, 6]).decompose()
    with pytest.raises(ValueError, match='direction must be "u" or "v"'):
        dn.NURBSSurface(np.zeros((3, 3, 3)), (2, 2)).insert_knot(0.5, direction="w")


@pytest.mark.parametrize("degree, times", [(1, 1), (2, 1), (3, 2)])
@pytest.mark.parametrize("rational", [False, True])
def test_degree_elevation_keeps_the_shape_and_the_continuity(degree, times, rational):
    rng = np.random.default_rng(20 + degree)
    interior = [0.3, 0.3, 0.7][: degree + 1] if degree > 1 else [0.3, 0.7]
    knots = np.r_[[0.0] * (degree + 1), interior, [1.0] * (degree + 1)]
    n_control = len(knots) - degree - 1
    weights = rng.uniform(0.3, 3.0, n_control) if rational else None
    curve = dn.NURBSCurve(rng.normal(size=(n_control, 3)), degree, knots, weights)
    elevated = curve.elevate_degree(times)
    assert elevated.degree == degree + times
    assert elevated.rational == rational
    # Every distinct knot appears `times` more often: the continuity C^(p - m) is kept.
    values, counts = np.unique(knots, return_counts=True)
    new_values, new_counts = np.unique(np.asarray(elevated.knots), return_counts=True)
    np.testing.assert_array_equal(new_values, values)
    np.testing.assert_array_equal(new_counts, counts + times)
    u = np.linspace(0, 1, 501)
    np.testing.assert_allclose(elevated(u), curve(u), atol=1e-12)


def test_elevating_a_bezier_curve_matches_the_closed_form():
    # Degree elevation of a Bezier curve: Q_i = i/(n+1) P_{i-1} + (1 - i/(n+1)) P_i.
    points = np.random.default_rng(5).normal(size=(4, 2))
    n = len(points) - 1
    padded = np.r_[points[:1] * 0, points, points[:1] * 0]
    i = np.arange(n + 2)[:, None]
    expected = i / (n + 1) * padded[i[:, 0]] + (1 - i / (n + 1)) * padded[i[:, 0] + 1]
    elevated = dn.NURBSCurve(points, n).elevate_degree()
    np.testing.assert_allclose(elevated.control_points, expected, atol=1e-13)


@pytest.mark.parametrize("direction", ["u", "v"])
def test_surface_degree_elevation(direction):
    rng = np.random.default_rng(8)
    surface = random_surface(rng, (2, 1), counts=(4, 3))
    elevated = surface.elevate_degree(2, direction=direction)
    expected = (4, 1) if direction == "u" else (2, 3)
    assert elevated.degree == expected
    u, v = rng.uniform(size=200), rng.uniform(size=200)
    np.testing.assert_allclose(elevated(u, v), surface(u, v), atol=1e-12)


def test_degree_elevation_is_differentiable_in_the_control_points():
    curve = random_curve(np.random.default_rng(9), 2, n_control=5, dim=2, rational=False)
    u = jnp.linspace(0, 1, 7)

    def moment(points, elevate):
        moved = dn.NURBSCurve(points, 2, curve.knots)
        return jnp.sum(jnp.sin((moved.elevate_degree() if elevate else moved)(u)))

    expected = jax.grad(moment)(curve.control_points, False)
    np.testing.assert_allclose(jax.grad(moment)(curve.control_points, True), expected, atol=1e-12)


def test_degree_elevation_rejects_bad_times():
    curve = random_curve(np.random.default_rng(10), 2, dim=2)
    with pytest.raises(ValueError, match="times"):
        curve.elevate_degree(0)
    with pytest.raises(ValueError, match="direction"):
        dn.NURBSSurface(np.zeros((3, 3, 3)), (2, 2)).elevate_degree(1, direction="w")


UNCLAMPED_KNOTS = {
    # 0, 1, ..., n + p: p knots beyond each end of the domain [p, n + 1].
    "uniform": lambda n_control, p: np.arange(n_control + p + 1.0),
    # Ends of multiplicity 1 and 2 (p >= 2), a double interior knot, uneven spans.
    "mixed": lambda n_control, p: np.r_[
        np.linspace(-1.0, -0.1, p),
        [0.0, 0.3, 0.3],
        np.linspace(0.45, 0.9, n_control - p - 3),
        [1.0, 1.0],
        np.linspace(1.4, 2.5, p - 1),
    ],
}


@pytest.mark.parametrize(
    "kind, degree, times",
    [("uniform", 1, 1), ("uniform", 2, 1), ("uniform", 3, 2), ("mixed", 2, 1), ("mixed", 3, 2)],
)
@pytest.mark.parametrize("rational", [False, True])
def test_degree_elevation_of_unclamped_knots(kind, degree, times, rational):
    # Knots beyond the domain: collocation in the elevated space had basis functions
    # without a site (NaN or wrong control points, negative weights).
    rng = np.random.default_rng(100 + 10 * degree + times + 5 * rational)
    n_control = degree + 6
    knots = UNCLAMPED_KNOTS[kind](n_control, degree)
    weights = rng.uniform(0.3, 3.0, n_control) if rational else None
    curve = dn.NURBSCurve(rng.normal(size=(n_control, 3)), degree, knots, weights)
    elevated = curve.elevate_degree(times)
    assert elevated.degree == degree + times
    assert elevated.rational == rational
    a, b = knots[degree], knots[-degree - 1]
    np.testing.assert_array_equal(elevated.domain, (a, b))
    u = np.linspace(a, b, 801)
    # The oracle: the Cox-de Boor recursion on the original knots (helpers.naive_curve).
    np.testing.assert_allclose(elevated(u), naive_curve(curve, u), atol=1e-12)
    if rational:
        assert np.all(np.asarray(elevated.weights) > 0)
    # The result is clamped; inside the domain every knot appears `times` more often.
    inside = knots[(knots > a) & (knots < b)]
    values, counts = np.unique(inside, return_counts=True)
    expected = np.r_[[a] * (degree + times + 1), np.repeat(values, counts + times)]
    expected = np.r_[expected, [b] * (degree + times + 1)]
    np.testing.assert_array_equal(elevated.knots, expected)


def test_degree_elevation_across_a_discontinuity():
    # An interior knot of multiplicity p + 1 splits the curve in two: each piece is elevated
    # on its own (collocation across it had two sites at the same place).
    rng = np.random.default_rng(31)
    knots = [0, 0, 0, 0.4, 0.4, 0.4, 0.7, 1, 1, 1.0]
    curve = dn.NURBSCurve(rng.normal(size=(7, 2)), 2, knots, rng.uniform(0.5, 2.0, 7))
    elevated = curve.elevate_degree(2)
    u = np.r_[np.linspace(0, 1, 401), np.nextafter(0.4, 0)]
    np.testing.assert_allclose(elevated(u), naive_curve(curve, u), atol=1e-12)
    np.testing.assert_array_equal(np.unique(elevated.knots, return_counts=True)[1], [5, 5, 3, 5])


@pytest.mark.parametrize("rational", [False, True])
def test_degree_elevation_matches_splipy_control_points(rational):
    # splipy raises the order of clamped splines explicitly (Huang, Hu and Martin's
    # derivative algorithm), on the same knot vector: the control points must agree.
    from splipy import BSplineBasis, Curve

    rng = np.random.default_rng(32 + rational)
    knots = [0, 0, 0, 0, 0.2, 0.5, 0.5, 0.7, 1, 1, 1, 1.0]
    weights = rng.uniform(0.3, 3.0, 8) if rational else None
    curve = dn.NURBSCurve(rng.normal(size=(8, 3)), 3, knots, weights)
    for times in (1, 2):
        elevated = curve.elevate_degree(times)
        oracle = Curve(BSplineBasis(4, knots), np.asarray(curve.homogeneous_points()), rational)
        oracle.raise_order(times)
        np.testing.assert_allclose(elevated.knots, oracle.knots(0, with_multiplicities=True))
        np.testing.assert_allclose(elevated.homogeneous_points(), oracle.controlpoints, atol=1e-12)


def test_degree_elevation_of_splipy_periodic_rational_curve():
    # splipy's periodic test curve (its test_periodic_split): a rational cubic, C2 across
    # the seam, control points in projective form (w x, w y, w). splipy elevates it as a
    # periodic spline, which is the oracle here.
    from splipy import BSplineBasis, Curve

    xyw = [(1, 0, 1), (1, 1, 0.7), (0, 1, 0.89), (-1, 1, 0.5), (-1, 0, 1), (-1, -0.5, 1)]
    projective = np.array([*xyw, (1, -0.5, 1)])
    knots = np.array([-3, -2, -1, 0, 1, 2, 2.5, 4, 5, 6, 7, 8, 9, 9.5])
    oracle = Curve(BSplineBasis(4, knots, 2), projective, rational=True)
    wrapped = np.concatenate([projective, projective[:3]])  # continuity 2: three repeat
    curve = dn.NURBSCurve(wrapped[:, :2] / wrapped[:, 2:], 3, knots, wrapped[:, 2])
    u = np.linspace(0.0, 7.0, 701)
    np.testing.assert_allclose(curve(u), oracle(u), atol=1e-12)
    elevated = curve.elevate_degree(2)
    assert elevated.degree == 5
    np.testing.assert_allclose(elevated(u), oracle.raise_order(2)(u), atol=1e-12)
    np.testing.assert_allclose(elevated(u), curve(u), atol=1e-12)


def test_degree_elevation_of_an_unclamped_circle():
    # splipy's test circle (its test_insert_knot): knots -1, 0, 0, 1, 1, ..., 4, 4, 5, the
    # first and last beyond the domain [0, 4]. (splipy's own raise_order gives NaN here.)
    s = np.sqrt(0.5)
    square = [(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0)]
    weights = np.tile([1, s], 5)[:9]
    knots = [-1, 0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5]
    curve = dn.NURBSCurve(np.array(square, float), 2, knots, weights)
    u = np.linspace(0.0, 4.0, 401)
    for times in (1, 3):
        elevated = curve.elevate_degree(times)
        np.testing.assert_allclose(np.linalg.norm(elevated(u), axis=-1), 1.0, atol=1e-12)
        np.testing.assert_allclose(elevated(u), naive_curve(curve, u), atol=1e-12)


@pytest.mark.parametrize("direction", ["u", "v"])
def test_surface_degree_elevation_of_unclamped_knots(direction):
    rng = np.random.default_rng(33)
    knots = (np.arange(9.0), np.arange(8.0))  # degrees (3, 2): 5 x 5 control points
    surface = dn.NURBSSurface(
        rng.normal(size=(5, 5, 3)), (3, 2), knots, rng.uniform(0.3, 3.0, (5, 5))
    )
    elevated = surface.elevate_degree(1, direction=direction)
    assert elevated.degree == ((4, 2) if direction == "u" else (3, 3))
    u, v = rng.uniform(3, 5, 200), rng.uniform(2, 5, 200)
    np.testing.assert_allclose(elevated(u, v), naive_surface(surface, u, v), atol=1e-12)


def geomdl_insert_all(degree, knots, points, values):
    """geomdl's A5.1, one knot after another: the oracle for refinement."""
    from geomdl import helpers

    knots, points = list(knots), np.asarray(points).tolist()
    for u in values:
        span = helpers.find_span_linear(degree, knots, len(points), u)
        points = helpers.knot_insertion(degree, knots, points, u, span=span)
        knots = helpers.knot_insertion_kv(knots, u, span, 1)
    return np.asarray(points), np.asarray(knots)


def test_refinement_with_a_thousand_knots_matches_geomdl():
    rng = np.random.default_rng(11)
    curve = random_curve(rng, 3, n_control=12, dim=2, rational=False)
    values = rng.uniform(0.0, 1.0, 1000)
    refined = curve.refine(values)
    assert refined.control_points.shape == (1012, 2)
    u = np.linspace(0, 1, 2001)
    np.testing.assert_allclose(refined(u), curve(u), atol=1e-12)
    points, knots = geomdl_insert_all(3, curve.knots.tolist(), curve.control_points, values[:60])
    partial = curve.refine(values[:60])
    np.testing.assert_allclose(partial.knots, knots, atol=1e-15)
    np.testing.assert_allclose(partial.control_points, points, atol=1e-12)


def test_refinement_is_differentiable_in_the_inserted_values():
    curve = random_curve(np.random.default_rng(12), 3, n_control=8, dim=2, rational=False)

    def polygon_length(values):
        points = curve.refine(values).control_points
        return jnp.sum(jnp.linalg.norm(jnp.diff(points, axis=0), axis=1))

    values = jnp.asarray([0.21, 0.55, 0.8])
    grad = jax.grad(polygon_length)(values)
    step = 1e-6
    for k in range(3):
        shift = jnp.zeros(3).at[k].set(step)
        fd = (polygon_length(values + shift) - polygon_length(values - shift)) / (2 * step)
        np.testing.assert_allclose(grad[k], fd, rtol=1e-6)


def test_refinement_rejects_too_many_copies_and_values_outside():
    curve = random_curve(np.random.default_rng(13), 2, n_control=6, dim=2)
    with pytest.raises(ValueError, match="insert it at most 2 times, not 3"):
        curve.refine([0.5, 0.5, 0.5])
    with pytest.raises(ValueError, match="must lie in the domain"):
        curve.refine([0.5, 1.5])
