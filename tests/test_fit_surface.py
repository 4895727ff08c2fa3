"""fit_surface: penalised least-squares surfaces through scattered points.

Oracles: exact geometry (a plane, the paraboloid z = x^2 + y^2, a cylinder), a random
B-spline height field evaluated by scipy's NdBSpline, the dense least-squares solution of
numpy.linalg.lstsq / solve on basis matrices from the naive Cox-de Boor recursion and
Gram matrices by scipy quadrature, distances to the public (global) closest_point, and
central finite differences.
"""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate
from helpers import naive_basis
from scipy.interpolate import BSpline, NdBSpline

import diffnurbs as dn


@pytest.fixture
def rng():
    return np.random.default_rng(15)


def mirrored(quarter):
    """The points `(x, y)` and their three reflections in the axes: the covariance of
    a height field even in `x` and `y` then has the coordinate axes as eigenvectors, so
    the PCA parameters are affine in `x` and `y`."""
    return np.concatenate([quarter, quarter * [-1, 1], quarter * [1, -1], -quarter])


def paraboloid(xy):
    return np.column_stack([xy, np.sum(xy**2, axis=1)])


def fresh_parameters(rng, count=500):
    uv = rng.uniform(0.0, 1.0, (count, 2))
    corners = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 0.0], [1.0, 1.0]])
    return np.concatenate([corners, uv])


def xy_plane():
    """The unit square of the xy plane as a bilinear surface: projecting onto it gives
    `(u, v) = (x, y)`."""
    corners = np.array([[[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0]]])
    return dn.NURBSSurface(corners, (1, 1))


@pytest.mark.parametrize("penalty", [0.0, None, 1.0])
def test_recovers_a_plane_with_any_penalty(rng, penalty):
    # A tilted plane, sampled over an ellipse: PCA finds the plane, the parameters are
    # affine in its coordinates, and affine maps have zero thin-plate energy.
    frame, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    radius, angle = np.sqrt(rng.uniform(0, 1, 300)), rng.uniform(0, 2 * np.pi, 300)
    local = np.column_stack([3 * radius * np.cos(angle), radius * np.sin(angle)])
    origin = np.array([1.0, -2.0, 0.5])
    points = origin + local @ frame[:, :2].T
    surface, report = dn.fit_surface(
        points, (5, 4), penalty=penalty, correct_parameters=False, full_output=True
    )
    uv = fresh_parameters(rng)
    samples = np.asarray(surface(uv[:, 0], uv[:, 1]))
    assert np.abs((samples - origin) @ frame[:, 2]).max() <= 1e-12
    assert float(report.max_residual) <= 1e-12
    # The parameter square maps onto the cloud's bounding rectangle along its principal
    # directions (numpy's SVD), to the rounding of the normal equations (they square the
    # condition number of the basis: about 1e-12 here).
    directions = np.linalg.svd(points - points.mean(axis=0))[2][:2].T
    np.testing.assert_allclose(
        np.ptp(samples @ directions, axis=0), np.ptp(points @ directions, axis=0), rtol=1e-10
    )


def test_recovers_a_paraboloid_from_pca_parameters(rng):
    points = paraboloid(mirrored(rng.uniform(0.0, 1.0, (100, 2)) * [1.2, 1.0]))
    surface, report = dn.fit_surface(
        points, (4, 5), penalty=0.0, correct_parameters=False, full_output=True
    )
    x, y, z = np.asarray(surface(*fresh_parameters(rng).T)).T
    assert np.abs(z - x**2 - y**2).max() <= 1e-12
    assert float(report.max_residual) <= 1e-12
    # The parameters are the coordinates scaled to [0, 1] over the cloud's extent.
    extent = np.ptp(points[:, :2], axis=0)
    np.testing.assert_allclose(np.ptp(x), extent[0], rtol=1e-12)
    np.testing.assert_allclose(np.ptp(y), extent[1], rtol=1e-12)


