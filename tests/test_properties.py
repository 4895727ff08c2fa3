"""Properties of B-splines and NURBS, on curves drawn by hypothesis."""

import jax.numpy as jnp
import numpy as np
from helpers import random_curve, random_knots
from hypothesis import given, settings, strategies as st
from scipy.spatial import ConvexHull

import diffnurbs as dn

SETTINGS = settings(max_examples=25, deadline=None)
seeds = st.integers(0, 2**32 - 1)
degrees = st.integers(1, 5)


@SETTINGS
@given(seeds, degrees)
def test_partition_of_unity_and_non_negativity(seed, degree):
    rng = np.random.default_rng(seed)
    knots = random_knots(rng, degree + int(rng.integers(1, 8)), degree)
    u = np.concatenate([rng.uniform(size=50), knots])
    _, funs = dn.basis_funs(knots, degree, u)
    np.testing.assert_allclose(funs.sum(-1), 1.0, atol=1e-13)
    assert np.all(np.asarray(funs) >= 0)


@SETTINGS
@given(seeds, degrees, st.data())
def test_local_support_of_a_control_point(seed, degree, data):
    rng = np.random.default_rng(seed)
    curve = random_curve(rng, degree, dim=2)
    i = data.draw(st.integers(0, curve.control_points.shape[0] - 1))
    moved = dn.NURBSCurve(curve.control_points.at[i].add(1.0), degree, curve.knots, curve.weights)
    knots = np.asarray(curve.knots)
    u = rng.uniform(size=200)
    outside = (u < knots[i]) | (u >= knots[i + degree + 1])
    np.testing.assert_allclose(moved(u)[outside], curve(u)[outside], atol=1e-13)


@SETTINGS
@given(seeds, degrees)
def test_affine_invariance(seed, degree):
    rng = np.random.default_rng(seed)
    curve = random_curve(rng, degree, dim=3)
    matrix, shift = rng.normal(size=(3, 3)), rng.normal(size=3)
    mapped = dn.NURBSCurve(
        curve.control_points @ matrix.T + shift, degree, curve.knots, curve.weights
    )
    u = rng.uniform(size=30)
    np.testing.assert_allclose(mapped(u), curve(u) @ matrix.T + shift, atol=1e-11)


@SETTINGS
@given(seeds, st.integers(2, 5))
def test_strong_convex_hull(seed, degree):
    # Each point lies in the hull of the p + 1 control points acting on its span.
    rng = np.random.default_rng(seed)
    curve = random_curve(rng, degree, dim=2)
    u = rng.uniform(size=40)
    span = np.asarray(dn.find_span(curve.knots, degree, u))
    points, net = np.asarray(curve(u)), np.asarray(curve.control_points)
    for x, s in zip(points, span, strict=True):
        hull = ConvexHull(net[s - degree : s + 1])
        assert np.all(hull.equations[:, :2] @ x + hull.equations[:, 2] <= 1e-12)


def reversed_curve(curve):
    """The same curve run backwards: C_rev(s) = C(a + b - s)."""
    knots = np.asarray(curve.knots)
    flipped = (knots[0] + knots[-1] - knots)[::-1]
    weights = None if curve.weights is None else curve.weights[::-1]
    return dn.NURBSCurve(curve.control_points[::-1], curve.degree, flipped, weights)


@SETTINGS
@given(seeds, degrees)
def test_continuity_across_knots(seed, degree):
    """At a knot of multiplicity m the curve is C^(p - m): left and right limits agree."""
    rng = np.random.default_rng(seed)
    curve = random_curve(rng, degree, n_control=degree + 5, dim=2)
    backwards = reversed_curve(curve)
    knots = np.asarray(curve.knots)
    interior, counts = np.unique(knots[degree + 1 : -degree - 1], return_counts=True)
    for knot, multiplicity in zip(interior, counts, strict=True):
        smoothness = degree - multiplicity
        right = np.asarray(curve.derivatives(knot, degree))
        # The reversed curve's right limit at the mirrored knot is the original's left limit.
        left = np.array(backwards.derivatives(knots[0] + knots[-1] - knot, degree))
        left *= ((-1.0) ** np.arange(degree + 1))[:, None]
        scale = max(1.0, np.abs(right[: smoothness + 1]).max())
        np.testing.assert_allclose(
            left[: smoothness + 1], right[: smoothness + 1], atol=1e-8 * scale
        )


@SETTINGS
@given(seeds)
def test_scaling_all_weights_changes_nothing(seed):
    rng = np.random.default_rng(seed)
    curve = random_curve(rng, 3, dim=2)
    scaled = dn.NURBSCurve(curve.control_points, 3, curve.knots, curve.weights * 7.5)
    u = jnp.asarray(rng.uniform(size=20))
    np.testing.assert_allclose(scaled.derivatives(u, 3), curve.derivatives(u, 3), atol=1e-10)
