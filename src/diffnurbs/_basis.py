"""B-spline and Bernstein basis functions.

The degree is always a Python int, so the loops below unroll at trace time and every
function is a fixed expression graph of array operations: `jit`, `vmap` and `grad`
(with respect to the knots as well as the parameter) work on all of them.

`find_span`, `basis_funs`, `ders_basis_funs` and `basis_matrix` check concrete knots (and
all but `find_span` concrete parameters) with `check_basis_arguments` before calling their
compiled bodies; traced ones pass unchecked, so the checks cost nothing inside `jit`.
"""

import functools
import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, Int

from ._misc import safe_divide
from ._validate import check_basis_arguments, check_degree, check_order


def find_span(knots: ArrayLike, degree: int, u: ArrayLike) -> Int[Array, "..."]:
    """Index `i` of the knot span `[knots[i], knots[i + 1])` that holds `u`.

    The largest `i` in `[degree, n]` with `knots[i] <= u`, where `n = len(knots) - degree - 2`:
    the last knot belongs to the last non-empty span, a repeated knot starts the span to
    its right, and parameters outside the domain fall into the first or last span. The
    search is a binary search written as a loop (a bisection per bit of the index), which
    XLA keeps as one pass over `u`.

    Concrete knots are checked (`ValueError`): at least `2 p + 2` of them, finite,
    non-decreasing, no value more than `p + 1` times, a non-empty domain. Traced knots
    are not, at no cost to the compiled program.

    **Arguments:**

    - `knots`: non-decreasing knot vector of length `n + degree + 2`.
    - `degree`: the degree `p >= 0`.
    - `u`: parameters, any shape.

    **Returns:**

    Integer array of the shape of `u`.
    """
    check_degree(degree, minimum=0)
    check_basis_arguments(knots, degree)
    return _find_span(knots, degree, u)


@functools.partial(jax.jit, static_argnums=1)
def _find_span(knots, degree, u):
    knots, u = jnp.asarray(knots), jnp.asarray(u)
    last = knots.shape[0] - degree - 2
    steps = max(last - degree, 0).bit_length()

    def bisect(i, span):
        candidate = span + jnp.left_shift(1, steps - 1 - i)
        start = knots[jnp.minimum(candidate, last)]
        # `start < knots[last + 1]`: at and beyond the domain's end, the last non-empty span
        # (the end knot may be repeated inside an unclamped knot vector).
        inside = (candidate <= last) & (start <= u) & (start < knots[last + 1])
        return jnp.where(inside, candidate, span)

    return jax.lax.fori_loop(0, steps, bisect, jnp.full(u.shape, degree, dtype=jnp.int32))


def _local_knots(knots, degree, span, u):
    """`left[j] = u - U[span + 1 - j]`, `right[j] = U[span + j] - u` for j = 0..p."""
    left = [u - knots[span + 1 - j] for j in range(degree + 1)]
    right = [knots[span + j] - u for j in range(degree + 1)]
    return left, right


def basis_funs(
    knots: ArrayLike, degree: int, u: ArrayLike
) -> tuple[Int[Array, "..."], Float[Array, "... p+1"]]:
    """The `degree + 1` non-zero B-spline basis functions at `u` (NURBS Book A2.2).

    Concrete knots are checked as in `find_span`, and concrete parameters must lie in the
    domain `[knots[p], knots[n + 1]]` (`ValueError`); traced ones are not checked, and a
    traced parameter outside the domain gets the polynomial piece of the first or last
    span.

    **Arguments:**

    - `knots`: non-decreasing knot vector.
    - `degree`: the degree `p`.
    - `u`: parameters, any shape.

    **Returns:**

    `(span, N)` where `span` has the shape of `u` and `N[..., r]` is
    `N_{span - p + r, p}(u)`, shape `u.shape + (p + 1,)`.
    """
    check_degree(degree, minimum=0)
    check_basis_arguments(knots, degree, u)
    return _basis_funs(knots, degree, u)


@functools.partial(jax.jit, static_argnums=1)
def _basis_funs(knots, degree, u):
    knots = jnp.asarray(knots)
    u = jnp.asarray(u, dtype=jnp.result_type(knots.dtype, float))
    span = _find_span(knots, degree, u)
    left, right = _local_knots(knots, degree, span, u)
    funs = [jnp.ones_like(u)]
    for j in range(1, degree + 1):
        saved = jnp.zeros_like(u)
        new = []
        for r in range(j):
            temp = safe_divide(funs[r], right[r + 1] + left[j - r])
            new.append(saved + right[r + 1] * temp)
            saved = left[j - r] * temp
        funs = [*new, saved]
    return span, jnp.stack(funs, axis=-1)