@pytest.mark.parametrize("correct_parameters", [False, True])
def test_recovers_a_random_bspline_height_field_with_its_knots(rng, correct_parameters):
    counts, degrees = (8, 4), (3, 3)  # as in the cylinder test: one compilation
    knots = [dn.clamped_knots(n, p) for n, p in zip(counts, degrees, strict=True)]
    heights = NdBSpline(tuple(np.asarray(k) for k in knots), rng.standard_normal(counts), 3)
    xy = np.concatenate([fresh_parameters(rng)[:4], rng.uniform(0.0, 1.0, (596, 2))])
    points = np.column_stack([xy, heights(xy)])
    surface, report = dn.fit_surface(
        points,
        counts,
        degrees,
        base=xy_plane(),
        penalty=0.0,
        correct_parameters=correct_parameters,
        full_output=True,
    )
    uv = fresh_parameters(rng)
    expected = np.column_stack([uv, heights(uv)])
    np.testing.assert_allclose(surface(uv[:, 0], uv[:, 1]), expected, rtol=0, atol=1e-10)
    assert float(report.max_residual) <= 1e-10


def wavy_cloud(rng, count=300):
    """A noisy wavy sheet over a rectangle, turned in space (not representable exactly);
    its PCA rectangle is nearly the rectangle, so data reach the corners."""
    xy = rng.uniform(0.0, 1.0, (count, 2)) * [2.0, 1.0]
    z = 0.2 * np.sin(2 * xy[:, 0]) * np.cos(3 * xy[:, 1]) + 0.01 * rng.standard_normal(count)
    return np.column_stack([xy, z]) @ np.linalg.qr(rng.standard_normal((3, 3)))[0]


def dense_basis(uv, counts, degrees):
    """`A[k, i nv + j] = N_i(u_k) N_j(v_k)` by the Cox-de Boor recursion."""
    bases = [
        naive_basis(dn.clamped_knots(n, p), p, uv[:, axis])
        for axis, (n, p) in enumerate(zip(counts, degrees, strict=True))
    ]
    return (np.asarray(bases[0])[:, :, None] * np.asarray(bases[1])[:, None, :]).reshape(
        uv.shape[0], -1
    )


def test_unpenalised_control_points_match_dense_lstsq(rng):
    points, counts, degrees = wavy_cloud(rng), (6, 5), (3, 2)
    surface, report = dn.fit_surface(
        points, counts, degrees, penalty=0.0, correct_parameters=False, full_output=True
    )
    matrix = dense_basis(np.asarray(report.parameters), counts, degrees)
    expected = np.linalg.lstsq(matrix, points, rcond=None)[0].reshape(*counts, 3)
    np.testing.assert_allclose(surface.control_points, expected, rtol=0, atol=1e-10)
    residuals = np.linalg.norm(matrix @ expected.reshape(-1, 3) - points, axis=1)
    np.testing.assert_allclose(report.rms_residual, np.sqrt(np.mean(residuals**2)), rtol=1e-10)


def gram_by_quadrature(n, degree, order):
    """`integral N_i^(order) N_j^(order)` over [0, 1] by scipy's BSpline and adaptive
    quadrature over each knot span."""
    knots = np.asarray(dn.clamped_knots(n, degree))
    splines = [BSpline(knots, np.eye(n)[i], degree).derivative(order) for i in range(n)]
    gram = np.zeros((n, n))
    breaks = np.unique(knots)
    for i in range(n):
        for j in range(i, n):
            gram[i, j] = gram[j, i] = sum(
                scipy.integrate.quad(lambda t, i=i, j=j: splines[i](t) * splines[j](t), a, b)[0]
                for a, b in itertools.pairwise(breaks)
            )
    return gram


def test_penalised_fit_solves_the_normal_equations_with_the_thin_plate_energy(rng):
    points, counts, degrees, penalty = wavy_cloud(rng), (6, 5), (3, 2), 1e-3
    surface, report = dn.fit_surface(
        points, counts, degrees, penalty=penalty, correct_parameters=False, full_output=True
    )
    (m0u, k1u, k2u), (m0v, k1v, k2v) = (
        [gram_by_quadrature(n, p, order) for order in range(3)]
        for n, p in zip(counts, degrees, strict=True)
    )
    energy = np.kron(k2u, m0v) + 2 * np.kron(k1u, k1v) + np.kron(m0u, k2v)
    matrix = dense_basis(np.asarray(report.parameters), counts, degrees)
    m = points.shape[0]
    expected = np.linalg.solve(matrix.T @ matrix / m + penalty * energy, matrix.T @ points / m)
    np.testing.assert_allclose(
        surface.control_points, expected.reshape(*counts, 3), rtol=0, atol=1e-9
    )
    # The penalty matters at this weight: the unpenalised fit is another surface.
    plain = dn.fit_surface(points, counts, degrees, penalty=0.0, correct_parameters=False)
    assert np.abs(np.asarray(plain.control_points) - expected.reshape(*counts, 3)).max() > 1e-2


