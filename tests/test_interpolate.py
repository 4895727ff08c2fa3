"""Interpolation and least squares against scipy, geomdl, numpy and exact polynomials."""

import itertools

import geomdl.fitting
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.interpolate import make_interp_spline, make_lsq_spline

import diffnurbs as dn
from diffnurbs._banded import band_rows, solve_banded

METHODS = ("uniform", "chord", "centripetal")


@pytest.fixture
def rng():
    return np.random.default_rng(6)


def wiggly_points(rng, m=13, dim=2):
    """Points along a loose spiral with random steps: no two consecutive ones coincide."""
    t = np.cumsum(rng.uniform(0.2, 1.0, m))
    return np.stack([t * np.cos(t), t * np.sin(t), *rng.normal(size=(dim - 2, m))], axis=-1)


def numpy_parameters(points, method):
    """Eq. 9.3-9.6 written out."""
    if method == "uniform":
        return np.linspace(0.0, 1.0, len(points))
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    steps = steps if method == "chord" else np.sqrt(steps)
    u = np.concatenate([[0.0], np.cumsum(steps) / steps.sum()])
    u[-1] = 1.0  # the rounded sum may end a hair off
    return u


def assert_curve_close(curve, spline, u, atol=1e-12):
    np.testing.assert_allclose(np.asarray(curve(jnp.asarray(u))), spline(u), atol=atol, rtol=0)


# ---------------------------------------------------------------------------------------------
# Parameters and knots


@pytest.mark.parametrize("method", METHODS)
def test_parametrize_follows_the_book(rng, method):
    points = wiggly_points(rng, dim=3)
    u = dn.parametrize(points, method)
    np.testing.assert_allclose(u, numpy_parameters(points, method), atol=1e-15)
    assert u[0] == 0.0 and u[-1] == 1.0


def test_parametrize_closed_adds_the_closing_step(rng):
    points = wiggly_points(rng)
    u = dn.parametrize(points, "chord", closed=True)
    expected = numpy_parameters(np.concatenate([points, points[:1]]), "chord")
    np.testing.assert_allclose(u, expected, atol=1e-15)


def test_parametrize_matches_geomdl(rng):
    points = wiggly_points(rng, dim=3)
    for centripetal, method in ((False, "chord"), (True, "centripetal")):
        expected = geomdl.fitting.compute_params_curve(points.tolist(), centripetal)
        np.testing.assert_allclose(dn.parametrize(points, method), expected, atol=1e-14)


@pytest.mark.parametrize("degree", [1, 2, 3, 5])
def test_averaged_knots_are_eq_9_8(rng, degree):
    u = np.sort(rng.uniform(size=11))
    u[0], u[-1] = 0.0, 1.0
    n = len(u) - 1
    interior = [u[j : j + degree].mean() for j in range(1, n - degree + 1)]
    expected = np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])
    np.testing.assert_allclose(dn.averaged_knots(u, degree), expected, atol=1e-15)


@pytest.mark.parametrize(("n_control", "degree"), [(4, 3), (7, 3), (12, 2), (20, 3), (20, 1)])
def test_approximation_knots_match_geomdl(rng, n_control, degree):
    u = np.sort(rng.uniform(size=20))
    u[0], u[-1] = 0.0, 1.0
    expected = geomdl.fitting.compute_knot_vector2(degree, len(u), n_control, u.tolist())
    np.testing.assert_allclose(dn.approximation_knots(u, n_control, degree), expected, atol=1e-15)


def test_every_approximation_span_holds_a_parameter(rng):
    u = np.sort(rng.uniform(size=30)) ** 3
    u[0], u[-1] = 0.0, 1.0
    knots = np.asarray(dn.approximation_knots(u, 25, 3))
    for a, b in itertools.pairwise(knots[3:-3]):
        assert np.any((u >= a) & (u <= b))


# ---------------------------------------------------------------------------------------------
# Banded solve


