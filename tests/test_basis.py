import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import naive_basis, random_knots, sample_parameters
from scipy.interpolate import BSpline

import diffnurbs as dn

DEGREES = [1, 2, 3, 4, 5]


def naive_span(knots, degree, u):
    """The seed's FindSpan (Listing 1.3) as a linear scan: knots[i] <= u < knots[i + 1]."""
    n = len(knots) - degree - 2
    if u >= knots[n + 1]:
        return n
    return max(i for i in range(degree, n + 1) if knots[i] <= u)


@pytest.mark.parametrize("degree", DEGREES)
def test_find_span_matches_linear_scan(degree):
    rng = np.random.default_rng(degree)
    knots = random_knots(rng, degree + 8, degree)
    u = sample_parameters(rng, knots, degree)
    expected = [naive_span(knots, degree, x) for x in u]
    np.testing.assert_array_equal(dn.find_span(knots, degree, u), expected)


def test_last_knot_belongs_to_last_nonempty_span():
    knots = [0, 0, 0, 0.5, 0.5, 1, 1, 1]
    assert int(dn.find_span(knots, 2, 1.0)) == 4
    assert int(dn.find_span(knots, 2, 0.5)) == 4  # a double knot starts the right span
    assert int(dn.find_span(knots, 2, 0.0)) == 2


@pytest.mark.parametrize("degree", DEGREES)
def test_basis_funs_match_cox_de_boor(degree):
    rng = np.random.default_rng(10 + degree)
    knots = random_knots(rng, degree + 7, degree)
    u = sample_parameters(rng, knots, degree)
    span, funs = dn.basis_funs(knots, degree, u)
    assert funs.shape == (*u.shape, degree + 1)
    full = naive_basis(knots, degree, u)
    local = np.take_along_axis(full, np.asarray(span)[:, None] - degree + np.arange(degree + 1), 1)
    np.testing.assert_allclose(funs, local, atol=1e-14)
    # Outside the span window the recursion gives exact zeros (local support).
    np.testing.assert_allclose(full.sum(-1), local.sum(-1), atol=1e-14)


@pytest.mark.parametrize("degree", DEGREES)
def test_ders_basis_funs_match_scipy(degree):
    rng = np.random.default_rng(20 + degree)
    n_control = degree + 7
    knots = random_knots(rng, n_control, degree)
    u = sample_parameters(rng, knots, degree)
    order = degree + 2
    span, ders = dn.ders_basis_funs(knots, degree, u, order)
    assert ders.shape == (*u.shape, order + 1, degree + 1)
    for r in range(degree + 1):
        for k in range(order + 1):
            index = np.asarray(span) - degree + r
            expected = [
                BSpline(knots, np.eye(n_control)[i], degree)(x, nu=k) if k <= degree else 0.0
                for i, x in zip(index, u, strict=True)
            ]
            scale = max(1.0, np.abs(expected).max())
            np.testing.assert_allclose(ders[:, k, r], expected, atol=1e-9 * scale)


@pytest.mark.parametrize("degree", DEGREES)
def test_ders_basis_funs_match_autodiff(degree):
    rng = np.random.default_rng(30 + degree)
    knots = random_knots(rng, degree + 6, degree)
    u = jnp.asarray(rng.uniform(0, 1, size=7))

    def funs(x):
        return dn.basis_funs(knots, degree, x)[1]

    _, ders = dn.ders_basis_funs(knots, degree, u, 3)
    derivative = funs
    for k in range(4):
        np.testing.assert_allclose(jax.vmap(derivative)(u), ders[:, k], rtol=1e-9, atol=1e-9)
        derivative = jax.jacfwd(derivative)


def test_ders_above_degree_are_exact_zeros():
    _, ders = dn.ders_basis_funs([0, 0, 0, 0.3, 1, 1, 1], 2, jnp.linspace(0, 1, 9), 5)
    assert np.all(np.asarray(ders[:, 3:]) == 0.0)


@pytest.mark.parametrize("degree", DEGREES)
def test_cox_de_boor_partition_of_unity_on_closed_domain(degree):
    rng = np.random.default_rng(40 + degree)
    knots = random_knots(rng, degree + 6, degree)
    u = sample_parameters(rng, knots, degree)
    np.testing.assert_allclose(naive_basis(knots, degree, u).sum(-1), 1.0, atol=1e-14)


def test_cox_de_boor_zero_over_zero_is_zero():
    # N_{0,2} on {0,0,0,1,...}: both recursive terms divide by a zero-length span.
    knots = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]
    u = jnp.linspace(0, 1, 5)
    np.testing.assert_allclose(dn.cox_de_boor(knots, 2, 0, u), (1 - u) ** 2, atol=1e-15)
    assert np.all(np.isfinite(jax.vmap(jax.grad(lambda x: dn.cox_de_boor(knots, 2, 0, x)))(u)))