def dense_basis(span: Array, funs: Array, degree: int, n_control: int) -> Array:
    """The local functions of `basis_funs` spread into a `(len(span), n_control)` matrix,
    zeros off the band."""
    first = (span - degree)[:, None]
    column = jnp.arange(n_control)
    return sum(funs[:, r, None] * (column == first + r) for r in range(degree + 1))


def local_indices(span: Array, degree: int) -> Array:
    """Indices `span - p, ..., span` of the control points that act on a span."""
    return span[..., None] - degree + jnp.arange(degree + 1)


def combine_local(funs: Array, points: Array, span: Array, degree: int) -> Array:
    """`sum_r funs[..., r] P[span - p + r]`: the `p + 1` non-zero terms of a B-spline sum.

    `funs` has shape `span.shape + extra + (p + 1,)` (e.g. one row per derivative order);
    the result has shape `span.shape + extra + points.shape[1:]`. One gathered row of points per
    term keeps the working set at `(..., dim)` instead of `(..., p + 1, dim)`.
    """
    extra = (1,) * (funs.ndim - span.ndim - 1)
    item = points.shape[1:]  # (dim,) for a curve, (nv, dim) for the rows of a surface net
    total = 0.0
    for r in range(degree + 1):
        row = points[span - degree + r].reshape(span.shape + extra + item)
        total = total + funs[..., r].reshape(funs.shape[:-1] + (1,) * len(item)) * row
    return total


def span_derivatives(
    knots: Array, degree: int, points: Array, span: Array, u: Array, order: int
) -> list[Array]:
    """`C^(k)(u)` for `k = 0..order` of the B-spline with control points `points`, each
    from the polynomial piece of span `span` (not searched for: any `u` may be given).

    `C^(k)` is the B-spline of degree `p - k` on the same knots whose control points are
    the differences `P^(k)_i = (p - k + 1) (P^(k-1)_{i+1} - P^(k-1)_i) / (U_{i+p+1} - U_{i+k})`
    (NURBS Book eq. 3.8, A3.3), and one A2.2 triangle holds the functions of every degree
    `p - k`. That is a few whole-array differences and one plain basis evaluation, about
    half the operations of A2.3 (`ders_basis_funs`) for all orders: a much smaller
    program for XLA to compile.

    **Returns:**

    A list of `order + 1` arrays of shape `u.shape + points.shape[1:]`.
    """
    p = degree
    left, right = _local_knots(knots, p, span, u)
    by_degree = [[jnp.ones_like(u)]]  # by_degree[q][r] = N_{span - q + r, q}(u)
    for j in range(1, p + 1):
        funs, saved, new = by_degree[-1], jnp.zeros_like(u), []
        for r in range(j):
            temp = safe_divide(funs[r], right[r + 1] + left[j - r])
            new.append(saved + right[r + 1] * temp)
            saved = left[j - r] * temp
        by_degree.append([*new, saved])
    item = (1,) * (points.ndim - 1)
    ders = []
    for k in range(min(order, p) + 1):
        if k > 0:
            count = points.shape[0] - 1
            steps = (knots[p + 1 : p + 1 + count] - knots[k : k + count]).reshape(-1, *item)
            points = (p - k + 1) * safe_divide(points[1:] - points[:-1], steps)
        # P^(k)_i goes with N_{i + k, p - k}: the span's functions start at span - p + k.
        ders.append(combine_local(jnp.stack(by_degree[p - k], axis=-1), points, span - k, p - k))
    zeros = jnp.zeros(u.shape + points.shape[1:], dtype=ders[0].dtype)
    return ders + [zeros] * (order - min(order, p))


def taylor_coefficients(knots: Array, degree: int, points: Array, at: Array) -> Array:
    """`C^(k)(at) / k!` for `k = 0..degree`: the coefficients of the curve's polynomial on the
    span of `at`, around `at` (`C(at + t) = sum_k coefficient_k t^k` on that span).

    `points` are the control points (homogeneous for a rational curve); the result has shape
    `at.shape + (degree + 1, dim)`.
    """
    span, ders = ders_basis_funs(knots, degree, at, degree)
    factorials = jnp.asarray([math.factorial(k) for k in range(degree + 1)], dtype=at.dtype)
    return combine_local(ders, points, span, degree) / factorials[:, None]