@pytest.mark.parametrize("half", [0, 1, 3])
def test_solve_banded_matches_a_dense_solve(rng, half):
    n = 17
    dense = np.zeros((n, n))
    for i in range(n):
        for j in range(max(0, i - half), min(n, i + half + 1)):
            dense[i, j] = rng.uniform(-1, 1)
        dense[i, i] = 2 * half + 2.0  # diagonally dominant: elimination needs no pivoting
    rows = np.repeat(np.arange(n), 2 * half + 1)
    cols = np.tile(np.arange(-half, half + 1), n) + rows
    inside = (cols >= 0) & (cols < n)
    values = np.where(inside, dense[rows, np.clip(cols, 0, n - 1)], 0.0)
    band = band_rows(
        jnp.arange(n), jnp.arange(n) - half, jnp.asarray(values.reshape(n, -1)), n, half
    )
    rhs = rng.normal(size=(n, 2))
    np.testing.assert_allclose(solve_banded(band, jnp.asarray(rhs)), np.linalg.solve(dense, rhs))


# ---------------------------------------------------------------------------------------------
# Interpolation of open curves


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("degree", [1, 2, 3, 4, 5])
def test_interpolation_equals_scipy(rng, method, degree):
    points = wiggly_points(rng, m=12, dim=3)
    curve = dn.interpolate(points, degree, method)
    u = numpy_parameters(points, method)
    np.testing.assert_allclose(curve.knots, dn.averaged_knots(u, degree), atol=1e-15)
    spline = make_interp_spline(u, points, k=degree, t=np.asarray(curve.knots))
    np.testing.assert_allclose(curve.control_points, spline.c, atol=1e-12)
    np.testing.assert_allclose(curve(jnp.asarray(u)), points, atol=1e-12)
    assert_curve_close(curve, spline, rng.uniform(size=50))


@pytest.mark.parametrize("centripetal", [False, True])
def test_interpolation_equals_geomdl(rng, centripetal):
    points = wiggly_points(rng, m=10, dim=3)
    reference = geomdl.fitting.interpolate_curve(points.tolist(), 3, centripetal=centripetal)
    curve = dn.interpolate(points, 3, "centripetal" if centripetal else "chord")
    np.testing.assert_allclose(curve.knots, reference.knotvector, atol=1e-14)
    np.testing.assert_allclose(curve.control_points, reference.ctrlpts, atol=1e-12)


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_interpolation_reproduces_polynomials_of_degree_at_most_p(rng, degree):
    """Points on a polynomial of degree <= p, at the given parameters: the spline space
    holds the polynomial, so interpolation must give it back everywhere."""
    coefficients = rng.normal(size=(degree + 1, 2))
    u = np.sort(rng.uniform(size=9))
    u[0], u[-1] = 0.0, 1.0

    def polynomial(t):
        return np.stack([np.polyval(coefficients[:, d], t) for d in range(2)], -1)

    curve = dn.interpolate(polynomial(u), degree, parametrization=u)
    t = rng.uniform(size=100)
    np.testing.assert_allclose(curve(jnp.asarray(t)), polynomial(t), atol=1e-12)


def test_seed_001_nine_points(rng):
    """Seed 001's nine planar points: the cubic passes through all of them."""
    points = np.array([[1, 1], [2, 5], [3, 2], [4, 4], [5, 1], [6, 1], [7, 1], [9, 1], [10, 2.0]])
    for method in METHODS:
        curve = dn.interpolate(points, 3, method)
        np.testing.assert_allclose(curve(dn.parametrize(points, method)), points, atol=1e-12)


@pytest.mark.parametrize("degree", [2, 3, 4])
@pytest.mark.parametrize("ends", ["start", "end", "both"])
def test_end_derivatives_equal_scipy(rng, degree, ends):
    points = wiggly_points(rng, m=8)
    start = rng.normal(size=2) if ends in ("start", "both") else None
    end = rng.normal(size=2) if ends in ("end", "both") else None
    curve = dn.interpolate(points, degree, "chord", start_derivative=start, end_derivative=end)
    u = numpy_parameters(points, "chord")
    bc = tuple(None if d is None else [(1, d)] for d in (start, end))
    spline = make_interp_spline(u, points, k=degree, t=np.asarray(curve.knots), bc_type=bc)
    np.testing.assert_allclose(curve.control_points, spline.c, atol=1e-12)
    np.testing.assert_allclose(curve(jnp.asarray(u)), points, atol=1e-12)
    for value, at in ((start, 0.0), (end, 1.0)):
        if value is not None:
            np.testing.assert_allclose(curve.derivatives(at, 1)[1], value, atol=1e-12)