@pytest.mark.parametrize("degree", [0, 1, 3, 7])
def test_bernstein_matches_binomial_formula_and_bezier_basis(degree):
    t = np.linspace(0, 1, 11)
    terms = [math.comb(degree, i) * t**i * (1 - t) ** (degree - i) for i in range(degree + 1)]
    expected = np.stack(terms, -1)
    np.testing.assert_allclose(dn.bernstein(degree, t), expected, atol=1e-15)
    if degree >= 1:
        bezier_knots = [0.0] * (degree + 1) + [1.0] * (degree + 1)
        np.testing.assert_allclose(naive_basis(bezier_knots, degree, t), expected, atol=1e-14)


def test_basis_gradients_with_respect_to_knots_are_finite_at_repeated_knots():
    knots = jnp.array([0, 0, 0, 0.5, 0.5, 1, 1, 1.0])

    def total(k):
        return jnp.sum(dn.ders_basis_funs(k, 2, jnp.array([0.0, 0.5, 1.0]), 2)[1] ** 2)

    assert np.all(np.isfinite(jax.grad(total)(knots)))


def test_basis_works_in_float32():
    knots = jnp.array([0, 0, 0, 0.25, 1, 1, 1], dtype=jnp.float32)
    _span, funs = dn.basis_funs(knots, 2, jnp.linspace(0, 1, 5, dtype=jnp.float32))
    assert funs.dtype == jnp.float32
    np.testing.assert_allclose(funs.sum(-1), 1.0, atol=1e-6)


def test_basis_matrix_matches_the_recursion():
    knots = jnp.asarray([0.0, 0, 0, 0.2, 0.5, 0.5, 0.8, 1, 1, 1])
    u = jnp.linspace(0.0, 1.0, 23)
    matrix = dn.basis_matrix(knots, 2, u)
    expected = jnp.stack([dn.cox_de_boor(knots, 2, i, u) for i in range(7)], axis=1)
    assert matrix.shape == (23, 7)
    np.testing.assert_allclose(matrix, expected, atol=1e-14)


def test_basis_matrix_rejects_a_grid():
    with pytest.raises(ValueError, match="1-D array"):
        dn.basis_matrix(jnp.asarray([0.0, 0, 1, 1]), 1, jnp.zeros((2, 2)))


def test_domain_end_repeated_inside_an_unclamped_knot_vector():
    # The domain [0, 3] ends at a triple knot followed by more knots: u = 3 belongs to the
    # last non-empty span [2, 3), not to the empty [3, 3).
    knots = jnp.asarray([-3.0, -2, -1, 0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3, 3, 4, 5, 6])
    assert int(dn.find_span(knots, 3, 3.0)) == 11
    points = np.random.default_rng(0).normal(size=(14, 2))
    curve = dn.NURBSCurve(points, 3, knots)
    np.testing.assert_allclose(curve(3.0), points[11], atol=1e-14)


BASIS_CALLS = {
    "find_span": dn.find_span,
    "basis_funs": dn.basis_funs,
    "ders_basis_funs": lambda knots, degree, u: dn.ders_basis_funs(knots, degree, u, 1),
    "basis_matrix": dn.basis_matrix,
}


@pytest.mark.parametrize("name", BASIS_CALLS)
def test_basis_functions_reject_bad_concrete_knots(name):
    # basis_matrix returned rows with negative entries, not summing to one, for these.
    call = BASIS_CALLS[name]
    u = np.array([0.1, 0.6])
    decreasing = r"non-decreasing, got knots\[4\] = 0.3 < knots\[3\] = 0.5"
    with pytest.raises(ValueError, match=decreasing):
        call([0, 0, 0, 0.5, 0.3, 1, 1, 1.0], 2, u)
    with pytest.raises(ValueError, match=r"at least 2 \(p \+ 1\) = 6 knots for degree 2, got 5"):
        call([0, 0, 0.5, 1, 1.0], 2, u)
    with pytest.raises(ValueError, match="at most degree \\+ 1 = 3 times"):
        call([0, 0, 0, 0.5, 0.5, 0.5, 0.5, 1, 1, 1.0], 2, u)


@pytest.mark.parametrize("name", ["basis_funs", "ders_basis_funs", "basis_matrix"])
def test_basis_functions_reject_concrete_parameters_outside_the_domain(name):
    # Outside the domain the values are those of the end spans' polynomials, not basis
    # functions (negative entries).
    call = BASIS_CALLS[name]
    with pytest.raises(ValueError, match=r"u must lie in the domain \[0.0, 1.0\], got 1.5"):
        call([0, 0, 0, 0.5, 1, 1, 1.0], 2, np.array([0.2, 1.5]))
    with pytest.raises(ValueError, match=r"domain \[2.0, 3.0\], got 1.0"):
        call(np.arange(6.0), 2, np.array([1.0]))  # unclamped: the domain is [knots[p], knots[-p-1]]
    with pytest.raises(ValueError, match="u must be finite"):
        call([0, 0, 0, 0.5, 1, 1, 1.0], 2, np.array([np.nan]))