def cylinder_patch(rng, count=600):
    """Points of a half cylinder of radius 1 around the y axis: its PCA plane is the xy
    plane, where the parameter x = cos(theta) crowds the points towards the steep sides."""
    theta = rng.uniform(np.radians(10), np.radians(170), count)
    return np.column_stack([np.cos(theta), rng.uniform(0.0, 2.0, count), np.sin(theta)])


def test_parameter_correction_lowers_the_residual_every_round(rng):
    points = cylinder_patch(rng)
    fits = [
        dn.fit_surface(points, (8, 4), penalty=0.0, max_steps=steps, tol=1e-30, full_output=True)
        for steps in (1, 2, 3, 4, 6, 8, 12, 16, 24)
    ]
    rms = [float(report.rms_residual) for _, report in fits]
    assert [int(report.steps) for _, report in fits] == [1, 2, 3, 4, 6, 8, 12, 16, 24]
    assert not any(bool(report.converged) for _, report in fits)
    assert all(later < earlier for earlier, later in itertools.pairwise(rms))
    _, plain = dn.fit_surface(
        points, (8, 4), penalty=0.0, correct_parameters=False, full_output=True
    )
    assert rms[-1] < float(plain.rms_residual) / 3
    # The report's residuals are the distances to the nearest points of the surface, as
    # the global point inversion finds them.
    surface, report = fits[-1]
    u, v = surface.closest_point(points)
    distances = np.linalg.norm(np.asarray(surface(u, v)) - points, axis=1)
    np.testing.assert_allclose(report.rms_residual, np.sqrt(np.mean(distances**2)), rtol=1e-8)
    np.testing.assert_allclose(report.max_residual, distances.max(), rtol=1e-8)
    np.testing.assert_allclose(report.parameters, np.column_stack([u, v]), atol=1e-7)


def test_tol_ends_the_rounds_when_they_stop_paying(rng):
    points = wavy_cloud(rng)
    fits = {
        tol: dn.fit_surface(points, (8, 4), tol=tol, max_steps=50, full_output=True)[1]
        for tol in (1e-2, 1e-3)
    }
    coarse, fine = fits[1e-2], fits[1e-3]
    assert bool(coarse.converged) and bool(fine.converged)
    assert 1 <= int(coarse.steps) < int(fine.steps) < 50
    assert float(fine.rms_residual) <= float(coarse.rms_residual)


def test_a_hole_is_filled_fairly(rng):
    # A quadratic height field is biharmonic: the least-bending fill of a hole in it is
    # the quadratic itself, which a bicubic net holds exactly.
    xy = mirrored(rng.uniform(0.0, 1.0, (1500, 2)) * [1.2, 1.0])
    hole = (np.abs(xy[:, 0]) < 0.7) & (np.abs(xy[:, 1]) < 0.6)
    points = paraboloid(xy[~hole])
    with pytest.raises(ValueError, match="singular"):
        dn.fit_surface(points, (12, 12), penalty=0.0, correct_parameters=False)
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 41), np.linspace(0, 1, 41)), -1).reshape(-1, 2)
    errors = {}
    for penalty in (None, 1e-4):
        surface = dn.fit_surface(points, (12, 12), penalty=penalty, correct_parameters=False)
        x, y, z = np.asarray(surface(grid[:, 0], grid[:, 1])).T
        inside = (np.abs(x) < 0.7) & (np.abs(y) < 0.6)
        assert inside.sum() > 100
        errors[penalty] = np.abs(z - x**2 - y**2), inside
    # The regularising default: the quadratic to about sqrt(eps), hole included.
    error, inside = errors[None]
    assert error.max() <= 1e-7
    # Strong penalty flattens the paraboloid everywhere (by up to 0.17), but over the
    # hole it strays no farther than over the data.
    error, inside = errors[1e-4]
    assert 1e-2 < error[~inside].max() < 0.5
    assert error[inside].max() <= error[~inside].max()


