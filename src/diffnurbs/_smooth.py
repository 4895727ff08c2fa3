"""Smoothing splines: penalised least squares with the penalty `lam int |C^(r)(u)|^2 du`.

The control points minimise `sum_k w_k |C(u_k) - Q_k|^2 + lam int |C^(r)(u)|^2 du` over
the domain, the knots fixed. Both terms are quadratic in the control points, with banded
matrices (half-bandwidth `p`): the normal matrix `N^T W N` assembled point by point as in
`least_squares`, and the penalty's Gram matrix `R_ij = int N_i^(r) N_j^(r) du`, integrated
exactly span by span by Gauss-Legendre quadrature (`N_i^(r) N_j^(r)` is a polynomial of
degree `2 (p - r)` on a span, which `p - r + 1` nodes integrate exactly).

The normal equations `(N^T W N + lam R) P = N^T W Q` as they stand lose the polynomial
part of the fit (degree < r, which `R` annihilates) once `eps lam |R|` nears `|N^T W N|`;
with knots at every point `|R| ~ spacing^(1 - 2r)`, so this comes early (lam ~ 1e5 for
cubics through 40 points on [0, 3], ~1e4 for 10^5 points 1e-4 apart; scipy's
`make_smoothing_spline` alike). They are solved instead in the variables `P = B c + Z d`
(`_change_variables`): `Z` spans the polynomials, `B` all control points but `r` pinned
ones, and `R` enters only as the positive definite `B^T R B`. The banded block is
factored `L D L^T` in O(m p^2) and the `r` columns of `Z` are eliminated by a Schur
complement; the distance to the polynomial limit then keeps falling as `1 / lam` to
`lam = 1e12` and beyond.

A closed curve is a periodic spline: its last `p` control points repeat the first `p`,
which adds `p x p` corners to the band; its null space is the constants. The `p` shared
control points join the dense border of the same Schur complement, so the cost stays
O(m p^2).

The penalty weight is given (`penalty`), or chosen on concrete data: so that the
residual `sum_k w_k |C(u_k) - Q_k|^2` equals a target (`smoothing`, by a root find on
`log lam`), or by generalised cross-validation. The trace of the hat matrix that GCV
needs comes from the band of the inverse of the normal matrix, computed exactly from its
`L D L^T` factorisation by the recurrence of Hutchinson and de Hoog (1985) in O(m p^2),
the algorithm scipy's `make_smoothing_spline` uses for cubics. The GCV search starts where
about `sqrt(m)` degrees of freedom are expected and walks a grid on which the dof halve
per step, to both limits of the dof, then refines the best sample by Brent's method.
"""

import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from jaxtyping import Array, ArrayLike

from ._banded import band_rows, solve_banded
from ._basis import basis_funs, combine_local, ders_basis_funs
from ._curve import NURBSCurve
from ._interpolate import _data_points, _parameters, _point_weights, check_solved
from ._knots import approximation_knots, periodic_knots
from ._validate import check_control_count, check_degree, check_finite, concrete

# The GCV score is sampled on a grid of `log lam` before Brent's method refines the best
# sample: GCV can have several local minima, and the grid finds the basin of the lowest.
# Neighbouring samples differ by about this factor in dof (dof ~ lam^(-1 / 2r)).
_GCV_DOF_RATIO = 2.0
_BRACKET_DECADES = 40  # how far the searches for lam may go from their start


class SmoothingReport(eqx.Module):
    """What `smooth` did.

    - `penalty`: the weight `lam` of the penalty used; `inf` for the polynomial limit.
    - `residual`: the weighted residual `sum_k w_k |C(u_k) - Q_k|^2`.
    - `dof`: the effective degrees of freedom, the trace of the hat matrix
      `N (N^T W N + lam R)^-1 N^T W` (of the limit for `lam = 0` and `inf`).
    - `gcv`: the generalised cross-validation score `m residual / (m - dof)^2`; NaN for
      an interpolating curve (`dof = m`).
    """

    penalty: Array
    residual: Array
    dof: Array
    gcv: Array


class _Parts(NamedTuple):
    """The banded pieces of a smoothing problem with fixed knots."""

    span: Array  # knot span of each data parameter
    funs: Array  # the p + 1 non-zero basis functions there
    points: Array  # data points (m, dim)
    weights: Array  # weights of the squared errors (m,)
    gram: Array  # band of N^T W N, (n, 2p + 1), n control points unfolded
    rhs: Array  # N^T W Q, (n, dim)
    penalty: Array  # band of R, (n, 2p + 1)
    null: Array  # basis Z of R's null space: the polynomials of degree < r, (n, r); closed:
    # the constants, (n - p, 1) on the folded control points
    # In the variables of `_change_variables` (the same for every lam):
    gram_b: "_Bordered"
    penalty_b: "_Bordered"
    rhs_b: tuple[Array, Array]


