import math

import jax
import numpy as np
import pytest
import scipy.special

import diffnurbs as dn

U = np.linspace(0, 1, 2001)


@pytest.mark.parametrize(
    ("start", "end", "segments"),
    [
        (0.0, math.pi / 6, 1),
        (0.3, 0.3 + math.pi / 2, 1),
        (1.0, 1.0 + 3 * math.pi / 2, 3),
        (0.0, 2 * math.pi, 4),
        (2.0, -1.5, 3),
    ],
)
def test_arcs_are_exact(start, end, segments):
    center = np.array([1.5, -0.5])
    curve = dn.arc(2.0, start, end, center)
    assert curve.control_points.shape[0] == 2 * segments + 1
    points = np.asarray(curve(U)) - center
    np.testing.assert_allclose(np.linalg.norm(points, axis=-1), 2.0, atol=1e-14)
    angles = np.unwrap(np.arctan2(points[:, 1], points[:, 0]))
    np.testing.assert_allclose([angles[0], angles[-1]], [start, end], atol=1e-13)
    assert np.all(np.diff(angles) * np.sign(end - start) > 0)  # monotone: no back-tracking
    np.testing.assert_allclose(curve.curvature(U), np.sign(end - start) / 2.0, rtol=1e-12)
    np.testing.assert_allclose(curve.arc_length(), 2.0 * abs(end - start), rtol=1e-12)


def test_circle_in_3d_and_ellipse():
    ring = dn.circle(3.0, center=(1.0, 2.0, 5.0))
    points = np.asarray(ring(U))
    np.testing.assert_allclose(points[:, 2], 5.0)
    np.testing.assert_allclose(np.linalg.norm(points[:, :2] - [1, 2], axis=-1), 3.0, atol=1e-14)
    oval = dn.ellipse(3.0, 1.0, center=(0.5, 0.0))
    x, y = np.asarray(oval(U)).T
    np.testing.assert_allclose(((x - 0.5) / 3.0) ** 2 + y**2, 1.0, atol=1e-14)
    # Perimeter 4 a E(e^2), E the complete elliptic integral of the second kind.
    perimeter = 4 * 3.0 * scipy.special.ellipe(1 - (1.0 / 3.0) ** 2)
    np.testing.assert_allclose(oval.arc_length(), perimeter, rtol=1e-10)


def test_traced_radius_and_angles():
    length = jax.jit(lambda r, a: dn.arc(r, 0.0, a).arc_length())
    np.testing.assert_allclose(length(2.0, 1.0), 2.0, rtol=1e-12)
    np.testing.assert_allclose(jax.grad(length, argnums=(0, 1))(2.0, 1.0), (1.0, 2.0), rtol=1e-10)


def test_bad_shapes():
    with pytest.raises(ValueError, match="radius must be finite and positive"):
        dn.circle(-1.0)
    with pytest.raises(ValueError, match="sweep angle"):
        dn.arc(1.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="sweep angle"):
        dn.arc(1.0, 0.0, 7.0)
    with pytest.raises(ValueError, match="dimension >= 2"):
        dn.circle(1.0, center=(0.0,))
    with pytest.raises(ValueError, match="semi_axis_b"):
        dn.ellipse(1.0, 0.0)
