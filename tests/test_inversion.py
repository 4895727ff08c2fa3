"""Point inversion against exact geometry, brute-force sampling and optimality conditions."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import nine_point_circle, random_curve, random_surface

import diffnurbs as dn


def brute_force_distance(points_on_geometry, queries):
    """Smallest distance from each query to a dense sample of the geometry."""
    sample = np.asarray(points_on_geometry).reshape(-1, np.shape(queries)[-1])
    return np.array([np.sqrt(np.min(np.sum((sample - q) ** 2, axis=-1))) for q in queries])


# ---------------------------------------------------------------- curves: exact geometry


@pytest.mark.parametrize("curve", [dn.circle(2.0, (1.0, -1.0)), nine_point_circle(2.0, (1, -1))])
def test_circle_nearest_point_is_radial(curve):
    rng = np.random.default_rng(0)
    center = np.array([1.0, -1.0])
    radius = rng.uniform(0.05, 8.0, 400)  # inside and outside the circle
    angle = rng.uniform(-np.pi, np.pi, 400)
    # Queries right at the seam (angle 0, where u = 0 and u = 1 meet) and just either side.
    angle[:6] = [0.0, 1e-9, -1e-9, 1e-4, -1e-4, -0.05]
    queries = center + radius[:, None] * np.stack([np.cos(angle), np.sin(angle)], -1)
    u = curve.closest_point(queries)
    expected = center + 2.0 * np.stack([np.cos(angle), np.sin(angle)], -1)
    np.testing.assert_allclose(curve(u), expected, atol=1e-12)


def test_arc_ends_are_nearest_beyond_the_arc():
    arc = dn.arc(1.0, 0.0, math.pi / 2)  # quarter arc from (1, 0) to (0, 1)
    queries = np.array([[2.0, -1.0], [1.0, -3.0], [-1.0, 2.0], [-3.0, 0.5]])
    u = arc.closest_point(queries)
    np.testing.assert_array_equal(u, [0.0, 0.0, 1.0, 1.0])


def test_straight_cubic_is_orthogonal_projection_clamped_to_its_ends():
    # A straight segment with uneven speed: the parameter is not the arc length.
    start, end = np.array([0.0, 1.0, 2.0]), np.array([4.0, -1.0, 3.0])
    points = start + np.array([0.0, 0.05, 0.6, 1.0])[:, None] * (end - start)
    line = dn.NURBSCurve(points, 3, weights=[1.0, 2.0, 0.5, 1.0])
    rng = np.random.default_rng(1)
    queries = rng.normal(size=(200, 3)) * 4
    along = (queries - start) @ (end - start) / np.sum((end - start) ** 2)
    expected = start + np.clip(along, 0, 1)[:, None] * (end - start)
    np.testing.assert_allclose(line(line.closest_point(queries)), expected, atol=1e-12)


# ------------------------------------------------- curves: brute force and optimality


@pytest.mark.parametrize("degree, rational", [(1, False), (2, True), (3, False), (5, True)])
def test_curve_matches_brute_force_and_is_optimal(degree, rational):
    rng = np.random.default_rng(10 * degree + rational)
    curve = random_curve(rng, degree, n_control=degree + 6, dim=3, rational=rational)
    queries = rng.normal(size=(300, 3)) * 1.5
    queries[:20] = curve(rng.uniform(0, 1, 20))  # points on the curve: distance 0
    u = np.asarray(curve.closest_point(queries))
    ders = np.asarray(curve.derivatives(u, 2))
    residual = ders[:, 0] - queries
    found = np.linalg.norm(residual, axis=-1)
    dense = curve(np.linspace(0.0, 1.0, 200_001))
    brute = brute_force_distance(dense, queries)
    # Never farther than the best of 200,001 samples (nor nearer than the true minimum:
    # `found` is the distance to a point of the curve).
    assert np.all(found <= brute + 1e-12)
    np.testing.assert_allclose(found[:20], 0.0, atol=1e-10)
    slope = np.sum(ders[:, 1] * residual, axis=-1)  # f'(u) = C'(u) . (C(u) - P)
    scale = np.linalg.norm(ders[:, 1], axis=-1) * (found + 1)
    # Knots of multiplicity >= degree are kinks (C0; every vertex of a polyline): there
    # the distance need only grow on both sides.
    interior = np.asarray(curve.knots)[degree + 1 : -degree - 1]
    values, counts = np.unique(interior, return_counts=True)
    kinks = values[counts >= degree]
    at_kink = np.isin(u, kinks)
    for side in (-1e-7, 1e-7):
        beside = np.linalg.norm(curve(np.clip(u[at_kink] + side, 0, 1)) - queries[at_kink], axis=-1)
        assert np.all(beside >= found[at_kink] - 1e-12)
    inside = (u > 0) & (u < 1) & ~at_kink
    np.testing.assert_allclose(slope[inside] / scale[inside], 0.0, atol=1e-9)
    # At an end the distance must grow into the domain.
    assert np.all(slope[u == 0] >= -1e-9 * scale[u == 0])
    assert np.all(slope[u == 1] <= 1e-9 * scale[u == 1])


def test_curve_shapes_and_jit():
    curve = random_curve(np.random.default_rng(2), 3, dim=2)
    assert curve.closest_point(np.zeros(2)).shape == ()
    queries = np.random.default_rng(3).normal(size=(2, 5, 2))
    u = curve.closest_point(queries)
    assert u.shape == (2, 5)
    jitted = jax.jit(lambda c, p: c.closest_point(p))(curve, queries)
    np.testing.assert_allclose(jitted, u, atol=1e-14)
    np.testing.assert_allclose(u[1, 2], curve.closest_point(queries[1, 2]), atol=1e-14)


def test_curve_on_another_domain():
    rng = np.random.default_rng(4)
    curve = random_curve(rng, 3, n_control=8, dim=2, domain=(-2.0, 5.0))
    queries = rng.normal(size=(100, 2))
    u = np.asarray(curve.closest_point(queries))
    assert np.all((u >= -2.0) & (u <= 5.0))
    brute = brute_force_distance(curve(np.linspace(-2.0, 5.0, 100_001)), queries)
    assert np.all(np.linalg.norm(curve(u) - queries, axis=-1) <= brute + 1e-12)


def test_float32_curve():
    exact = dn.circle(1.5, (0.5, 0.0))
    curve = dn.NURBSCurve(
        np.asarray(exact.control_points, np.float32),
        2,
        np.asarray(exact.knots, np.float32),
        np.asarray(exact.weights, np.float32),
    )
    rng = np.random.default_rng(5)
    angle = rng.uniform(-np.pi, np.pi, 50)
    queries = (np.array([0.5, 0.0]) + 3 * np.stack([np.cos(angle), np.sin(angle)], -1)).astype(
        np.float32
    )
    u = curve.closest_point(queries)
    assert u.dtype == jnp.float32
    expected = np.array([0.5, 0.0]) + 1.5 * np.stack([np.cos(angle), np.sin(angle)], -1)
    np.testing.assert_allclose(curve(u), expected, atol=2e-5)


# ------------------------------------------------------------------- curves: gradients


def test_gradient_matches_implicit_function_theorem():
    rng = np.random.default_rng(6)
    curve = random_curve(rng, 3, n_control=7, dim=3)
    queries = rng.normal(size=(30, 3))
    u = np.asarray(curve.closest_point(queries))
    inside = (u > 1e-6) & (u < 1 - 1e-6)
    grads = np.asarray(jax.vmap(jax.grad(curve.closest_point))(jnp.asarray(queries)))
    # g(u, P) = C'(u).(C(u) - P) = 0, so du/dP = -g_P / g_u = C'(u) / f''(u).
    ders = np.asarray(curve.derivatives(u, 2))
    second = np.sum(ders[:, 1] ** 2, -1) + np.sum(ders[:, 2] * (ders[:, 0] - queries), -1)
    expected = ders[:, 1] / second[:, None]
    np.testing.assert_allclose(grads[inside], expected[inside], rtol=1e-7, atol=1e-10)
    np.testing.assert_array_equal(grads[~inside], 0.0)  # held at an end: no gradient
    assert inside.sum() > 10


def test_gradient_wrt_curve_matches_finite_differences():
    rng = np.random.default_rng(7)
    curve = random_curve(rng, 3, n_control=6, dim=2)
    query = jnp.asarray([0.3, -0.2])

    def parameter(control_points, weights):
        return dn.NURBSCurve(control_points, 3, curve.knots, weights).closest_point(query)

    assert 0 < parameter(curve.control_points, curve.weights) < 1
    grads = jax.grad(parameter, argnums=(0, 1))(curve.control_points, curve.weights)
    step = 1e-6
    for array, grad, argnum in zip(
        (curve.control_points, curve.weights), grads, (0, 1), strict=True
    ):
        flat = np.asarray(array).ravel()
        numeric = []
        for i in range(flat.size):
            shifted = [np.asarray(curve.control_points), np.asarray(curve.weights)]
            plus, minus = flat.copy(), flat.copy()
            plus[i] += step
            minus[i] -= step
            shifted[argnum] = plus.reshape(array.shape)
            high = parameter(*shifted)
            shifted[argnum] = minus.reshape(array.shape)
            low = parameter(*shifted)
            numeric.append((high - low) / (2 * step))
        np.testing.assert_allclose(np.ravel(grad), numeric, rtol=1e-5, atol=1e-8)


def test_gradient_finite_at_degenerate_query():
    # Every point of the circle is nearest to its centre: f'' = 0 there.
    circle = dn.circle(1.0)
    grad = jax.grad(circle.closest_point)(jnp.zeros(2))
    assert np.all(np.isfinite(grad))


# ------------------------------------------------------------------------------- surfaces


def sphere(radius, center):
    """An exact sphere: a half circle in the xz-plane revolved about the z axis."""
    profile = dn.arc(radius, -math.pi / 2, math.pi / 2, center=(0.0, 0.0, 0.0))
    # arc() draws in the xy-plane; turn y into z to put the half circle in the xz-plane.
    points = profile.control_points[:, jnp.array([0, 2, 1])] + jnp.asarray(center)
    profile = dn.NURBSCurve(points, 2, profile.knots, profile.weights)
    return dn.revolve(profile, center, (0.0, 0.0, 1.0))


def test_sphere_nearest_point_is_radial():
    center = np.array([0.5, -1.0, 2.0])
    surface = sphere(1.5, center)
    rng = np.random.default_rng(8)
    directions = rng.normal(size=(300, 3))
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    # Near the seam of the revolution (azimuth 0) on both sides, and near the poles.
    directions[:4] = [[1, 1e-9, 0.1], [1, -1e-9, 0.1], [1, -1e-3, -0.3], [1e-3, 0, 1]]
    directions[:4] /= np.linalg.norm(directions[:4], axis=-1, keepdims=True)
    distance = rng.uniform(0.2, 5.0, (300, 1))
    queries = center + distance * directions
    u, v = surface.closest_point(queries)
    assert u.shape == v.shape == (300,)
    np.testing.assert_allclose(surface(u, v), center + 1.5 * directions, atol=1e-11)


def test_plane_projection_clamped_to_edges_and_corners():
    # A 2 x 3 rectangle in a tilted plane, extruded from a straight cubic with uneven speed.
    origin, side, across = np.array([1.0, 0, 0]), np.array([2.0, 0, 0]), np.array([0, 3.0, 1])
    across_unit = across / np.linalg.norm(across)
    line = dn.NURBSCurve(origin + np.array([0, 0.2, 0.3, 1])[:, None] * side, 3)
    plane = dn.extrude(line, across, np.linalg.norm(across))
    rng = np.random.default_rng(9)
    queries = origin + rng.uniform(-1, 2, (300, 1)) * side + rng.uniform(-1, 2, (300, 1)) * across
    queries += rng.normal(size=(300, 1)) * np.cross(side, across_unit)  # off the plane
    u, v = plane.closest_point(queries)
    s = np.clip((queries - origin) @ side / (side @ side), 0, 1)
    t = np.clip((queries - origin) @ across / (across @ across), 0, 1)
    expected = origin + s[:, None] * side + t[:, None] * across
    np.testing.assert_allclose(plane(u, v), expected, atol=1e-12)
    assert np.any((s == 0) & (t == 0)) and np.any((s == 1) & (t == 1))  # corners were hit


def test_cylinder_beyond_its_ends():
    cylinder = dn.extrude(dn.circle(1.0, (0.0, 0.0, 0.0)), (0.0, 0.0, 1.0), 2.0)
    queries = np.array([[3.0, 0.0, -1.0], [0.0, -2.0, 5.0], [0.3, 0.4, 1.0]])
    u, v = cylinder.closest_point(queries)
    expected = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 2.0], [0.6, 0.8, 1.0]])
    np.testing.assert_allclose(cylinder(u, v), expected, atol=1e-12)


@pytest.mark.parametrize("rational", [False, True])
def test_surface_matches_brute_force_and_is_optimal(rational):
    rng = np.random.default_rng(20 + rational)
    surface = random_surface(rng, (3, 2), counts=(6, 5), rational=rational)
    # Smooth optima only: a knot line of multiplicity = degree is a crease (C0), where the
    # distance has a kink and need not be stationary (curves test kinks separately).
    for knots, degree in zip(surface.knots, surface.degree, strict=True):
        interior = np.asarray(knots)[degree + 1 : -degree - 1]
        assert np.max(np.unique(interior, return_counts=True)[1], initial=0) < degree
    queries = rng.normal(size=(150, 3)) * 1.5
    # A random net folds sharply within a span: the start's grid must resolve the folds.
    u, v = (np.asarray(x) for x in surface.closest_point(queries, samples_per_span=32))
    ders = np.asarray(surface.derivatives(u, v, 1))
    residual = ders[:, 0, 0] - queries
    found = np.linalg.norm(residual, axis=-1)
    grid = np.linspace(0.0, 1.0, 701)
    brute = brute_force_distance(surface.grid(grid, grid), queries)
    assert np.all(found <= brute + 1e-12)
    for k, x in ((1, u), (0, v)):
        tangent = ders[:, k, 1 - k]
        slope = np.sum(tangent * residual, -1)
        scale = np.linalg.norm(tangent, axis=-1) * (found + 1)
        inside = (x > 0) & (x < 1)
        np.testing.assert_allclose(slope[inside] / scale[inside], 0.0, atol=1e-9)
        assert np.all(slope[x == 0] >= -1e-9 * scale[x == 0])
        assert np.all(slope[x == 1] <= 1e-9 * scale[x == 1])


def test_height_field_matches_brute_force_with_default_sampling():
    rng = np.random.default_rng(15)
    count = 7
    grid = np.stack(np.meshgrid(np.arange(count), np.arange(count), indexing="ij"), -1) / 2
    net = np.concatenate([grid, 0.4 * rng.normal(size=(count, count, 1))], -1)
    surface = dn.NURBSSurface(net, (3, 2), weights=rng.uniform(0.5, 2.0, (count, count)))
    queries = net.reshape(-1, 3)[rng.integers(0, count * count, 200)]
    queries = queries + 0.5 * rng.normal(size=queries.shape)
    u, v = surface.closest_point(queries)
    found = np.linalg.norm(np.asarray(surface(u, v)) - queries, axis=-1)
    samples = np.linspace(0.0, 1.0, 701)
    assert np.all(found <= brute_force_distance(surface.grid(samples, samples), queries) + 1e-12)


def test_surface_gradient_matches_finite_differences():
    rng = np.random.default_rng(12)
    surface = random_surface(rng, (2, 3), counts=(4, 5))
    normal = surface.normal(0.4, 0.7)
    query = surface(0.4, 0.7) + 0.05 * normal + jnp.asarray([0.01, -0.02, 0.0])

    def parameters(point):
        return jnp.stack(surface.closest_point(point))

    uv = parameters(query)
    assert np.all((uv > 0) & (uv < 1))
    jacobian = jax.jacrev(parameters)(query)
    step = 1e-6
    numeric = np.stack(
        [
            (parameters(query + step * e) - parameters(query - step * e)) / (2 * step)
            for e in np.eye(3)
        ],
        axis=-1,
    )
    np.testing.assert_allclose(jacobian, numeric, rtol=1e-5, atol=1e-8)


def test_surface_batch_shape():
    surface = random_surface(np.random.default_rng(13), (2, 2))
    u, v = surface.closest_point(np.zeros((4, 3, 3)))
    assert u.shape == v.shape == (4, 3)


# ----------------------------------------------------------------------------- bad input


def test_bad_input():
    curve = dn.circle(1.0)
    surface = random_surface(np.random.default_rng(14), (2, 2))
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2\)"):
        curve.closest_point(np.zeros(3))
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2\)"):
        curve.closest_point(1.0)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        surface.closest_point(np.zeros((5, 2)))
    with pytest.raises(ValueError, match="point must be finite"):
        curve.closest_point(np.array([[0.0, 1.0], [np.nan, 0.0]]))
    with pytest.raises(ValueError, match="point must be finite"):
        surface.closest_point(np.array([0.0, np.inf, 0.0]))
    with pytest.raises(ValueError, match="samples_per_span must be >= 1"):
        curve.closest_point(np.zeros(2), samples_per_span=0)