@functools.partial(jax.jit, static_argnames=("degree", "order"))
def penalty_band(knots: Array, degree: int, order: int) -> Array:
    """The band of `R_ij = int N_i^(r) N_j^(r) du` over the domain `[knots[p], knots[n]]`
    (Gauss-Legendre with `p - r + 1` nodes per span: exact), shape `(n, 2p + 1)`."""
    n = knots.shape[0] - degree - 1
    nodes, node_weights = np.polynomial.legendre.leggauss(degree - order + 1)
    lo, hi = knots[degree:n], knots[degree + 1 : n + 1]
    u = (lo + hi)[:, None] / 2 + (hi - lo)[:, None] / 2 * jnp.asarray(nodes, knots.dtype)
    # A node of an empty span (lo == hi) falls into a neighbour, with zero quadrature weight.
    span, ders = ders_basis_funs(knots, degree, u, order)
    ders = ders[..., order, :]  # (spans, nodes, p + 1)
    scale = (hi - lo)[:, None] / 2 * jnp.asarray(node_weights, knots.dtype)
    local = jnp.einsum("sq,sqa,sqb->sqab", scale, ders, ders).reshape(-1, degree + 1)
    first = (span - degree).ravel()
    rows = (first[:, None] + jnp.arange(degree + 1)).ravel()
    return band_rows(rows, jnp.repeat(first, degree + 1), local, n, degree)


def _unit(u: Array, values: Array) -> Array:
    """`values` mapped as `[u[0], u[-1]]` to `[-1, 1]` (polynomials stay well conditioned)."""
    return (values - (u[0] + u[-1]) / 2) / ((u[-1] - u[0]) / 2)


def _monomial_controls(u: Array, knots: Array, degree: int, order: int) -> Array:
    """Control points of the monomials `s^k`, `k < order`, `s = _unit(u, u)`, shape `(n,
    order)`: the blossom of `s^k` in degree `p` at `knots[i+1 .. i+p]`, the elementary
    symmetric polynomial `e_k` of those (scaled) knots divided by `C(p, k)` (exact)."""
    n = knots.shape[0] - degree - 1
    scaled = _unit(u, knots)
    elementary = [jnp.ones(n, knots.dtype)] + [jnp.zeros(n, knots.dtype)] * (order - 1)
    for j in range(1, degree + 1):
        value = scaled[j : j + n]
        for k in range(order - 1, 0, -1):
            elementary[k] = elementary[k] + value * elementary[k - 1]
    return jnp.stack([elementary[k] / math.comb(degree, k) for k in range(order)], 1)


@functools.partial(jax.jit, static_argnames=("degree", "order", "closed"))
def _assemble(u, points, knots, weights, degree, order, closed) -> _Parts:
    n = knots.shape[0] - degree - 1
    span, funs = basis_funs(knots, degree, u)
    weighted = funs * weights[:, None]
    first = span - degree
    rows = (first[:, None] + jnp.arange(degree + 1)).ravel()
    gram = (weighted[:, :, None] * funs[:, None, :]).reshape(-1, degree + 1)
    gram = band_rows(rows, jnp.repeat(first, degree + 1), gram, n, degree)
    dim = points.shape[1]
    rhs = (
        jnp.zeros((n, dim), points.dtype)
        .at[rows]
        .add((weighted[:, :, None] * points[:, None, :]).reshape(-1, dim))
    )
    if closed:
        null = jnp.ones((n - degree, 1), knots.dtype)
    else:
        null = _monomial_controls(u, knots, degree, order)
    penalty = penalty_band(knots, degree, order)
    return _Parts(
        span,
        funs,
        points,
        weights,
        gram,
        rhs,
        penalty,
        null,
        _change_variables(gram, null, closed, coupled=True),
        _change_variables(penalty, null, closed, coupled=False),
        _change_rhs(rhs, null, closed),
    )


def _band_entries(band: Array, i: Array, j: Array) -> Array:
    """`A[i, j]` of a band matrix for index arrays, zero outside the band."""
    half = (band.shape[1] - 1) // 2
    offset = j - i + half
    inside = (offset >= 0) & (offset <= 2 * half)
    return jnp.where(inside, band[i, jnp.clip(offset, 0, 2 * half)], 0.0)


def _band_matmul(band: Array, x: Array) -> Array:
    """`A @ x` for a band matrix `A` (as `band_rows` stores it) and a matrix `x`."""
    half = (band.shape[1] - 1) // 2
    padded = jnp.pad(x, ((half, half), (0, 0)))
    n = band.shape[0]
    return sum(band[:, j, None] * padded[j : j + n] for j in range(2 * half + 1))


class _Bordered(NamedTuple):
    """A symmetric system `[[A11, A12], [A12^T, A22]]`: `A11` banded, `k` dense columns."""

    band11: Array
    a12: Array
    a22: Array


def _split_periodic(band: Array, n: int) -> _Bordered:
    """Fold the band of an unfolded system (`n + p` control points, the last `p` equal to
    the first `p`) into the periodic `n x n` system, bordered by the `p` shared ones."""
    half = (band.shape[1] - 1) // 2
    rows = jnp.arange(half, n)
    columns = rows[:, None] - half + jnp.arange(2 * half + 1)
    band11 = jnp.where((columns >= half) & (columns < n), band[half:n], 0.0)
    i, j = rows[:, None], jnp.arange(half)[None, :]
    a12 = _band_entries(band, i, j) + _band_entries(band, i, j + n)
    i, j = jnp.arange(half)[:, None], jnp.arange(half)[None, :]
    a22 = sum(_band_entries(band, i + a, j + b) for a in (0, n) for b in (0, n))
    return _Bordered(band11, a12, a22)


