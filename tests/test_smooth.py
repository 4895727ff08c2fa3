"""Smoothing splines (`smooth`) against scipy's `make_smoothing_spline`, dense linear
algebra, exact limits (interpolation, least squares, polynomials) and finite differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import central_difference
from scipy.interpolate import make_interp_spline, make_smoothing_spline

import diffnurbs as dn
from diffnurbs._smooth import _inverse_band


def noisy_function(rng, m=60, noise=0.1):
    x = np.sort(rng.uniform(0.0, 3.0, m))
    return x, np.sin(2 * x) + noise * rng.standard_normal(m)


def noisy_circle(rng, m=80, noise=0.02):
    t = np.sort(rng.uniform(0.0, 2 * np.pi, m))
    circle = np.stack([np.cos(t), np.sin(t)], axis=-1)
    return circle + noise * rng.standard_normal((m, 2))


def dense_hat(curve, u, weights, lam, closed=False):
    """`N (N^T W N + lam R)^-1 N^T W` built densely: `N` from `basis_matrix`, `R` by
    numerical integration of the derivatives on a fine Gauss grid, independently of the
    banded code (a closed curve's basis folded by hand)."""
    knots, p = np.asarray(curve.knots), curve.degree
    n = knots.size - p - 1
    basis = np.asarray(dn.basis_matrix(knots, p, u))
    nodes, node_weights = np.polynomial.legendre.leggauss(8)
    lo, hi = knots[p:n], knots[p + 1 : n + 1]
    at = ((lo + hi)[:, None] + (hi - lo)[:, None] * nodes).ravel() / 2
    scale = ((hi - lo)[:, None] / 2 * node_weights).ravel()
    eye = np.eye(n)
    second = np.stack(
        [
            np.asarray(dn.NURBSCurve(eye[i][:, None], p, knots).derivatives(at, 2))[:, 2, 0]
            for i in range(n)
        ]
    )
    penalty = (second * scale) @ second.T
    if closed:  # the last p control points are the first p
        fold = np.zeros((n, n - p))
        fold[np.arange(n), np.arange(n) % (n - p)] = 1
        basis, penalty = basis @ fold, fold.T @ penalty @ fold
    gram = basis.T @ (weights[:, None] * basis)
    return basis @ np.linalg.solve(gram + lam * penalty, basis.T * weights)


@pytest.mark.parametrize("lam", [1e-5, 1e-3, 1e-1, 10.0])
def test_same_as_scipy_make_smoothing_spline(lam):
    rng = np.random.default_rng(1)
    x, y = noisy_function(rng)
    w = rng.uniform(0.5, 2.0, x.size)
    at = np.linspace(x[0], x[-1], 1001)
    for weights in (None, w):
        curve = dn.smooth(y, x=x, penalty=lam, weights=weights)
        expected = make_smoothing_spline(x, y, w=weights, lam=lam)(at)
        assert curve.control_points.shape == (x.size + 2, 1)
        assert np.max(np.abs(np.asarray(curve(at))[:, 0] - expected)) < 1e-9 * np.abs(y).max()


def test_gcv_same_as_scipy():
    rng = np.random.default_rng(2)
    x, y = noisy_function(rng, m=80)
    curve, report = dn.smooth(y, x=x, full_output=True)
    at = np.linspace(x[0], x[-1], 1001)
    # Both minimise the same GCV score (scipy on lam, Brent, to its default tolerance).
    assert np.max(np.abs(np.asarray(curve(at))[:, 0] - make_smoothing_spline(x, y)(at))) < 1e-4
    hat = dense_hat(curve, x, np.ones(x.size), float(report.penalty))
    residual = np.sum((hat @ y - y) ** 2)
    assert float(report.residual) == pytest.approx(residual, rel=1e-10)
    assert float(report.dof) == pytest.approx(np.trace(hat), rel=1e-10)
    gcv = x.size * residual / (x.size - np.trace(hat)) ** 2
    assert float(report.gcv) == pytest.approx(gcv, rel=1e-10)
    for factor in (0.9, 1.1):  # a minimum of the dense score
        hat = dense_hat(curve, x, np.ones(x.size), factor * float(report.penalty))
        assert x.size * np.sum((hat @ y - y) ** 2) / (x.size - np.trace(hat)) ** 2 > gcv


def test_gcv_with_n_control_is_the_lowest_on_a_dense_grid():
    rng = np.random.default_rng(17)
    x, y = noisy_function(rng, m=80)
    curve, report = dn.smooth(y, 20, x=x, full_output=True)

    def gcv(lam):
        hat = dense_hat(curve, x, np.ones(x.size), lam)
        return x.size * np.sum((hat @ y - y) ** 2) / (x.size - np.trace(hat)) ** 2

    assert float(report.gcv) == pytest.approx(gcv(float(report.penalty)), rel=1e-10)
    # The global minimum: no lam of a fine grid over 16 decades scores lower.
    grid = np.geomspace(1e-10, 1e6, 65)
    assert float(report.gcv) <= min(gcv(lam) for lam in grid) * (1 + 1e-9)
    assert gcv(0.9 * float(report.penalty)) > report.gcv < gcv(1.1 * float(report.penalty))


@pytest.mark.parametrize("closed", [False, True])
@pytest.mark.parametrize("n_control", [None, 15])
def test_dof_is_trace_of_dense_hat_matrix(closed, n_control):
    rng = np.random.default_rng(3)
    points = noisy_circle(rng, m=40) if closed else noisy_function(rng, 40)[1][:, None]
    x = np.sort(rng.uniform(0.0, 1.0, 41 if closed else 40))
    w = rng.uniform(0.0, 2.0, 40)
    curve, report = dn.smooth(
        points, n_control, x=x, weights=w, penalty=3e-3, closed=closed, full_output=True
    )
    hat = dense_hat(curve, x[:40], w, 3e-3, closed)
    assert float(report.dof) == pytest.approx(np.trace(hat), rel=1e-10)
    fitted = np.asarray(curve(x[:40]))
    assert np.allclose(fitted, hat @ points, atol=1e-10)


def test_inverse_band_is_band_of_dense_inverse():
    rng = np.random.default_rng(4)
    n, h = 30, 3
    a = rng.standard_normal((n, n)) * (np.abs(np.subtract.outer(range(n), range(n))) <= h)
    matrix = a @ a.T + n * np.eye(n)  # half-bandwidth 2h
    band = np.zeros((n, 4 * h + 1))
    for i in range(n):
        for j in range(4 * h + 1):
            if 0 <= i - 2 * h + j < n:
                band[i, j] = matrix[i, i - 2 * h + j]
    inverse = np.linalg.inv(matrix)
    sigma = np.asarray(_inverse_band(jnp.asarray(band)))
    for d in range(2 * h + 1):
        assert np.allclose(sigma[: n - d, d], np.diagonal(inverse, d), rtol=1e-12, atol=1e-14)


def test_penalty_zero_is_the_natural_interpolant():
    rng = np.random.default_rng(5)
    x, y = noisy_function(rng, m=50)
    curve = dn.smooth(y, x=x, penalty=0.0)
    natural = make_interp_spline(x, y, k=3, bc_type="natural")
    assert np.allclose(np.asarray(curve.control_points)[:, 0], natural.c, rtol=0, atol=1e-10)
    # Any degree: it interpolates, and other interpolants with the same knots cost more.
    for degree, order in ((2, 1), (5, 3)):
        curve = dn.smooth(y, degree=degree, penalty_order=order, x=x, penalty=0.0)
        assert np.allclose(np.asarray(curve(x))[:, 0], y, atol=1e-9)
    assert dn.smooth(y, degree=1, penalty_order=1, x=x, penalty=0.0)(x)[:, 0] == pytest.approx(y)


def test_penalty_zero_is_least_squares_and_periodic_interpolation():
    rng = np.random.default_rng(6)
    x, y = noisy_function(rng, m=50)
    smooth = dn.smooth(y, 12, x=x, penalty=0.0)
    lsq = dn.approximate(y[:, None], 12, 3, x, interpolate_ends=False)
    assert np.allclose(smooth.knots, lsq.knots, rtol=0, atol=0)
    assert np.allclose(smooth.control_points, lsq.control_points, atol=1e-11)
    points = noisy_circle(rng)
    closed = dn.smooth(points, closed=True, penalty=0.0)
    expected = dn.interpolate(points, 3, closed=True)
    assert np.allclose(closed.knots, expected.knots, rtol=0, atol=1e-15)
    assert np.allclose(closed.control_points, expected.control_points, atol=1e-10)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_large_penalty_tends_to_the_least_squares_polynomial(order):
    rng = np.random.default_rng(7)
    x, y = noisy_function(rng, m=40)
    w = rng.uniform(0.5, 2.0, x.size)
    expected = np.polyval(np.polyfit(x, y, order - 1, w=np.sqrt(w)), x)
    # The distance to the limit falls as 1 / lam all the way to lam = 1e12, also with knots
    # at every point (min spacing 0.002, |R| ~ 1e8 for r = 2): the normal equations lost
    # the polynomial part once eps lam |R| neared |N^T W N| (lam ~ 1e5 for r = 2, 1e3 for
    # r = 3; scipy's make_smoothing_spline alike).
    lams = (1e3, 1e6, 1e9, 1e12)
    for n_control in (None, 10):
        errors = [
            np.abs(
                dn.smooth(y, n_control, x=x, weights=w, penalty_order=order, penalty=lam)(x)[:, 0]
                - expected
            ).max()
            for lam in lams
        ]
        # 1000 times closer for every factor 1000 of lam
        assert np.all(np.abs(np.diff(np.log10(errors)) + 3) < 0.3), errors
    for n_control in (None, 10):
        # a target residual at or above the polynomial's gives the polynomial exactly
        curve, report = dn.smooth(
            y, n_control, x=x, weights=w, penalty_order=order, smoothing=1e6, full_output=True
        )
        assert np.allclose(np.asarray(curve(x))[:, 0], expected, atol=1e-12)
        assert float(report.penalty) == np.inf and float(report.dof) == order
        assert float(report.residual) == pytest.approx(np.sum(w * (expected - y) ** 2))
    closed = dn.smooth(y[:, None] * [1.0, -1.0], closed=True, weights=w, smoothing=1e6)
    assert np.allclose(closed.control_points, np.average(y, weights=w) * np.array([1.0, -1.0]))


def test_large_penalty_periodic_tends_to_the_weighted_mean():
    rng = np.random.default_rng(15)
    points = noisy_circle(rng, m=50)
    w = rng.uniform(0.5, 2.0, 50)
    mean = np.average(points, axis=0, weights=w)
    for n_control in (None, 12):
        errors = [
            np.abs(
                dn.smooth(points, n_control, weights=w, penalty=lam, closed=True).control_points
                - mean
            ).max()
            for lam in (1e3, 1e6, 1e9, 1e12)
        ]
        # 1000 times closer for every factor 1000 of lam
        assert np.all(np.abs(np.diff(np.log10(errors)) + 3) < 0.3), errors


@pytest.mark.parametrize("order, m", [(2, 10_000), (3, 1000)])
def test_polynomial_data_are_kept_at_any_penalty(order, m):
    # A polynomial of degree < r costs no penalty, so it is its own smoothing spline for
    # every lam: an exact oracle where lam |R| reaches 1e20 (|R| ~ spacing^(1 - 2r)). For
    # r = 2, m = 10^4 the normal equations were off by 2e-6 at lam = 1 and 6e-3 at lam = 1e4
    # (scipy's make_smoothing_spline by 3e-5 and 0.9). Rounding still grows with the
    # conditioning of R, ~ m^(2r): for r = 3 at m = 10^4 it reaches 1e-8 at lam ~ 1e-4,
    # hence m = 1000 there.
    rng = np.random.default_rng(16)
    x = np.linspace(0.0, 1.0, m) + rng.uniform(-0.3, 0.3, m) / m
    coefficients = [0.8, -0.7, 0.3][3 - order :]
    at = np.linspace(x[0], x[-1], 501)
    for lam in (1e-4, 1.0, 1e4, 1e8):
        curve, report = dn.smooth(
            np.polyval(coefficients, x), x=x, penalty=lam, penalty_order=order, full_output=True
        )
        assert np.allclose(curve(at)[:, 0], np.polyval(coefficients, at), rtol=0, atol=1e-10)
    assert float(report.dof) == pytest.approx(order, rel=1e-6)  # the polynomial's dof


def test_smoothing_target_is_met_and_monotone():
    rng = np.random.default_rng(8)
    x, y = noisy_function(rng, m=70)
    targets = [0.05, 0.2, 0.5, 1.0]
    reports = [dn.smooth(y, x=x, smoothing=s, full_output=True)[1] for s in targets]
    for s, report in zip(targets, reports, strict=True):
        assert float(report.residual) == pytest.approx(s, rel=1e-8)
    assert np.all(np.diff([float(r.penalty) for r in reports]) > 0)
    assert np.all(np.diff([float(r.dof) for r in reports]) < 0)
    # With the chosen penalty given directly the same curve comes back.
    again = dn.smooth(y, x=x, penalty=reports[1].penalty)
    assert np.allclose(again(x), dn.smooth(y, x=x, smoothing=0.2)(x), atol=1e-12)
    # s = 0 interpolates; with n_control it is plain least squares.
    assert np.allclose(dn.smooth(y, x=x, smoothing=0.0)(x)[:, 0], y, atol=1e-9)
    lsq = dn.approximate(y[:, None], 15, 3, x, interpolate_ends=False)
    assert np.allclose(dn.smooth(y, 15, x=x, smoothing=0.0).control_points, lsq.control_points)


def test_closed_curve_is_periodic_and_near_the_circle():
    rng = np.random.default_rng(9)
    t = np.sort(rng.uniform(0.0, 2 * np.pi, 120))
    points = np.stack([np.cos(t), np.sin(t)], axis=-1) + 0.02 * rng.standard_normal((120, 2))
    # The angles as parameters: chord or centripetal parameters of noisy points carry the
    # noise, and GCV then keeps most of it (dof 109 of 120).
    angles = np.append(t, t[0] + 2 * np.pi)
    for n_control in (None, 20):
        curve, report = dn.smooth(points, n_control, x=angles, closed=True, full_output=True)
        lo, hi = curve.knots[3], curve.knots[-4]
        start, end = curve.derivatives(jnp.stack([lo, hi]), 2)
        assert np.allclose(start, end, rtol=0, atol=1e-10)  # C^2 at the seam
        radius = np.linalg.norm(np.asarray(curve(jnp.linspace(lo, hi, 2001))), axis=-1)
        assert np.max(np.abs(radius - 1.0)) < 0.02  # the data stray up to 0.056
        assert 4 < float(report.dof) < 20


def test_curve_in_3d_separates_by_coordinate():
    rng = np.random.default_rng(10)
    t = np.linspace(0.0, 4 * np.pi, 150)
    helix = np.stack([np.cos(t), np.sin(t), t / 4], axis=-1)
    points = helix + 0.03 * rng.standard_normal(helix.shape)
    curve, report = dn.smooth(points, parametrization=t, full_output=True)
    noise = np.sqrt(np.mean(np.sum((points - helix) ** 2, -1)))
    assert np.sqrt(np.mean(np.sum((curve(t) - helix) ** 2, -1))) < noise / 2
    for k in range(3):  # the same penalty per coordinate gives the same coordinate
        alone = dn.smooth(points[:, k], x=t, penalty=report.penalty)
        assert np.allclose(alone.control_points[:, 0], curve.control_points[:, k], atol=1e-10)


def test_float32():
    rng = np.random.default_rng(11)
    x = np.linspace(0.0, 3.0, 60) + rng.uniform(-0.01, 0.01, 60)  # spacing >= 0.03
    y = np.sin(2 * x) + 0.1 * rng.standard_normal(60)
    curve = dn.smooth(y.astype(np.float32), x=x.astype(np.float32), penalty=np.float32(1e-2))
    assert curve.control_points.dtype == jnp.float32
    reference = dn.smooth(y, x=x, penalty=1e-2)
    # float32 rounding (6e-8) times the condition number of the normal equations (~1e4)
    assert np.allclose(curve(x.astype(np.float32)), reference(x), atol=1e-3)
    curve, report = dn.smooth(y.astype(np.float32), 20, x=x.astype(np.float32), full_output=True)
    assert curve.control_points.dtype == report.dof.dtype == jnp.float32
    assert np.isfinite(report.gcv) and 4 < report.dof < 20


@pytest.mark.parametrize("closed", [False, True])
def test_gradients_match_finite_differences(closed):
    rng = np.random.default_rng(12)
    m = 12
    points = noisy_circle(rng, m, 0.05) if closed else rng.standard_normal((m, 2))
    x = np.sort(rng.uniform(0.0, 1.0, m + closed))
    w = rng.uniform(0.5, 2.0, m)
    at = np.sort(rng.uniform(x[0], x[-1], 9))
    probe = rng.standard_normal((9, 2))

    def loss(points, x, w, lam):
        curve, report = dn.smooth(
            points, x=x, weights=w, penalty=lam, closed=closed, full_output=True
        )
        return jnp.sum(curve(at) * probe) + report.gcv

    args = (points, x, w, 0.01)
    grads = jax.jit(jax.grad(loss, argnums=(0, 1, 2, 3)))(*args)
    compiled = jax.jit(loss)
    for k, g in enumerate(grads):

        def f(v, k=k):
            return float(compiled(*[v if j == k else a for j, a in enumerate(args)]))

        assert np.allclose(g, central_difference(f, args[k]), rtol=1e-5, atol=1e-6), k


def test_bad_input():
    rng = np.random.default_rng(13)
    x, y = noisy_function(rng, m=10)
    cases = [
        (dict(points=y[:3], x=x[:3]), "at least p \\+ 1 = 4 points"),
        (dict(smoothing=-1.0), "smoothing must be a finite number >= 0"),
        (dict(penalty=-1.0), "penalty must be a finite number >= 0"),
        (dict(penalty=np.nan), "penalty must be a finite number >= 0"),
        (dict(penalty=1.0, smoothing=1.0), "either smoothing"),
        (dict(penalty_order=0), "penalty_order must be >= 1"),
        (dict(penalty_order=4), "penalty_order must be in 1 .. degree = 3"),
        (dict(points=np.where(np.arange(10) == 3, np.nan, y)), "points must be finite"),
        (dict(x=np.where(np.arange(10) == 3, np.inf, x)), "x must be finite"),
        (dict(x=x[::-1]), "x must increase strictly"),
        (dict(x=x[:9]), "x must be a 1-D array of 10 abscissae"),
        (dict(weights=np.ones(9)), "weights must have shape \\(10,\\)"),
        (dict(weights=-np.ones(10)), "weights must be non-negative"),
        (dict(weights=np.full(10, np.nan)), "weights must be finite"),
        (dict(x=None), "function values: give their abscissae x"),
        (dict(n_control=11), "at most 10 control points"),
        (dict(n_control=3), "at least p \\+ 1 = 4 control points"),
        (dict(points=y[:, None, None]), "points must have 2 dimensions"),
        (dict(penalty=0.0, weights=np.r_[0.0, np.ones(9)]), "zero weights"),
    ]
    for change, message in cases:
        kwargs = dict(points=y, x=x) | change
        with pytest.raises(ValueError, match=message):
            dn.smooth(**kwargs)
    with pytest.raises(ValueError, match="needs concrete inputs"):
        jax.grad(lambda q: jnp.sum(dn.smooth(q, x=x, smoothing=0.1).control_points))(y)


def test_works_under_jit():
    rng = np.random.default_rng(14)
    x, y = noisy_function(rng)
    smooth = jax.jit(lambda y, lam: dn.smooth(y, x=x, penalty=lam).control_points)
    assert np.allclose(smooth(y, 0.01), dn.smooth(y, x=x, penalty=0.01).control_points)