def test_both_end_derivatives_give_the_books_knots(rng):
    """Eq. 9.22: with both derivatives, interior knots average all windows of p parameters."""
    points = wiggly_points(rng, m=7)
    curve = dn.interpolate(points, 3, "chord", start_derivative=[1, 0], end_derivative=[0, 1])
    u = numpy_parameters(points, "chord")
    interior = [u[j : j + 3].mean() for j in range(len(u) - 2)]
    np.testing.assert_allclose(curve.knots, np.r_[[0] * 4, interior, [1] * 4], atol=1e-15)


# ---------------------------------------------------------------------------------------------
# Closed curves


@pytest.mark.parametrize("degree", [1, 2, 3, 4, 5])
def test_closed_interpolation_equals_scipy_periodic(rng, degree):
    points = wiggly_points(rng, m=11, dim=3)
    curve = dn.interpolate(points, degree, "centripetal", closed=True)
    u = numpy_parameters(np.concatenate([points, points[:1]]), "centripetal")
    spline = make_interp_spline(
        u, np.concatenate([points, points[:1]]), k=degree, bc_type="periodic"
    )
    if degree > 1:  # scipy leaves the (unused) outer knots of a polyline clamped
        np.testing.assert_allclose(curve.knots, spline.t, atol=1e-14)
    assert_curve_close(curve, spline, np.concatenate([u, rng.uniform(size=50)]))
    np.testing.assert_allclose(curve(jnp.asarray(u[:-1])), points, atol=1e-12)


@pytest.mark.parametrize("degree", [2, 3, 4, 5])
def test_closed_curve_joins_with_c_p_minus_1_continuity(rng, degree):
    points = wiggly_points(rng, m=9)
    curve = dn.interpolate(points, degree, closed=True)
    ders = curve.derivatives(jnp.asarray([0.0, 1.0]), degree - 1)
    scale = np.abs(ders).max(axis=(0, 2), keepdims=True)[0]
    np.testing.assert_allclose(ders[0] / scale, ders[1] / scale, atol=1e-11)
    np.testing.assert_allclose(curve(0.0), points[0], atol=1e-12)
    assert curve.control_points.shape == (len(points) + degree, 2)


def test_closed_interpolation_of_circle_points_is_close_to_the_circle():
    angles = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    points = np.stack([np.cos(angles), np.sin(angles)], -1)
    curve = dn.interpolate(points, 3, "chord", closed=True)
    radius = np.linalg.norm(curve(jnp.linspace(0.0, 1.0, 1001)), axis=-1)
    # a cubic with step h = 2 pi / 40 is accurate to O(h^4) ~ 6e-4 times a small constant
    assert np.abs(radius - 1).max() < 1e-5


def wrapped_basis(knots, degree, u, n_control):
    """The basis matrix of a closed curve's `n_control` free control points: the columns
    of control points `n .. n+p-1` (the first `p` again) added to those of `0 .. p-1`."""
    matrix = np.asarray(dn.basis_matrix(jnp.asarray(knots), degree, jnp.asarray(u)))
    wrapped = matrix[:, :n_control].copy()
    wrapped[:, :degree] += matrix[:, n_control:]
    return wrapped


@pytest.mark.parametrize(
    ("degree", "n_control", "weighted"),
    [
        (1, 2, False),
        (2, 3, False),
        (2, 8, True),
        (3, 4, True),
        (3, 11, False),
        (4, 9, True),
        (5, 14, False),
    ],
)
def test_closed_least_squares_equals_a_dense_lstsq_of_the_wrapped_basis(
    rng, degree, n_control, weighted
):
    points = wiggly_points(rng, m=23, dim=3) + rng.normal(scale=0.3, size=(23, 3))
    weights = rng.uniform(0.0, 2.0, 23) if weighted else None
    curve = dn.approximate(points, n_control, degree, "chord", weights, closed=True)
    u = numpy_parameters(np.concatenate([points, points[:1]]), "chord")
    matrix = wrapped_basis(curve.knots, degree, u[:-1], n_control)
    root = np.sqrt(np.ones(23) if weights is None else weights)[:, None]
    expected = np.linalg.lstsq(root * matrix, root * points, rcond=None)[0]
    np.testing.assert_allclose(curve.control_points[:n_control], expected, atol=1e-11)
    np.testing.assert_allclose(curve.control_points[n_control:], expected[:degree])
    assert curve.knots.shape == (n_control + 2 * degree + 1,)
    # One period of knots from u_0 to u_m, the rest continuing it.
    period = np.asarray(curve.knots)
    np.testing.assert_allclose(period[[degree, n_control + degree]], [0.0, 1.0])
    np.testing.assert_allclose(period[n_control:] - period[:-n_control], 1.0, atol=1e-14)


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_every_closed_approximation_span_holds_a_parameter(rng, degree):
    for m, n_control in [(9, 9), (20, 7), (31, 30), (50, 6)]:
        u = np.concatenate([[0.0], np.sort(rng.uniform(0.0, 1.0, m - 1)), [1.0]])
        knots = np.asarray(
            dn.approximate(rng.normal(size=(m, 2)), n_control, degree, u, closed=True).knots
        )
        spans = knots[degree : n_control + degree + 1]
        counts = np.histogram(u[:-1], bins=spans)[0]
        assert np.all(counts >= 1), (m, n_control, counts)


