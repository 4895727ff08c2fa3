"""Agreement with independent libraries: scipy (homogeneous BSpline, NdBSpline) and geomdl."""

import numpy as np
import pytest
from geomdl import NURBS
from helpers import random_curve, random_surface, sample_parameters
from scipy.interpolate import BSpline, NdBSpline

import diffnurbs as dn


def scipy_rational_curve(curve, u, order):
    """Points and derivatives of a NURBS curve from scipy's BSpline of the homogeneous curve."""
    homogeneous = np.asarray(curve.homogeneous_points())
    spline = BSpline(np.asarray(curve.knots), homogeneous, curve.degree)
    a_ders = np.stack([spline(u, nu=k) for k in range(order + 1)], -2)
    return np.asarray(dn.rational_curve_derivatives(a_ders[..., :-1], a_ders[..., -1]))


@pytest.mark.parametrize("degree", [1, 2, 3, 4, 5])
def test_curve_derivatives_match_scipy(degree):
    rng = np.random.default_rng(400 + degree)
    curve = random_curve(rng, degree, dim=3)
    u = sample_parameters(rng, curve.knots, degree)
    expected = scipy_rational_curve(curve, u, degree)
    scale = np.abs(expected).max(axis=(0, 2), keepdims=True)
    np.testing.assert_allclose(curve.derivatives(u, degree), expected, atol=1e-11 * scale.max())


@pytest.mark.parametrize("degrees", [(1, 2), (3, 3), (2, 4)])
def test_surface_matches_scipy_ndbspline(degrees):
    rng = np.random.default_rng(500 + sum(degrees))
    surface = random_surface(rng, degrees)
    spline = NdBSpline(
        tuple(np.asarray(k) for k in surface.knots),
        np.asarray(surface.homogeneous_points()),
        degrees,
    )
    uv = rng.uniform(size=(200, 2))
    homogeneous = spline(uv)
    expected = homogeneous[:, :-1] / homogeneous[:, -1:]
    np.testing.assert_allclose(surface(uv[:, 0], uv[:, 1]), expected, atol=1e-12)
    derivative = spline(uv, nu=(1, 1))
    mixed = np.asarray(surface.derivatives(uv[:, 0], uv[:, 1], 1))
    # Check the homogeneous identity A_uv = (w S)_uv with the library's own S-derivatives.
    w = homogeneous[:, -1:]
    w_u, w_v, w_uv = (spline(uv, nu=n)[:, -1:] for n in [(1, 0), (0, 1), (1, 1)])
    a_uv = w_uv * mixed[:, 0, 0] + w_u * mixed[:, 0, 1] + w_v * mixed[:, 1, 0] + w * mixed[:, 1, 1]
    np.testing.assert_allclose(a_uv, derivative[:, :-1], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("degree", [2, 3])
def test_curve_matches_geomdl(degree):
    rng = np.random.default_rng(600 + degree)
    curve = random_curve(rng, degree, n_control=8, dim=3)
    reference = NURBS.Curve()
    reference.degree = degree
    reference.ctrlpts = np.asarray(curve.control_points).tolist()
    reference.weights = np.asarray(curve.weights).tolist()
    reference.knotvector = np.asarray(curve.knots).tolist()
    u = np.linspace(0, 1, 57)
    expected = np.array(reference.evaluate_list(u.tolist()))
    np.testing.assert_allclose(curve(u), expected, atol=1e-12)


def test_surface_matches_geomdl():
    rng = np.random.default_rng(700)
    surface = random_surface(rng, (2, 3), counts=(5, 6))
    reference = NURBS.Surface()
    reference.degree_u, reference.degree_v = surface.degree
    reference.ctrlpts_size_u, reference.ctrlpts_size_v = 5, 6
    reference.ctrlpts = np.asarray(surface.control_points).reshape(-1, 3).tolist()
    reference.weights = np.asarray(surface.weights).ravel().tolist()
    reference.knotvector_u, reference.knotvector_v = (np.asarray(k).tolist() for k in surface.knots)
    uv = rng.uniform(size=(60, 2))
    expected = np.array(reference.evaluate_list(uv.tolist()))
    np.testing.assert_allclose(surface(uv[:, 0], uv[:, 1]), expected, atol=1e-12)