def basis_matrix(knots: ArrayLike, degree: int, u: ArrayLike) -> Float[Array, "m n+1"]:
    """The collocation matrix `A[k, i] = N_{i,p}(u_k)` of all basis functions.

    Interpolation and least squares solve with it; a curve's points are `A @ P`.

    Concrete inputs are checked (`ValueError`, as in `basis_funs`): at least `2 p + 2`
    finite, non-decreasing knots, no value repeated more than `p + 1` times, a non-empty
    domain, and every `u` in the domain `[knots[p], knots[n + 1]]`. Traced inputs (inside
    `jit` or `grad`) are not checked; there a parameter outside the domain gets the
    polynomial pieces of the first or last span.

    **Arguments:**

    - `knots`: non-decreasing knot vector of length `n + p + 2`.
    - `degree`: the degree `p`.
    - `u`: 1-D array of `m` parameters.

    **Returns:**

    Dense array of shape `(m, n + 1)`, `p + 1` non-zeros per row at most.
    """
    knots = jnp.asarray(knots)
    u = jnp.asarray(u, dtype=jnp.result_type(knots.dtype, float))
    if u.ndim != 1:
        raise ValueError(f"u must be a 1-D array of parameters, got shape {u.shape}")
    check_degree(degree, minimum=0)
    check_basis_arguments(knots, degree, u)
    return _basis_matrix(knots, degree, u)


@functools.partial(jax.jit, static_argnums=1)
def _basis_matrix(knots, degree, u):
    span, funs = _basis_funs(knots, degree, u)
    return dense_basis(span, funs, degree, knots.shape[0] - degree - 1)


def _ndu_table(left, right, degree, u):
    """Triangular table of A2.3: basis functions (upper) and knot differences (lower)."""
    ndu = [[None] * (degree + 1) for _ in range(degree + 1)]
    ndu[0][0] = jnp.ones_like(u)
    for j in range(1, degree + 1):
        saved = jnp.zeros_like(u)
        for r in range(j):
            ndu[j][r] = right[r + 1] + left[j - r]
            temp = safe_divide(ndu[r][j - 1], ndu[j][r])
            ndu[r][j] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        ndu[j][j] = saved
    return ndu


