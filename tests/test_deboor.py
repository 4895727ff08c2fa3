"""de Boor's construction against de Casteljau's triangle and against knot insertion."""

import jax
import numpy as np
import pytest
from helpers import random_curve

import diffnurbs as dn


def casteljau_triangle(points, t):
    """Every level of de Casteljau's algorithm, by repeated linear interpolation."""
    levels = [np.asarray(points, float)]
    while len(levels[-1]) > 1:
        level = levels[-1]
        levels.append((1 - t) * level[:-1] + t * level[1:])
    return levels


@pytest.mark.parametrize("degree", [1, 2, 3, 5])
def test_bezier_levels_are_de_casteljaus(degree):
    rng = np.random.default_rng(degree)
    points = rng.normal(size=(degree + 1, 2))
    levels = dn.de_boor_levels(dn.NURBSCurve(points, degree), 0.37)
    expected = casteljau_triangle(points, 0.37)
    assert [level.shape for level in levels] == [level.shape for level in expected]
    for level, oracle in zip(levels, expected, strict=True):
        np.testing.assert_allclose(level, oracle, atol=1e-14)


@pytest.mark.parametrize("rational", [False, True])
@pytest.mark.parametrize("degree", [2, 3, 4])
def test_edges_of_the_triangle_are_the_points_of_knot_insertion(degree, rational):
    # Inserting a new knot u p times (Boehm) leaves, around its span k, the control points
    # P_{k-p}, the first point of every level down to C(u), then the last point of every
    # level back up to P_k.
    rng = np.random.default_rng(10 * degree + rational)
    curve = random_curve(rng, degree, rational=rational)
    breaks = np.unique(np.asarray(curve.knots)[degree:-degree])
    middle = len(breaks) // 2  # the midpoint of a non-empty span is not a knot
    u = 0.5 * (breaks[middle - 1] + breaks[middle])
    levels = dn.de_boor_levels(curve, u)
    span = int(dn.find_span(curve.knots, degree, u))
    inserted = np.asarray(curve.insert_knot(u, times=degree).control_points)
    edges = [level[0] for level in levels] + [level[-1] for level in levels[-2::-1]]
    np.testing.assert_allclose(
        np.stack(edges), inserted[span - degree : span + degree + 1], atol=1e-12
    )
    np.testing.assert_allclose(levels[-1][0], curve(u), atol=1e-13)


def test_levels_at_the_ends_and_under_jit():
    curve = random_curve(np.random.default_rng(3), 3, rational=True)
    lower, upper = (float(x) for x in curve.domain)
    for u in (lower, upper):
        np.testing.assert_allclose(dn.de_boor_levels(curve, u)[-1][0], curve(u), atol=1e-13)
    compiled = jax.jit(lambda c, u: dn.de_boor_levels(c, u)[-1][0])
    np.testing.assert_allclose(
        compiled(curve, 0.4 * lower + 0.6 * upper), curve(0.4 * lower + 0.6 * upper), atol=1e-13
    )


def test_bad_parameters():
    curve = dn.NURBSCurve(np.eye(4, 2), 3)
    with pytest.raises(ValueError, match="one parameter u, got shape"):
        dn.de_boor_levels(curve, [0.1, 0.2])
    with pytest.raises(ValueError, match=r"u must lie in the domain \[0.0, 1.0\]"):
        dn.de_boor_levels(curve, 1.5)