@pytest.mark.parametrize("degree", [1, 2, 3, 4, 5])
def test_closed_least_squares_with_a_point_per_control_point_interpolates(rng, degree):
    points = wiggly_points(rng, m=12, dim=3)
    fit = dn.approximate(points, 12, degree, closed=True)
    interpolant = dn.interpolate(points, degree, closed=True)
    np.testing.assert_array_equal(fit.knots, interpolant.knots)
    np.testing.assert_allclose(fit.control_points, interpolant.control_points, atol=1e-12)


@pytest.mark.parametrize("degree", [2, 3])
def test_closed_least_squares_recovers_a_periodic_spline_from_its_samples(rng, degree):
    n_control = 7
    steps = rng.uniform(0.5, 1.5, n_control)
    u = np.concatenate([[0.0], np.cumsum(steps) / steps.sum()])
    knots = np.asarray(dn.periodic_knots(u, degree))
    control = rng.normal(size=(n_control, 3))
    truth = dn.NURBSCurve(np.concatenate([control, control[:degree]]), degree, knots)
    t = np.concatenate([[0.0], np.sort(rng.uniform(0.0, 1.0, 40)), [1.0]])
    curve = dn.approximate(truth(t[:-1]), n_control, degree, t, knots=knots, closed=True)
    np.testing.assert_allclose(curve.control_points[:n_control], control, atol=1e-12)
    check = jnp.linspace(0.0, 1.0, 501)
    np.testing.assert_allclose(curve(check), truth(check), atol=1e-12)


@pytest.mark.parametrize("degree", [2, 3, 4, 5])
def test_closed_least_squares_joins_with_c_p_minus_1_continuity(rng, degree):
    points = wiggly_points(rng, m=30) + rng.normal(scale=0.2, size=(30, 2))
    curve = dn.approximate(points, 10, degree, closed=True)
    # Derivatives at the domain's start come from the first span (the right side of the
    # seam), those at its end from the last span (the left side).
    ders = np.asarray(curve.derivatives(jnp.asarray([0.0, 1.0]), degree))
    scale = np.abs(ders).max(axis=(0, 2))[:, None]
    np.testing.assert_allclose(
        ders[0, :degree] / scale[:degree], ders[1, :degree] / scale[:degree], atol=1e-11
    )
    # The p-th derivative jumps: the two sides are evaluated on different spans.
    assert np.abs(ders[0, degree] - ders[1, degree]).max() > 1e-3 * scale[degree, 0]


def test_closed_least_squares_gradient_matches_finite_differences(rng):
    points = jnp.asarray(wiggly_points(rng, m=15))
    at = jnp.linspace(0.0, 1.0, 11)

    def loss(q):
        return jnp.sum(jnp.sin(dn.approximate(q, 6, 3, closed=True)(at)))

    grad = np.asarray(jax.grad(loss)(points))
    h = 1e-6
    for k, d in [(0, 0), (7, 1), (14, 0)]:
        central = (loss(points.at[k, d].add(h)) - loss(points.at[k, d].add(-h))) / (2 * h)
        np.testing.assert_allclose(grad[k, d], central, rtol=1e-6)


# ---------------------------------------------------------------------------------------------
# Least squares