def _pinned(n: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The `k` control points of an open curve traded for the null space's coefficients,
    spread from end to end (a polynomial's control points follow its values, so one of
    degree < k cannot vanish at all of them: `B^T R B` is positive definite), and the
    others."""
    pinned = np.round(np.linspace(0, n - 1, k)).astype(int)
    return pinned, np.setdiff1d(np.arange(n), pinned)


def _change_variables(band: Array, null: Array, closed: bool, coupled: bool) -> _Bordered:
    """A symmetric band matrix `A` (unfolded control points) in the variables `(c, d)` of
    `P = B c + Z d`, `Z = null` and `B` the unit columns of all control points but `k`
    pinned ones (`k` the columns of `Z`): `[[B^T A B, B^T A Z], [Z^T A B, Z^T A Z]]`.

    The penalty matrix `R` annihilates `Z` (the polynomials of degree < r), but its
    computed entries do so only to rounding, `eps |R|`, which `lam` multiplies: in the
    normal equations `(N^T W N + lam R) P = N^T W Q` the polynomial part of the fit is lost
    once `eps lam |R|` approaches `|N^T W N|` (`lam ~ 1e5` for cubics through 40 points).
    Here `R` enters as `B^T R B` alone, its coupling to `Z` set to zero (`coupled=False`)
    rather than computed; `B^T R B` is positive definite, so `lam` scales a well-posed
    block whose solution `c` shrinks like `1 / lam`, while `d` comes from the data alone.

    An open curve pins `k = r` control points (`_pinned`); a closed one the first of its
    `p` shared control points (`Z` = the constants), and `d` joins the dense border.
    """
    if not closed:
        half = (band.shape[1] - 1) // 2
        _, kept = _pinned(band.shape[0], null.shape[1])
        # The band of B^T A B: dropping rows and columns keeps the band.
        columns = np.arange(kept.size)[:, None] - half + np.arange(2 * half + 1)
        inside = (columns >= 0) & (columns < kept.size)
        band11 = _band_entries(band, kept[:, None], kept[np.clip(columns, 0, kept.size - 1)])
        band11 = jnp.where(inside, band11, 0.0)
        if not coupled:
            k = null.shape[1]  # R Z = 0 exactly
            zeros = jnp.zeros((kept.size + k, k), band.dtype)
            return _Bordered(band11, zeros[: kept.size], zeros[kept.size :])
        product = _band_matmul(band, null)
        return _Bordered(band11, product[kept], null.T @ product)
    half = (band.shape[1] - 1) // 2
    system = _split_periodic(band, band.shape[0] - half)
    if not coupled:
        a12 = jnp.pad(system.a12[:, 1:], ((0, 0), (0, 1)))
        return _Bordered(system.band11, a12, jnp.pad(system.a22[1:, 1:], ((0, 1), (0, 1))))
    # A Z for Z = ones: the row sums of the folded matrix.
    sums1 = jnp.sum(system.band11, axis=1) + jnp.sum(system.a12, axis=1)
    sums2 = jnp.sum(system.a12, axis=0) + jnp.sum(system.a22, axis=1)
    a12 = jnp.concatenate([system.a12[:, 1:], sums1[:, None]], axis=1)
    corner = jnp.sum(sums1) + jnp.sum(sums2)
    a22 = jnp.block([[system.a22[1:, 1:], sums2[1:, None]], [sums2[None, 1:], corner[None, None]]])
    return _Bordered(system.band11, a12, a22)


def _change_rhs(rhs: Array, null: Array, closed: bool) -> tuple[Array, Array]:
    """`(B^T b, Z^T b)` for a right-hand side `b` of the unfolded control points."""
    if not closed:
        _, kept = _pinned(rhs.shape[0], null.shape[1])
        return rhs[kept], null.T @ rhs
    half = rhs.shape[0] - null.shape[0]
    shared = rhs[:half] + rhs[rhs.shape[0] - half :]
    rest = rhs[half : rhs.shape[0] - half]
    total = jnp.sum(shared, axis=0) + jnp.sum(rest, axis=0)
    return rest, jnp.concatenate([shared[1:], total[None]])


def _control(x1: Array, x2: Array, null: Array, closed: bool) -> Array:
    """The unfolded control points `P = B c + Z d` from `x1 = c` and `x2` (`d` last)."""
    if not closed:
        _, kept = _pinned(null.shape[0], null.shape[1])
        return jnp.zeros((null.shape[0], x1.shape[1]), x1.dtype).at[kept].set(x1) + null @ x2
    d = x2[-1]
    folded = jnp.concatenate([d[None], x2[:-1] + d, x1 + d])
    half = x2.shape[0]
    return jnp.concatenate([folded, folded[:half]])


def _solve_bordered(system: _Bordered, factors, rhs1: Array, rhs2: Array):
    """`(x1, x2)` solving the bordered system, and `(X, S)`: `X = A11^-1 A12` and the Schur
    complement `S = A22 - A12^T X` (for the trace of the inverse).

    `factors` is `_ldl(A11)`: `A11` is a principal block of a positive definite matrix, so
    its factorisation needs no pivoting; the `k x k` complement is solved densely.
    """
    y = _ldl_solve(*factors, jnp.concatenate([rhs1, system.a12], axis=1))
    y1, x12 = y[:, : rhs1.shape[1]], y[:, rhs1.shape[1] :]
    schur = system.a22 - system.a12.T @ x12
    x2 = jnp.linalg.solve(schur, rhs2 - system.a12.T @ y1)
    return y1 - x12 @ x2, x2, (x12, schur)


def _ldl(band: Array) -> tuple[Array, Array]:
    """`A = L D L^T` for a symmetric positive definite band matrix of half-bandwidth `h`
    (no pivoting): `lower[i, a] = L[i, i - h + a]`, `a < h`, and `diag[i] = D[i]`."""
    h = (band.shape[1] - 1) // 2

    def factor(carry, row):
        # prev_l[a] holds L[i - h + a, i - 2h + a .. i - h + a - 1], prev_d[a] = D[i - h + a]
        prev_l, prev_d = carry
        l_row = []
        for a in range(h):
            total = row[a] - sum(l_row[b] * prev_l[a, b - a + h] * prev_d[b] for b in range(a))
            l_row.append(total / prev_d[a])
        l_row = jnp.stack(l_row)
        d = row[h] - jnp.sum(l_row**2 * prev_d)
        carry = (jnp.concatenate([prev_l[1:], l_row[None]]), jnp.concatenate([prev_d[1:], d[None]]))
        return carry, (l_row, d)

    # Identity rows stand in above the matrix (the band holds zeros to eliminate there).
    start = (jnp.zeros((h, h), band.dtype), jnp.ones(h, band.dtype))
    _, (lower, diag) = jax.lax.scan(factor, start, band)
    return lower, diag


def _lower_columns(lower: Array) -> Array:
    """`lcol[i, k - 1] = L[i + k, i]`, `k = 1..h` (stored at `lower[i + k, h - k]`; zero
    below the matrix)."""
    n, h = lower.shape
    padded = jnp.pad(lower, ((0, h), (0, 0)))
    return jnp.stack([padded[k : n + k, h - k] for k in range(1, h + 1)], axis=1)


def _ldl_solve(lower: Array, diag: Array, rhs: Array) -> Array:
    """`A^-1 rhs` from `_ldl(A)`: forward substitution with `L`, then `D`, then `L^T`."""
    h = lower.shape[1]

    def forward(window, inputs):  # window[a] = y[i - h + a]
        row, b = inputs
        y = b - row @ window
        return jnp.concatenate([window[1:], y[None]]), y

    start = jnp.zeros((h, rhs.shape[1]), rhs.dtype)
    _, y = jax.lax.scan(forward, start, (lower, rhs))

    def backward(window, inputs):  # window[k - 1] = x[i + k]
        column, z = inputs
        x = z - column @ window
        return jnp.concatenate([x[None], window[:-1]]), x

    _, x = jax.lax.scan(backward, start, (_lower_columns(lower), y / diag[:, None]), reverse=True)
    return x


def _inverse_band(band: Array, factors: tuple[Array, Array] | None = None) -> Array:
    """The entries `Sigma[i, i + d]`, `d = 0..h`, of the inverse of a symmetric positive
    definite band matrix of half-bandwidth `h`, shape `(n, h + 1)` (`factors`: its `_ldl`
    if already known).

    From `A = L D L^T` (`L` unit lower triangular with the band of `A`), `Sigma = A^-1`
    satisfies `Sigma = D^-1 L^-1 + (I - L^T) Sigma`, whose upper triangle within the band
    is found row by row from the bottom from the band alone (Hutchinson and de Hoog 1985):
    `Sigma[i, i + j] = -sum_k L[i + k, i] Sigma[i + k, i + j]`, `k = 1..h`, and
    `Sigma[i, i] = 1 / D[i] - sum_k L[i + k, i] Sigma[i, i + k]`.
    """
    h = (band.shape[1] - 1) // 2
    lower, diag = _ldl(band) if factors is None else factors
    lcol = _lower_columns(lower)

    def invert(window, inputs):
        # window[a, d] = Sigma[i + 1 + a, i + 1 + a + d]
        column, d = inputs
        upper = [
            -sum(column[k - 1] * window[min(k, j) - 1, abs(j - k)] for k in range(1, h + 1))
            for j in range(1, h + 1)
        ]
        diagonal = 1 / d - sum(column[k - 1] * upper[k - 1] for k in range(1, h + 1))
        row = jnp.stack([diagonal, *upper])
        return jnp.concatenate([row[None], window[:-1]]), row

    _, sigma = jax.lax.scan(invert, jnp.zeros((h, h + 1), band.dtype), (lcol, diag), reverse=True)
    return sigma


def _trace_band(sigma: Array, band: Array) -> Array:
    """`tr(Sigma M)` for symmetric `Sigma` (its upper band as `_inverse_band` returns it) and
    a symmetric band matrix `M` of the same half-bandwidth."""
    h = sigma.shape[1] - 1
    return jnp.sum(sigma[:, 0] * band[:, h]) + 2 * jnp.sum(sigma[:, 1:] * band[:, h + 1 :])


def _fit(parts: _Parts, lam: Array, closed: bool, dof: bool):
    """Control points (unfolded) of the penalised fit with weight `lam`, and with `dof` the
    trace of the hat matrix, `tr((N^T W N + lam R)^-1 N^T W N)` (else None)."""
    gram = parts.gram_b
    system = jax.tree.map(lambda g, r: g + lam * r, gram, parts.penalty_b)
    factors = _ldl(system.band11)
    x1, x2, (x12, schur) = _solve_bordered(system, factors, *parts.rhs_b)
    control = _control(x1, x2, parts.null, closed)
    if not dof:
        return control, None
    # The trace is invariant under the change of variables. With X = A11^-1 A12 and S the
    # Schur complement, the inverse of the bordered matrix is [[A11^-1 + X S^-1 X^T,
    # -X S^-1], [-S^-1 X^T, S^-1]], whose trace against M (bordered alike) is below.
    inner = x12.T @ _band_matmul(gram.band11, x12) - 2 * x12.T @ gram.a12 + gram.a22
    trace = _trace_band(_inverse_band(system.band11, factors), gram.band11) + jnp.trace(
        jnp.linalg.solve(schur, inner)
    )
    return control, trace


def _residual(parts: _Parts, control: Array, degree: int) -> Array:
    fitted = combine_local(parts.funs, control, parts.span, degree)
    return jnp.sum(parts.weights * jnp.sum((fitted - parts.points) ** 2, axis=-1))


def _gcv(residual: Array, dof: Array, weights: Array) -> Array:
    """`m residual / (m - dof)^2`, `m` the number of points of positive weight."""
    count = jnp.sum(weights > 0).astype(residual.dtype)
    return count * residual / (count - dof) ** 2


@functools.partial(jax.jit, static_argnames=("degree", "closed"))
def _statistics(parts: _Parts, lam: Array, degree: int, closed: bool):
    """`(residual, dof, gcv)` of the fit with weight `lam` (the lam search's objective)."""
    control, dof = _fit(parts, lam, closed, dof=True)
    residual = _residual(parts, control, degree)
    return residual, dof, _gcv(residual, dof, parts.weights)


@functools.partial(jax.jit, static_argnames=("degree", "closed", "stats"))
def _penalised(parts: _Parts, lam: Array, degree: int, closed: bool, stats: bool):
    control, dof = _fit(parts, lam, closed, dof=stats)
    if not stats:
        return control, None
    residual = _residual(parts, control, degree)
    return control, (residual, dof, _gcv(residual, dof, parts.weights))


@functools.partial(jax.jit, static_argnames=("degree", "stats"))
def _interpolation_limit(parts: _Parts, degree: int, stats: bool):
    """The `lam -> 0` limit with knots at every parameter of an open curve: the interpolant
    with the least penalty (for `p = 2r - 1` the natural spline).

    There are `m + p - 1` control points for `m` conditions `C(u_k) = Q_k`. `p - 1` of
    them are left free (`a`): `(p - 1) // 2` next to the start, the others next to the
    end, so that each condition pairs with a basis function centred on its parameter (as
    with clamped end conditions; leaving them all at one end would make the banded solve
    march like an initial-value problem, with errors growing exponentially). The others
    follow from the conditions by a banded solve of a collocation matrix, `P(a) = P0 + Z a`,
    and `a` minimises `P(a)^T R P(a)` (a `(p - 1) x (p - 1)` system).
    """
    n, count = parts.gram.shape[0], parts.points.shape[0]
    start = (degree - 1) // 2
    free = np.concatenate([np.arange(1, start + 1), np.arange(n - degree + start, n - 1)])
    fixed = np.setdiff1d(np.arange(n), free)  # one per condition, in order
    position = np.full(n, -1)
    position[fixed] = np.arange(count)
    columns = parts.span[:, None] - degree + jnp.arange(degree + 1)
    is_fixed = jnp.asarray(position)[columns] >= 0
    # Row k of the collocation matrix on the fixed unknowns, placed at their positions.
    rows = jnp.broadcast_to(jnp.arange(count)[:, None], columns.shape)
    offsets = jnp.where(is_fixed, jnp.asarray(position)[columns] - rows + degree, 0)
    band = jnp.zeros((count, 2 * degree + 1), parts.funs.dtype)
    band = band.at[rows, offsets].add(jnp.where(is_fixed, parts.funs, 0.0))
    if free.size == 0:  # degree 1: as many control points as conditions
        control = solve_banded(band, parts.points)
        residual = _residual(parts, control, degree)
        return control, (residual, jnp.asarray(count, residual.dtype), jnp.asarray(jnp.nan))
    free_columns = jnp.stack(
        [jnp.sum(jnp.where(columns == c, parts.funs, 0.0), axis=1) for c in free], axis=1
    )
    solved = solve_banded(band, jnp.concatenate([parts.points, free_columns], axis=1))
    dim = parts.points.shape[1]
    base = jnp.zeros((n, dim), parts.points.dtype).at[fixed].set(solved[:, :dim])
    basis = jnp.zeros((n, free.size), parts.points.dtype).at[fixed].set(-solved[:, dim:])
    basis = basis.at[free, np.arange(free.size)].set(1.0)
    r_basis = _band_matmul(parts.penalty, basis)
    a = jnp.linalg.solve(basis.T @ r_basis, -r_basis.T @ base)
    control = base + basis @ a
    if not stats:
        return control, None
    residual = _residual(parts, control, degree)
    return control, (residual, jnp.asarray(count, residual.dtype), jnp.asarray(jnp.nan))


@functools.partial(jax.jit, static_argnames=("degree", "order", "closed"))
def _polynomial_limit(u, parts: _Parts, degree: int, order: int, closed: bool):
    """The `lam -> inf` limit: the weighted least-squares polynomial of degree `< r` (a
    periodic spline: the weighted mean), and `(residual, dof, gcv)`.

    Its control points are those of the monomials (`parts.null`) times its coefficients.
    """
    weights, points = parts.weights, parts.points
    n = parts.gram.shape[0]
    if closed:
        mean = weights @ points / jnp.sum(weights)
        control = jnp.broadcast_to(mean, (n, points.shape[1]))
        dof = jnp.asarray(1.0, points.dtype)
    else:
        root = jnp.sqrt(weights)[:, None]
        vandermonde = _unit(u, u)[:, None] ** jnp.arange(order)
        coefficients = jnp.linalg.lstsq(root * vandermonde, root * points)[0]
        control = parts.null @ coefficients
        dof = jnp.asarray(float(order), points.dtype)
    residual = _residual(parts, control, degree)
    return control, (residual, dof, _gcv(residual, dof, weights))


def _knots(u: Array, n_control: int | None, degree: int, closed: bool) -> Array:
    """Knots at every parameter (`n_control=None`) or `n_control` spans holding data."""
    if closed:
        if n_control is not None:
            # n_control + 1 breaks spread over the parameters, then continued periodically.
            m = u.shape[0] - 1
            u = jnp.interp(np.linspace(0.0, m, n_control + 1), np.arange(m + 1), u)
        return periodic_knots(u, degree)
    if n_control is not None:
        return approximation_knots(u, n_control, degree)
    return jnp.concatenate([jnp.repeat(u[:1], degree), u, jnp.repeat(u[-1:], degree)])


def _abscissae(x: ArrayLike, count: int, dtype, closed: bool) -> Array:
    x = jnp.asarray(x)
    expected = count + closed
    if x.shape != (expected,):
        raise ValueError(
            f"x must be a 1-D array of {expected} abscissae "
            f"({'one per value and one closing the period' if closed else 'one per value'}), "
            f"got shape {x.shape}"
        )
    x = check_finite(x.astype(dtype), "x")
    values = concrete(x)
    if values is not None and np.any(np.diff(values) <= 0):
        k = int(np.argmax(np.diff(values) <= 0))
        raise ValueError(
            f"x must increase strictly, got x[{k}] = {values[k]} >= x[{k + 1}] = {values[k + 1]}"
        )
    return x


def _check_number(value, name: str):
    """A concrete number `>= 0`; a traced one is checked when the program runs."""
    if value is None:
        return None
    value = jnp.asarray(value)
    if value.ndim != 0:
        raise ValueError(f"{name} must be a number, got shape {value.shape}")
    concrete_value = concrete(value)
    if concrete_value is None:
        return eqx.error_if(value, ~(jnp.isfinite(value) & (value >= 0)), f"{name} must be >= 0")
    if not (np.isfinite(concrete_value) and concrete_value >= 0):
        raise ValueError(f"{name} must be a finite number >= 0, got {concrete_value}")
    return value


def _choose_by_residual(statistics, target: float, scale: float, max_steps: int) -> float:
    """`lam` with `residual(lam) = target` (the residual rises with `lam`): a bracket in
    decades from `scale`, then Brent's method on `log lam`."""

    def excess(log_lam):
        return float(statistics(np.exp(log_lam))[0]) - target

    lo = hi = math.log(scale)
    for _ in range(_BRACKET_DECADES):
        if excess(lo) <= 0:
            break
        lo -= math.log(10.0)
    else:
        return math.exp(lo)  # the target is within rounding of the interpolating residual
    for _ in range(_BRACKET_DECADES):
        if excess(hi) >= 0:
            break
        hi += math.log(10.0)
    if lo == hi:
        return math.exp(lo)
    log_lam = scipy.optimize.brentq(excess, lo, hi, xtol=1e-13, rtol=1e-15, maxiter=max_steps)
    return math.exp(log_lam)


def _choose_by_gcv(statistics, start: float, order: int, limits, max_steps: int):
    """`lam` minimising the GCV score: the best of a grid in `log lam`, refined by Brent's
    method between its neighbours.

    The grid runs from `start` in steps of `2 r log 2` in `log lam` (the dof halve or
    double), down until `dof` is within 0.01 of its `lam -> 0` limit or fewer than one
    degree of freedom is left to the residual (`m - dof < 1`: towards interpolation GCV is
    0/0 and its rounding error grows without bound), and up until `dof` is within 0.01 of
    its `lam -> inf` limit (the polynomial); beyond both GCV no longer changes. `limits =
    (floor, ceiling, m)`: those two limits of `dof` and the number of weighted points.
    """
    floor, ceiling, count = limits
    step = 2 * order * math.log(_GCV_DOF_RATIO)

    def score(log_lam):
        _, dof, value = (float(v) for v in statistics(math.exp(log_lam)))
        usable = count - dof >= 1 and np.isfinite(value)
        return (value if usable else np.inf), dof

    start = math.log(start)
    samples = {start: score(start)}
    for direction in (-1, 1):
        g = start
        for _ in range(int(_BRACKET_DECADES * math.log(10.0) / step)):
            dof = samples[g][1]
            if direction < 0 and (count - dof < 1 or dof > ceiling - 0.01):
                break
            if direction > 0 and dof < floor + 0.01:
                break
            g += direction * step
            samples[g] = score(g)
    grid = np.array(sorted(samples))
    scores = np.array([samples[g][0] for g in grid])
    if not np.any(np.isfinite(scores)):
        raise ValueError(
            "GCV found no penalty that leaves the residual a degree of freedom; "
            "give smoothing or penalty"
        )
    best = int(np.argmin(scores))
    bounds = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    # To 0.1% in lam: GCV is flat at its minimum (a change of 1e-3 in lam moves the curve
    # by far less than the data's noise), and its rounding error, ~1e-9 of its value at
    # 10^5 points, would keep a tighter search wandering. Unusable scores (inf) become a
    # finite worst value, which keeps Brent's parabolic steps finite.
    worst = 2 * np.max(scores[np.isfinite(scores)])
    found = scipy.optimize.minimize_scalar(
        lambda g: min(score(g)[0], worst),
        bounds=bounds,
        method="bounded",
        options={"xatol": 1e-3, "maxiter": max_steps},
    )
    return math.exp(found.x if found.fun <= scores[best] else grid[best])


def smooth(
    points: ArrayLike,
    n_control: int | None = None,
    degree: int = 3,
    smoothing: float | None = None,
    penalty_order: int = 2,
    parametrization="centripetal",
    weights: ArrayLike | None = None,
    *,
    closed: bool = False,
    x: ArrayLike | None = None,
    penalty: ArrayLike | None = None,
    max_steps: int = 100,
    full_output: bool = False,
) -> NURBSCurve | tuple[NURBSCurve, SmoothingReport]:
    """Smoothing spline: the B-spline curve minimising `sum_k w_k |C(u_k) - Q_k|^2 +
    lam int |C^(r)(u)|^2 du` over its control points, with fixed knots.

    With knots at every data parameter (`n_control=None`), `r = 2` and `p = 3` this is the
    classical cubic smoothing spline, the minimiser over all functions (a natural cubic
    spline), the same as scipy's `make_smoothing_spline(x, y, w, lam)` with the same `lam`.
    With `n_control` the knots follow `approximation_knots` (penalised regression splines,
    like P-splines with the exact integral penalty).

    The weight `lam` is `penalty` when given; otherwise chosen on the data: with
    `smoothing = s` so that the weighted residual equals `s` (splprep's `s`; `s` at or
    below the residual of `lam = 0` gives `lam = 0`, `s` at or above the residual of the
    polynomial limit gives that limit), else by minimising the generalised
    cross-validation score `m residual / (m - tr H)^2`. Either choice runs on concrete
    data in NumPy/SciPy; `lam` is then a constant of the data: to differentiate with
    respect to the data, choose `lam` once (`full_output=True`) and pass it as `penalty`.
    Parameters computed from noisy points (chord, centripetal) carry the noise, and GCV
    then keeps most of it; give known parameters (`x`) or use `smoothing` for curves.

    `lam = 0` is plain least squares with `n_control`, and with knots at every parameter
    the interpolant with the least penalty (for `p = 2r - 1` the natural spline; a closed
    curve: `interpolate(..., closed=True)`). `lam -> inf` tends to the weighted
    least-squares polynomial of degree `< r` (a closed curve: the weighted mean); the
    solve keeps that limit accurate for any finite `lam` (the distance to it falls as
    `1 / lam`), also with knots at every point. Rounding grows with the conditioning of
    the penalty, `~ m^(2r)` with knots at every point: for `r = 2` at `m = 10^5` the curve
    is good to ~1e-9 and the reported `dof` to ~1e-2 at `lam >= 1e8`.

    **Arguments:**

    - `points`: array `(m, dim)`; with `x`, also `(m,)` function values.
    - `n_control`: None for knots at every data parameter, or the number of control
      points, `degree + 1 <= n_control <= m` (of one period when closed).
    - `degree`: the degree `p`.
    - `smoothing`: the target residual `s >= 0`, or None for GCV; giving both `smoothing`
      and `penalty` is a `ValueError`.
    - `penalty_order`: the derivative order `r` penalised, `1 <= r <= p`.
    - `parametrization`: a method name (see `parametrize`) or increasing parameters (`m`,
      or `m + 1` when closed, as in `interpolate`).
    - `weights`: optional `m` non-negative weights of the squared errors.
    - `closed`: a periodic curve (the points without the first repeated at the end),
      `C^(p-1)` at the seam, the penalty integrated over the whole period.
    - `x`: abscissae of a function `y(x)`: the parameters (instead of `parametrization`),
      increasing, `m` of them (`m + 1` when closed: the end of the period).
    - `penalty`: the weight `lam >= 0`, given directly.
    - `max_steps`: limit of the root find or of the GCV minimisation.
    - `full_output`: also return a `SmoothingReport`.

    **Returns:**

    A non-rational `NURBSCurve` (control points `(n, 1)` for 1-D values, as
    `fit_function` returns, so `curve(x)[..., 0]` is the function); with `full_output`,
    `(curve, report)`. With `penalty` given everything is array code: `jax.grad` reaches
    `points`, `x` (or given parameters), `weights` and `penalty`, also inside `jit`.
    Choosing `lam` (`smoothing` or GCV) needs concrete inputs. Costs O(m p^2) per solve.
    """
    degree = check_degree(degree)
    order = check_degree(penalty_order, name="penalty_order")
    if order > degree:
        raise ValueError(f"penalty_order must be in 1 .. degree = {degree}, got {order}")
    if not isinstance(closed, bool):
        raise ValueError(f"closed must be True or False, got {closed!r}")
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise ValueError(f"max_steps must be a positive Python int, got {max_steps!r}")
    points = jnp.asarray(points)
    if x is not None and points.ndim == 1:
        points = points[:, None]
    elif points.ndim == 1:
        raise ValueError(
            f"points of shape {points.shape} are function values: give their abscissae x"
        )
    points = _data_points(points)
    m = points.shape[0]
    check_control_count(m, degree, "points")
    if n_control is not None:
        if isinstance(n_control, bool) or not isinstance(n_control, (int, np.integer)):
            raise ValueError(f"n_control must be None or a Python int, got {n_control!r}")
        check_control_count(int(n_control), degree, at_most=m)
        n_control = int(n_control)
    if penalty is not None and smoothing is not None:
        raise ValueError("give either smoothing (a target residual) or penalty, not both")
    lam = _check_number(penalty, "penalty")
    smoothing = _check_number(smoothing, "smoothing")
    if x is not None:
        u = _abscissae(x, m, points.dtype, closed)
    else:
        u = _parameters(points, parametrization, closed)
    weights = jnp.ones(m, points.dtype) if weights is None else _point_weights(weights, m)
    knots = _knots(u, n_control, degree, closed)
    parts = _assemble(u[:m], points, knots, weights.astype(points.dtype), degree, order, closed)
    interpolating = n_control is None and not closed

    def fit(lam_value, stats):
        if interpolating and concrete(lam_value) is not None and float(lam_value) == 0:
            values = concrete(weights)
            if values is not None and np.any(values == 0):
                raise ValueError(
                    "penalty 0 with knots at every parameter interpolates every point; "
                    "zero weights are then meaningless (use penalty > 0 or n_control)"
                )
            return _interpolation_limit(parts, degree, stats)
        return _penalised(parts, lam_value, degree, closed, stats)

    if lam is None:
        if any(concrete(a) is None for a in (points, u, weights)):
            raise ValueError(
                "choosing the penalty (smoothing or GCV) needs concrete inputs; inside "
                "jit or grad pass penalty= (e.g. report.penalty from full_output=True)"
            )
        lam = _choose(
            parts, u, knots, degree, order, closed, n_control is None, smoothing, max_steps, fit
        )
    if isinstance(lam, str):  # the polynomial limit
        control, stats = _polynomial_limit(u, parts, degree, order, closed)
        lam = jnp.asarray(jnp.inf, points.dtype)
    else:
        lam = jnp.asarray(lam, points.dtype)
        control, stats = fit(lam, full_output)
    curve = NURBSCurve(check_solved(control), degree, knots)
    if not full_output:
        return curve
    if stats is None:
        stats = _polynomial_limit(u, parts, degree, order, closed)[1]
    residual, dof, gcv = stats
    return curve, SmoothingReport(penalty=lam, residual=residual, dof=dof, gcv=gcv)


def _choose(parts, u, knots, degree, order, closed, at_every, smoothing, max_steps, fit):
    """`lam` for a target residual or by GCV, or `"polynomial"` for the `lam -> inf` limit."""
    # Where the dof is about sqrt(m): on a period L with total weight W, the penalty damps
    # the Fourier mode of frequency k by 1 / (1 + lam (2 pi k / L)^(2r) L / W), so the
    # dof, twice the number of modes kept, are about (L / pi) (W / (L lam))^(1 / 2r).
    count = float(jnp.sum(parts.weights > 0))
    length = float(u[-1] - u[0])
    dof = max(math.sqrt(count), order + 1.0)
    scale = float(jnp.sum(parts.weights)) / length * (length / (math.pi * dof)) ** (2 * order)

    def statistics(lam):
        return _statistics(parts, jnp.asarray(lam, parts.points.dtype), degree, closed)

    if smoothing is None:
        floor = 1.0 if closed else float(order)
        ceiling = min(count, float(parts.gram_b.band11.shape[0] + parts.gram_b.a22.shape[0]))
        return _choose_by_gcv(statistics, scale, order, (floor, ceiling, count), max_steps)
    target = float(smoothing)
    # With knots at every parameter lam = 0 interpolates (the residual is zero).
    zero = jnp.asarray(0.0, parts.points.dtype)
    least = 0.0 if at_every else float(fit(zero, True)[1][0])
    if target <= least:
        return 0.0
    most = float(_polynomial_limit(u, parts, degree, order, closed)[1][0])
    if target >= most:
        return "polynomial"
    return _choose_by_residual(statistics, target, scale, max_steps)