def test_find_span_outside_the_domain_is_the_first_or_last_span():
    np.testing.assert_array_equal(dn.find_span([0, 0, 0, 0.25, 1, 1, 1.0], 2, [-0.1, 1.1]), [2, 3])


def test_basis_matrix_outside_the_domain_under_jit():
    # Traced parameters are not checked: outside the domain a row holds the polynomial
    # pieces of the first or last span, as scipy's BSpline extrapolates them.
    knots = np.array([0.0, 0, 0, 0.3, 0.5, 1, 1, 1])
    u = jnp.asarray([-0.2, 0.0, 0.4, 1.0, 1.3])
    matrix = jax.jit(dn.basis_matrix, static_argnums=1)(knots, 2, u)
    expected = [BSpline(knots, np.eye(5)[i], 2, extrapolate=True)(u) for i in range(5)]
    np.testing.assert_allclose(matrix, np.stack(expected, axis=1), atol=1e-14)
    np.testing.assert_allclose(matrix.sum(axis=1), 1.0, atol=1e-14)


def span_by_definition(knots, degree, u):
    """`find_span`'s docstring as a linear scan: the largest i in [p, n] with knots[i] <= u,
    counting only knots before the domain's end (the last knot belongs to the last non-empty
    span); p below the domain and for NaN."""
    n = len(knots) - degree - 2
    found = [i for i in range(degree, n + 1) if knots[i] <= u and knots[i] < knots[n + 1]]
    return max(found, default=degree)


def knot_vector_zoo(rng, degree, n_interior):
    """Knot vectors of one length: random, uniform, repeated (up to p + 1), clustered (half
    of them within 1e-6), on a grid (ties), clamped or not."""
    ends = (np.zeros(degree + 1), np.ones(degree + 1))
    unclamped = (-np.arange(degree + 1, 0, -1) / 10.0, 1 + np.arange(degree + 1) / 10.0)
    distinct = rng.uniform(0.0, 1.0, n_interior)
    repeated = np.repeat(distinct, rng.integers(1, degree + 2, n_interior))[:n_interior]
    cluster = np.concatenate(
        [0.3 + 1e-6 * rng.uniform(size=n_interior // 2), distinct[n_interior // 2 :]]
    )
    grid = rng.integers(1, 8, n_interior) / 8.0
    uniform = np.linspace(0.0, 1.0, n_interior + 2)[1:-1]
    for inner in (distinct, repeated, cluster, grid, uniform):
        for lower, upper in (ends, unclamped):
            yield np.concatenate([lower, np.sort(inner), upper])
    # The domain's end repeated inside an unclamped knot vector.
    inner = np.sort(np.concatenate([distinct[: n_interior - 2], [1.0, 1.0]]))
    yield np.concatenate([ends[0], inner, unclamped[1]])


@pytest.mark.parametrize("degree", [0, 1, 3, 5])
@pytest.mark.parametrize("ordered", [True, False])
def test_find_span_equals_the_definition(degree, ordered):
    # The search against its definition, at every knot (ties), next to every knot, outside the
    # domain and at random, in order or not.
    # Traced knots are not checked, so knots repeated more than p + 1 times are searched too.
    search = jax.jit(dn.find_span, static_argnums=1)
    rng = np.random.default_rng(degree)
    n_interior = 40
    for knots in knot_vector_zoo(rng, degree, n_interior):
        u = np.concatenate(
            [
                knots,
                np.nextafter(knots, -np.inf),
                np.nextafter(knots, np.inf),
                [-np.inf, -5.0, 5.0, np.inf],
                rng.uniform(knots[0] - 0.1, knots[-1] + 0.1, 300),
            ]
        )
        u = np.sort(u) if ordered else rng.permutation(u)
        expected = [span_by_definition(knots, degree, x) for x in u]
        np.testing.assert_array_equal(search(knots, degree, u), expected)
        np.testing.assert_array_equal(
            search(knots, degree, u.astype(np.float32)),
            [span_by_definition(knots, degree, x) for x in u.astype(np.float32)],
        )


def test_find_span_under_vmap_over_knots_and_parameters():
    rng = np.random.default_rng(7)
    knots = jnp.asarray(np.stack([random_knots(rng, 50, 3) for _ in range(4)]))
    knots = knots.at[1, 20:28].set(knots[1, 20])  # a knot repeated beyond p + 1 (unchecked)
    u = jnp.asarray(np.sort(rng.uniform(0.0, 1.0, (4, 200)), axis=1))
    both = jax.vmap(lambda k, x: dn.find_span(k, 3, x))(knots, u)
    only_u = jax.vmap(lambda x: dn.find_span(knots[0], 3, x))(u)
    for i in range(4):
        expected = [span_by_definition(np.asarray(knots[i]), 3, x) for x in np.asarray(u[i])]
        np.testing.assert_array_equal(both[i], expected)
        expected = [span_by_definition(np.asarray(knots[0]), 3, x) for x in np.asarray(u[i])]
        np.testing.assert_array_equal(only_u[i], expected)