def _derivative_row(ndu, degree, r, order):
    """Derivatives 1..order of `N_{span - p + r, p}` from the table (inner loops of A2.3)."""
    p = degree
    row = []
    a_prev = {0: jnp.ones_like(ndu[0][0])}
    for k in range(1, order + 1):
        a = {}
        d = jnp.zeros_like(ndu[0][0])
        rk, pk = r - k, p - k
        if r >= k:
            a[0] = safe_divide(a_prev[0], ndu[pk + 1][rk])
            d = a[0] * ndu[rk][pk]
        j1 = 1 if rk >= -1 else -rk
        j2 = k - 1 if r - 1 <= pk else p - r
        for j in range(j1, j2 + 1):
            a[j] = safe_divide(a_prev[j] - a_prev[j - 1], ndu[pk + 1][rk + j])
            d = d + a[j] * ndu[rk + j][pk]
        if r <= pk:
            a[k] = safe_divide(-a_prev[k - 1], ndu[pk + 1][r])
            d = d + a[k] * ndu[r][pk]
        row.append(d * (math.factorial(p) // math.factorial(p - k)))
        a_prev = a
    return row


def ders_basis_funs(
    knots: ArrayLike, degree: int, u: ArrayLike, order: int
) -> tuple[Int[Array, "..."], Float[Array, "... order+1 p+1"]]:
    """Non-zero basis functions and their derivatives up to `order` (NURBS Book A2.3).

    Derivatives of order above the degree are exactly zero. Concrete inputs are checked
    as in `basis_funs`; traced ones are not, and a traced parameter outside the domain
    gets the polynomial piece of the first or last span.

    **Arguments:**

    - `knots`: non-decreasing knot vector.
    - `degree`: the degree `p`.
    - `u`: parameters, any shape.
    - `order`: highest derivative order, `>= 0`.

    **Returns:**

    `(span, ders)` with `ders[..., k, r]` the k-th derivative of `N_{span - p + r, p}` at
    `u`, shape `u.shape + (order + 1, p + 1)`.
    """
    check_degree(degree, minimum=0)
    order = check_order(order)
    check_basis_arguments(knots, degree, u)
    return _ders_basis_funs(knots, degree, u, order)


@functools.partial(jax.jit, static_argnums=(1, 3))
def _ders_basis_funs(knots, degree, u, order):
    knots = jnp.asarray(knots)
    u = jnp.asarray(u, dtype=jnp.result_type(knots.dtype, float))
    span = _find_span(knots, degree, u)
    left, right = _local_knots(knots, degree, span, u)
    ndu = _ndu_table(left, right, degree, u)
    top = min(order, degree)
    columns = []
    for r in range(degree + 1):
        column = [ndu[r][degree], *_derivative_row(ndu, degree, r, top)]
        column += [jnp.zeros_like(u)] * (order - top)
        columns.append(jnp.stack(column, axis=-1))
    return span, jnp.stack(columns, axis=-1)


def cox_de_boor(knots: ArrayLike, degree: int, i: int, u: ArrayLike) -> Float[Array, "..."]:
    """`N_{i,p}(u)` by the recursive Cox–de Boor definition, for teaching and testing.

    Degree 0 uses half-open spans `[u_i, u_{i+1})`, except that the last non-empty span
    also holds its right end, so the basis sums to one on the closed domain. Terms with
    a zero denominator are taken as zero (the 0/0 = 0 convention).

    **Arguments:**

    - `knots`: knot vector.
    - `degree`: the degree `p`.
    - `i`: index of the basis function, `0 <= i < len(knots) - p - 1`.
    - `u`: parameters, any shape.

    **Returns:**

    `N_{i,p}(u)` with the shape of `u`.
    """
    check_degree(degree, minimum=0)
    knots = jnp.asarray(knots)
    u = jnp.asarray(u, dtype=jnp.result_type(knots.dtype, float))
    if not 0 <= i < knots.shape[0] - degree - 1:
        raise ValueError(
            f"basis index i must be in [0, {knots.shape[0] - degree - 2}] for "
            f"{knots.shape[0]} knots and degree {degree}, got {i}"
        )
    if isinstance(knots, jax.core.Tracer) or isinstance(u, jax.core.Tracer):
        return _cox_de_boor(knots, degree, i, u)  # inlined into the caller's program
    return _compiled_cox_de_boor(knots, degree, i, u)


def _cox_de_boor(knots, degree, i, u):
    if degree == 0:
        inside = (knots[i] <= u) & (u < knots[i + 1])
        # The closed end: u == u_max belongs to the last span of positive length, the one
        # after which every knot equals its end knot.
        after = jnp.arange(knots.shape[0]) > i
        last_nonempty = (knots[i] < knots[i + 1]) & jnp.all(~after | (knots == knots[i + 1]))
        at_end = last_nonempty & (u == knots[i + 1])
        return jnp.where(inside | at_end, 1.0, 0.0).astype(u.dtype)
    rising = safe_divide(u - knots[i], knots[i + degree] - knots[i])
    falling = safe_divide(knots[i + degree + 1] - u, knots[i + degree + 1] - knots[i + 1])
    return rising * _cox_de_boor(knots, degree - 1, i, u) + falling * _cox_de_boor(
        knots, degree - 1, i + 1, u
    )


# Called eagerly: one compiled program per knot count, degree and parameter shape, `i` an
# argument of it. Run op by op, each of the recursion's 2^p terms dispatched (and compiled)
# a few small programs, for every `i` (a chapter's basis plots compiled hundreds of them);
# under a caller's trace, `i` stays a Python int and the recursion is traced in place.
_compiled_cox_de_boor = jax.jit(_cox_de_boor, static_argnums=1)


@functools.partial(jax.jit, static_argnums=0)
def bernstein(degree: int, t: ArrayLike) -> Float[Array, "... n+1"]:
    """All Bernstein polynomials `B_{i,n}(t) = C(n, i) t^i (1 - t)^(n - i)`.

    **Arguments:**

    - `degree`: the degree `n >= 0`.
    - `t`: parameters, any shape.

    **Returns:**

    Array of shape `t.shape + (n + 1,)`.
    """
    check_degree(degree, minimum=0)
    t = jnp.asarray(t, dtype=jnp.result_type(t, float))
    binomials = jnp.array([math.comb(degree, k) for k in range(degree + 1)], dtype=t.dtype)
    # Integer powers keep t**0 == 1 at t == 0 and have finite gradients everywhere.
    powers = [t**k * (1 - t) ** (degree - k) for k in range(degree + 1)]
    return binomials * jnp.stack(powers, axis=-1)