@pytest.mark.parametrize("degree", [1, 2, 3, 5])
def test_plain_least_squares_equals_make_lsq_spline(rng, degree):
    points = wiggly_points(rng, m=60, dim=3) + rng.normal(scale=0.1, size=(60, 3))
    weights = rng.uniform(0.0, 2.0, 60)
    u = numpy_parameters(points, "chord")
    for w in (None, weights):
        curve = dn.approximate(points, 12, degree, "chord", w, interpolate_ends=False)
        # scipy minimises sum (w_k r_k)^2: its weights are square roots of ours
        spline = make_lsq_spline(
            u, points, np.asarray(curve.knots), degree, w=None if w is None else np.sqrt(w)
        )
        np.testing.assert_allclose(curve.control_points, spline.c, atol=1e-11)
        assert_curve_close(curve, spline, u, atol=1e-11)


@pytest.mark.parametrize("centripetal", [False, True])
def test_least_squares_through_the_ends_equals_geomdl(rng, centripetal):
    points = wiggly_points(rng, m=40, dim=3)
    method = "centripetal" if centripetal else "chord"
    reference = geomdl.fitting.approximate_curve(
        points.tolist(), 3, ctrlpts_size=9, centripetal=centripetal
    )
    curve = dn.approximate(points, 9, 3, method)
    np.testing.assert_allclose(curve.knots, reference.knotvector, atol=1e-14)
    np.testing.assert_allclose(curve.control_points, reference.ctrlpts, atol=1e-10)


def test_weighted_least_squares_through_the_ends_equals_a_constrained_lstsq(rng):
    """Independent oracle: numpy's lstsq for the interior control points, the end control
    points fixed to the end data points."""
    points = wiggly_points(rng, m=50) + rng.normal(scale=0.2, size=(50, 2))
    weights = rng.uniform(0.1, 3.0, 50)
    curve = dn.approximate(points, 10, 3, "centripetal", weights)
    u = numpy_parameters(points, "centripetal")
    basis = np.asarray(dn.basis_matrix(curve.knots, 3, u))
    residual = points - np.outer(basis[:, 0], points[0]) - np.outer(basis[:, -1], points[-1])
    root = np.sqrt(weights)[:, None]
    inner, *_ = np.linalg.lstsq(root * basis[:, 1:-1], root * residual, rcond=None)
    np.testing.assert_allclose(curve.control_points[1:-1], inner, atol=1e-11)
    np.testing.assert_allclose(np.asarray(curve.control_points)[[0, -1]], points[[0, -1]], atol=0)


@pytest.mark.parametrize("interpolate_ends", [True, False])
def test_least_squares_reproduces_polynomials(rng, interpolate_ends):
    u = np.sort(rng.uniform(size=40))
    u[0], u[-1] = 0.0, 1.0
    values = np.stack([u**3 - 2 * u, 1 + u**2], -1)
    curve = dn.approximate(values, 7, 3, u, interpolate_ends=interpolate_ends)
    t = rng.uniform(size=100)
    np.testing.assert_allclose(
        curve(jnp.asarray(t)), np.stack([t**3 - 2 * t, 1 + t**2], -1), atol=1e-12
    )


def test_as_many_control_points_as_points_interpolates(rng):
    points = wiggly_points(rng, m=15)
    curve = dn.approximate(points, 15, 3, "chord")
    np.testing.assert_allclose(curve(dn.parametrize(points, "chord")), points, atol=1e-10)


def test_zero_weights_ignore_points(rng):
    points = wiggly_points(rng, m=30)
    weights = np.ones(30)
    weights[10] = 0.0
    moved = points.copy()
    moved[10] += 100.0
    u = dn.parametrize(points, "chord")
    a = dn.approximate(points, 8, 3, u, weights)
    b = dn.approximate(moved, 8, 3, u, weights)
    np.testing.assert_allclose(a.control_points, b.control_points, atol=1e-12)