@pytest.mark.parametrize(
    "options",
    [
        dict(penalty=1e-3, correct_parameters=False),
        dict(penalty=0.0, correct_parameters=False, base="plane"),
    ],
)
def test_gradient_with_respect_to_the_points_matches_finite_differences(rng, options):
    points = wavy_cloud(rng, 60)
    if options.get("base") == "plane":
        points = np.column_stack([rng.uniform(0, 1, (60, 2)), points[:, 2]])
        options = {**options, "base": xy_plane()}
    uv = fresh_parameters(rng, 20)
    weights = rng.standard_normal((uv.shape[0], 3))

    def loss(points):
        surface = dn.fit_surface(points, (4, 4), **options)
        return jnp.sum(weights * surface(uv[:, 0], uv[:, 1]) ** 2)

    gradient = jax.grad(loss)(jnp.asarray(points))
    direction = rng.standard_normal(points.shape)
    h = 1e-6
    difference = (loss(points + h * direction) - loss(points - h * direction)) / (2 * h)
    np.testing.assert_allclose(jnp.vdot(gradient, direction), difference, rtol=1e-6)


def test_gradient_with_respect_to_the_penalty_matches_finite_differences(rng):
    points = wavy_cloud(rng, 60)

    def loss(penalty):
        surface = dn.fit_surface(points, (4, 4), penalty=penalty, correct_parameters=False)
        return jnp.sum(surface(0.3, 0.6) ** 2)

    penalty, h = 1e-3, 1e-7
    difference = (loss(penalty + h) - loss(penalty - h)) / (2 * h)
    np.testing.assert_allclose(jax.grad(loss)(penalty), difference, rtol=1e-6)


def line(count=20):
    t = np.linspace(0.0, 1.0, count)
    return np.column_stack([t, 2 * t, -t])


@pytest.mark.parametrize(
    ("points", "kwargs", "message"),
    [
        ("cloud", dict(n_control=(6, 6), penalty=0.0), "at least nu \\* nv = 36 points"),
        ("nan", {}, "points must be finite"),
        (np.zeros((30, 2)), {}, "shape \\(m, 3\\)"),
        (np.zeros((30, 3, 1)), {}, "2 dimensions"),
        ("cloud", dict(degree=(0, 3)), "degree p must be >= 1"),
        ("cloud", dict(degree=3), "degree must be a pair"),
        ("cloud", dict(n_control=(3, 4)), "at least p \\+ 1 = 4 control points along u"),
        ("cloud", dict(n_control=4), "n_control must be a pair"),
        ("cloud", dict(n_control=(4.0, 4)), "n_control along u must be a Python int"),
        ("cloud", dict(penalty=-1.0), "penalty must be a finite number >= 0"),
        ("cloud", dict(penalty=np.nan), "penalty must be a finite number >= 0"),
        ("cloud", dict(penalty=[1.0]), "penalty must be a finite number >= 0"),
        (line(), {}, "lie on a line, so their PCA plane is undefined"),
        (np.ones((30, 3)), {}, "lie on a line"),
        ("cloud", dict(base="not a surface"), "base must be a surface"),
        ("cloud", dict(base="2d"), "base must be a surface in 3D"),
        (0.4 * line(), dict(base="plane"), "parameters on base lie on a line"),
        ("cloud", dict(max_steps=0), "max_steps must be positive"),
        ("cloud", dict(max_steps=2.5), "max_steps must be a Python int"),
        ("cloud", dict(tol=-1.0), "tol must be a finite number > 0"),
        ("cloud", dict(correct_parameters=1), "correct_parameters must be True or False"),
    ],
)
def test_bad_input_raises_value_error(rng, points, kwargs, message):
    if isinstance(points, str):
        cloud = wavy_cloud(rng, 30)
        if points == "nan":
            cloud[3, 1] = np.nan
        points = cloud
    bases = {"plane": xy_plane(), "2d": dn.NURBSSurface(np.zeros((2, 2, 2)), (1, 1))}
    if isinstance(kwargs.get("base"), str) and kwargs["base"] in bases:
        kwargs = {**kwargs, "base": bases[kwargs["base"]]}
    kwargs = {"n_control": (4, 4), "correct_parameters": False, **kwargs}
    with pytest.raises(ValueError, match=message):
        dn.fit_surface(points, **kwargs)


def test_works_in_float32(rng):
    points = paraboloid(mirrored(rng.uniform(0.0, 1.0, (100, 2)) * [1.2, 1.0]))
    surface, report = dn.fit_surface(points.astype(np.float32), (4, 5), full_output=True)
    assert surface.control_points.dtype == jnp.float32
    assert report.parameters.dtype == jnp.float32
    x, y, z = np.asarray(surface(*fresh_parameters(rng).T.astype(np.float32))).T
    assert np.abs(z - x**2 - y**2).max() <= 1e-3