def test_approximate_with_given_knots(rng):
    points = wiggly_points(rng, m=30)
    u = numpy_parameters(points, "chord")
    knots = np.r_[[0] * 4, 0.2, 0.3, 0.7, [1] * 4]
    curve = dn.approximate(points, 7, 3, "chord", knots=knots, interpolate_ends=False)
    spline = make_lsq_spline(u, points, knots, 3)
    np.testing.assert_allclose(curve.control_points, spline.c, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# Gradients and tracing


def _check_gradient(loss, points, rng):
    """`jax.grad` under `jit` (so the construction runs on traced points) against central
    differences along a random direction."""
    gradient = jax.jit(jax.grad(loss))(points)
    loss = jax.jit(loss)
    direction = jnp.asarray(rng.normal(size=points.shape))
    eps = 1e-6
    numeric = (loss(points + eps * direction) - loss(points - eps * direction)) / (2 * eps)
    np.testing.assert_allclose(jnp.vdot(gradient, direction), numeric, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize(
    "build",
    [
        lambda q: dn.interpolate(q, 3, "centripetal"),
        lambda q: dn.interpolate(
            q, 3, "chord", start_derivative=q[1] - q[0], end_derivative=[1, 0]
        ),
        lambda q: dn.interpolate(q, 3, "centripetal", closed=True),
        lambda q: dn.approximate(q, 6, 3, "chord", weights=jnp.linspace(1, 2, q.shape[0])),
        lambda q: dn.approximate(q, 6, 2, "uniform", interpolate_ends=False),
    ],
    ids=["open", "derivatives", "closed", "lsq", "lsq-plain"],
)
def test_gradient_with_respect_to_the_points(rng, build):
    points = jnp.asarray(wiggly_points(rng, m=10))
    t = jnp.linspace(0.0, 1.0, 23)

    def loss(q):
        return jnp.sum(jnp.sin(build(q)(t)))

    _check_gradient(loss, points, rng)


def test_surface_gradients(rng):
    grid = jnp.asarray(surface_grid(rng, 6, 5))
    t = jnp.linspace(0.0, 1.0, 7)
    for build in (
        lambda g: dn.interpolate_surface(g, (3, 2)),
        lambda g: dn.approximate_surface(g, (4, 4), (2, 2)),
    ):

        def loss(g, build=build):
            return jnp.sum(build(g).grid(t, t) ** 2)

        _check_gradient(loss, grid, rng)


def test_works_in_float32(rng):
    points = wiggly_points(rng).astype(np.float32)
    curve = dn.interpolate(points, 3)
    assert curve.control_points.dtype == jnp.float32
    np.testing.assert_allclose(curve(dn.parametrize(points)), points, atol=2e-5)
    assert dn.approximate(points, 6).control_points.dtype == jnp.float32


# ---------------------------------------------------------------------------------------------
# Surfaces


def surface_grid(rng, nu, nv):
    u, v = np.sort(rng.uniform(size=nu)), np.sort(rng.uniform(size=nv))
    uu, vv = np.meshgrid(np.cumsum(u + 0.3), np.cumsum(v + 0.3), indexing="ij")
    return np.stack([uu, vv, np.sin(uu) * np.cos(vv) + 0.1 * rng.normal(size=uu.shape)], -1)


@pytest.mark.parametrize("method", METHODS)
def test_surface_interpolation_equals_scipy_along_both_directions(rng, method):
    grid = surface_grid(rng, 7, 6)
    surface = dn.interpolate_surface(grid, (3, 2), method)
    u, v = dn._interpolate.grid_parameters(jnp.asarray(grid), method)
    np.testing.assert_allclose(surface.grid(u, v), grid, atol=1e-12)
    along_u = make_interp_spline(np.asarray(u), grid, k=3, t=np.asarray(surface.knots_u), axis=0)
    along_v = make_interp_spline(
        np.asarray(v), along_u.c, k=2, t=np.asarray(surface.knots_v), axis=1
    )
    # scipy moves the interpolation axis to the front
    np.testing.assert_allclose(surface.control_points, np.swapaxes(along_v.c, 0, 1), atol=1e-12)


def test_grid_parameters_match_the_book(rng):
    grid = surface_grid(rng, 6, 5)
    for centripetal, method in ((False, "chord"), (True, "centripetal")):
        flat = grid.reshape(-1, 3).tolist()
        u_ref, v_ref = geomdl.fitting.compute_params_surface(flat, 6, 5, centripetal)
        u, v = dn._interpolate.grid_parameters(jnp.asarray(grid), method)
        np.testing.assert_allclose(u, u_ref, atol=1e-14)
        np.testing.assert_allclose(v, v_ref, atol=1e-14)


def test_surface_interpolation_equals_geomdl(rng):
    grid = surface_grid(rng, 6, 7)
    reference = geomdl.fitting.interpolate_surface(grid.reshape(-1, 3).tolist(), 6, 7, 3, 3)
    surface = dn.interpolate_surface(grid, (3, 3), "chord")
    np.testing.assert_allclose(surface.knots_u, reference.knotvector_u, atol=1e-14)
    np.testing.assert_allclose(surface.knots_v, reference.knotvector_v, atol=1e-14)
    np.testing.assert_allclose(surface.control_points.reshape(-1, 3), reference.ctrlpts, atol=1e-11)


def test_surface_interpolation_skips_a_pole_row(rng):
    """A row collapsed to one point has no chord length: it is left out of the average."""
    grid = surface_grid(rng, 6, 5)
    grid[0] = grid[0, 0]
    surface = dn.interpolate_surface(grid, (3, 3))
    u, v = dn._interpolate.grid_parameters(jnp.asarray(grid), "centripetal")
    np.testing.assert_allclose(
        v, dn._interpolate.grid_parameters(jnp.asarray(grid[1:]), "centripetal")[1], atol=1e-15
    )
    np.testing.assert_allclose(surface.grid(u, v), grid, atol=1e-12)


def test_surface_interpolation_reproduces_a_bi_polynomial(rng):
    u, v = np.linspace(0, 1, 6), np.linspace(0, 1, 5)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    grid = np.stack([uu, vv, uu**3 * vv - 2 * uu * vv**2 + 1], -1)
    surface = dn.interpolate_surface(grid, (3, 2), "uniform")
    s, t = rng.uniform(size=30), rng.uniform(size=30)
    expected = np.stack([s, t, s**3 * t - 2 * s * t**2 + 1], -1)
    np.testing.assert_allclose(surface(jnp.asarray(s), jnp.asarray(t)), expected, atol=1e-12)


def test_plain_surface_least_squares_is_the_tensor_product_fit(rng):
    """Oracle: one big lstsq with the Kronecker product of the two basis matrices."""
    grid = surface_grid(rng, 12, 10)
    surface = dn.approximate_surface(grid, (6, 5), (3, 2), "chord", interpolate_ends=False)
    u, v = dn._interpolate.grid_parameters(jnp.asarray(grid), "chord")
    basis = np.kron(
        np.asarray(dn.basis_matrix(surface.knots_u, 3, u)),
        np.asarray(dn.basis_matrix(surface.knots_v, 2, v)),
    )
    control, *_ = np.linalg.lstsq(basis, grid.reshape(-1, 3), rcond=None)
    np.testing.assert_allclose(surface.control_points.reshape(-1, 3), control, atol=1e-11)


def test_surface_least_squares_through_the_boundary(rng):
    grid = surface_grid(rng, 12, 10)
    surface = dn.approximate_surface(grid, (6, 5))
    for corner in ((0, 0), (0, -1), (-1, 0), (-1, -1)):
        np.testing.assert_allclose(surface.control_points[corner], grid[corner], atol=1e-12)
    # the u = 0 boundary is the curve fit of the first grid line
    _, v = dn._interpolate.grid_parameters(jnp.asarray(grid), "centripetal")
    edge = dn.approximate(grid[0], 5, 3, v)
    np.testing.assert_allclose(surface.control_points[0], edge.control_points, atol=1e-12)


def test_surface_least_squares_equals_geomdl(rng):
    grid = surface_grid(rng, 10, 9)
    reference = geomdl.fitting.approximate_surface(
        grid.reshape(-1, 3).tolist(), 10, 9, 3, 2, ctrlpts_size_u=6, ctrlpts_size_v=5
    )
    surface = dn.approximate_surface(grid, (6, 5), (3, 2), "chord")
    np.testing.assert_allclose(surface.knots_u, reference.knotvector_u, atol=1e-14)
    np.testing.assert_allclose(surface.control_points.reshape(-1, 3), reference.ctrlpts, atol=1e-10)


# ---------------------------------------------------------------------------------------------
# Bad input


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda q: dn.interpolate(q[:3], 3), "at least p \\+ 1 = 4 points for degree 3, got 3"),
        (lambda q: dn.approximate(q[:3], 4, 3), r"at most 3 control points \(the number of points"),
        (lambda q: dn.approximate(q, 3, 3), r"at least p \+ 1 = 4 control points for degree 3"),
        (lambda q: dn.approximate(q, 11, 3), r"at most 10 control points \(the number of points"),
        (lambda q: dn.interpolate(q.at[4].set(q[3]), 3, "chord"), "points 3 and 4 coincide"),
        (lambda q: dn.interpolate(q.at[4].set(q[3]), 3), "points 3 and 4 coincide"),
        (lambda q: dn.interpolate(q.at[2, 1].set(jnp.nan), 3), "points must be finite"),
        (lambda q: dn.interpolate(q, 3, "arc"), "parametrization must be one of"),
        (lambda q: dn.interpolate(q, 3, jnp.linspace(0, 1, 9)), "10 parameters"),
        (lambda q: dn.interpolate(q, 3, jnp.linspace(1, 0, 10)), "increase strictly"),
        (lambda q: dn.interpolate(q[0], 3), "2 dimensions"),
        (lambda q: dn.interpolate(q.at[-1].set(q[0]), 3, closed=True), "without repeating"),
        (lambda q: dn.interpolate(q, 3, closed=True, end_derivative=[0, 1]), "open curves"),
        (lambda q: dn.interpolate(q, 3, start_derivative=[0, 1, 2]), "shape \\(2,\\)"),
        (lambda q: dn.interpolate(q, 1, start_derivative=[0, 1]), "degree >= 2"),
        (lambda q: dn.approximate(q, 5, weights=-jnp.ones(10)), "non-negative"),
        (lambda q: dn.approximate(q, 5, weights=jnp.ones(9)), "one per point"),
        (
            lambda q: dn.approximate(q, 5, 3, knots=jnp.r_[[0] * 4, 0.5, [2] * 4]),
            "interpolate_ends needs clamped knots",
        ),
        (
            lambda q: dn.approximate(
                q, 6, 1, jnp.linspace(0, 1, 10), knots=jnp.r_[0, 0, 0.01, 0.02, 0.03, 0.05, 1, 1]
            ),
            "singular",
        ),
        (lambda q: dn.approximate(q, 11, 3, closed=True), r"at most 10 control points"),
        (lambda q: dn.approximate(q, 3, 3, closed=True), r"at least p \+ 1 = 4 control points"),
        (
            lambda q: dn.approximate(q.at[2, 0].set(jnp.nan), 5, closed=True),
            "points must be finite",
        ),
        (lambda q: dn.approximate(q.at[-1].set(q[0]), 5, closed=True), "without repeating"),
        (lambda q: dn.approximate(q, 5, closed=True, interpolate_ends=True), "open curves only"),
        (lambda q: dn.approximate(q, 5, 3, jnp.linspace(0, 1, 10), closed=True), "11 parameters"),
        (
            lambda q: dn.approximate(q, 5, 2, knots=jnp.linspace(-0.4, 1.4, 11), closed=True),
            r"needs n_control \+ 2 p \+ 1 = 10 periodic knots",
        ),
        (
            lambda q: dn.approximate(
                q, 5, 2, knots=jnp.r_[-0.3, -0.2, 0, 0.2, 0.4, 0.6, 0.8, 1, 1.2, 1.3], closed=True
            ),
            "must repeat with the period",
        ),
    ],
)
def test_bad_input_raises_a_clear_value_error(rng, call, message):
    points = jnp.asarray(wiggly_points(rng, m=10))
    with pytest.raises(ValueError, match=message):
        call(points)


def test_uniform_parametrization_accepts_repeated_points(rng):
    points = wiggly_points(rng, m=10)
    points[4] = points[3]
    curve = dn.interpolate(points, 3, "uniform")
    np.testing.assert_allclose(curve(jnp.linspace(0, 1, 10)), points, atol=1e-12)


def test_bad_surface_input(rng):
    grid = surface_grid(rng, 5, 4)
    with pytest.raises(ValueError, match=r"at least p \+ 1 = 5 points along v for degree 4, got 4"):
        dn.interpolate_surface(grid, (3, 4))
    with pytest.raises(ValueError, match=r"at most 5 control points along u \(the number of grid"):
        dn.approximate_surface(grid, (6, 3))
    with pytest.raises(ValueError, match="3 dimensions"):
        dn.interpolate_surface(grid[0], (3, 3))
    grid[:, 2] = grid[:, 1]
    with pytest.raises(ValueError, match="grid lines along v at positions 1 and 2 coincide"):
        dn.interpolate_surface(grid, (3, 2), "chord")
