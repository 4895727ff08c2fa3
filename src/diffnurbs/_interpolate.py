"""Global interpolation and least-squares approximation of points by B-spline curves and
surfaces (NURBS Book A9.1, A9.4, A9.7).

Every construction is a chain of array operations (parameters, knots, basis functions, a
banded solve), so `jax.grad` of anything computed from the result reaches the data points,
and the functions work on traced points. Degrees, counts, the parametrization name and the
flags (`closed`, `interpolate_ends`, whether end derivatives are given) shape the linear
system, so they must be concrete Python values. Checks that need values (coincident points,
NaNs, parameters and knots that do not fit) run when the inputs are concrete.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from ._banded import band_rows, collocation_solve, solve_banded
from ._basis import basis_funs, basis_matrix
from ._curve import NURBSCurve
from ._knots import (
    approximation_knots,
    averaged_knots,
    check_distinct_parameters,
    check_parametrization,
    chord_steps,
    normalized_cumsum,
    parametrize,
    periodic_knots,
)
from ._surface import NURBSSurface
from ._validate import (
    check_control_count,
    check_degree,
    check_degree_pair,
    check_finite,
    check_knots,
    check_pair,
    check_rank,
    concrete,
    float_dtype,
)


def _data_points(points: ArrayLike, name: str = "points") -> Array:
    points = jnp.asarray(points)
    check_rank(points, 2, name, "(n_points, dim)")
    return check_finite(points.astype(float_dtype(points)), name)


def _parameters(points: Array, parametrization, closed: bool = False) -> Array:
    """Parameters from a method name, or given ones checked (increasing, one per point)."""
    if isinstance(parametrization, str):
        return parametrize(points, parametrization, closed)
    u = check_finite(jnp.asarray(parametrization, dtype=points.dtype), "parametrization")
    expected = points.shape[0] + closed
    if u.shape != (expected,):
        raise ValueError(
            f"parametrization must be a method name or {expected} parameters "
            f"({'one per point and one closing the loop' if closed else 'one per point'}), "
            f"got shape {u.shape}"
        )
    values = concrete(u)
    if values is not None and np.any(np.diff(values) <= 0):
        k = int(np.argmax(np.diff(values) <= 0))
        raise ValueError(
            f"parameters must increase strictly, got u[{k}] = {values[k]} >= "
            f"u[{k + 1}] = {values[k + 1]}"
        )
    return u


def interpolate(
    points: ArrayLike,
    degree: int = 3,
    parametrization="centripetal",
    *,
    start_derivative: ArrayLike | None = None,
    end_derivative: ArrayLike | None = None,
    closed: bool = False,
) -> NURBSCurve:
    """The B-spline curve through all the points (global interpolation, NURBS Book A9.1).

    Open curves get clamped knots by averaging the parameters (eq. 9.8), so the matrix is
    banded and nonsingular, and the solve costs O(m). Each end derivative given adds a
    control point and an equation (eq. 9.21-9.22); it is the derivative with respect to the
    curve parameter, so its length should match the parametrization (the book suggests the
    total chord length times a unit tangent, the parameter running over [0, 1]).

    A closed curve (`closed=True`) is a periodic spline: the points, without the first
    repeated at the end, are interpolated at parameters that also step back from the last
    point to the first; the knots continue periodically (`periodic_knots`) and the last
    `degree` control points repeat the first ones, so the curve closes with `C^(p-1)`
    continuity and starts at the first point. Its cyclic system is solved densely (O(m^3)).

    **Arguments:**

    - `points`: array of shape `(m, dim)`, `m >= degree + 1`.
    - `degree`: the degree `p >= 1` (`>= 2` with end derivatives).
    - `parametrization`: `"uniform"`, `"chord"`, `"centripetal"` (see `parametrize`), or
      an increasing array of parameters, `m` of them (`m + 1` when closed); they become the
      domain.
    - `start_derivative`, `end_derivative`: optional vectors of length `dim`, `C'` at the
      ends of an open curve.
    - `closed`: periodic interpolation of a closed loop.

    **Returns:**

    A non-rational `NURBSCurve` with `C(u_k) = Q_k`. Works on traced points, derivatives
    and parameters (inside `jit` or `grad`); `degree`, `closed`, a method name and whether
    each derivative is given must be concrete.
    """
    degree = check_degree(degree)
    points = _data_points(points)
    check_control_count(points.shape[0], degree, "points")
    if closed:
        if start_derivative is not None or end_derivative is not None:
            raise ValueError("end derivatives apply to open curves only, got closed=True")
        return _interpolate_closed(points, degree, parametrization)
    u = _parameters(points, parametrization)
    start, end = (
        None if d is None else _derivative(d, points.shape[1], name)
        for d, name in ((start_derivative, "start_derivative"), (end_derivative, "end_derivative"))
    )
    if degree == 1 and (start is not None or end is not None):
        raise ValueError("end derivatives need degree >= 2 (a polyline has no free tangent)")
    control, knots = _open_interpolation(u, points, start, end, degree)
    return NURBSCurve(control, degree, knots)


@functools.partial(jax.jit, static_argnames="degree")
def _open_interpolation(u, points, start, end, degree):
    """`(control points, knots)` of the open interpolant, end derivatives optional."""
    sites, orders, rhs = [u], [np.zeros(points.shape[0], int)], [points]
    if start is not None:  # the row C'(u_0) = D_0 goes second, next to C(u_0) = Q_0
        sites = [u[:1], u[:1], u[1:]]
        orders = [np.zeros(1, int), np.ones(1, int), orders[0][1:]]
        rhs = [points[:1], start[None], points[1:]]
    if end is not None:  # C'(u_m) = D_m goes second to last
        sites = [*sites[:-1], sites[-1][:-1], u[-1:], u[-1:]]
        orders = [*orders[:-1], orders[-1][:-1], np.ones(1, int), np.zeros(1, int)]
        rhs = [*rhs[:-1], rhs[-1][:-1], end[None], points[-1:]]
    sites, orders, rhs = jnp.concatenate(sites), np.concatenate(orders), jnp.concatenate(rhs)
    # A derivative condition counts as one more site at its end (eq. 9.21-9.22).
    knots = averaged_knots(sites, degree)
    return collocation_solve(sites, orders, knots, degree, rhs), knots


def _derivative(value: ArrayLike, dim: int, name: str) -> Array:
    value = jnp.asarray(value)
    if value.shape != (dim,):
        raise ValueError(
            f"{name} must be a vector of shape ({dim},), like the points, got {value.shape}"
        )
    return check_finite(value.astype(float_dtype(value)), name)


def _interpolate_closed(points: Array, degree: int, parametrization) -> NURBSCurve:
    values = concrete(points)
    if values is not None and np.array_equal(values[0], values[-1]):
        raise ValueError(
            "closed=True takes the points without repeating the first at the end; "
            "drop the last point"
        )
    u = _parameters(points, parametrization, closed=True)
    control, knots = _closed_interpolation(u, points, degree)
    return NURBSCurve(control, degree, knots)


@functools.partial(jax.jit, static_argnames="degree")
def _closed_interpolation(u, points, degree):
    m = points.shape[0]
    knots = periodic_knots(u, degree)
    matrix = basis_matrix(knots, degree, u[:-1])
    # Control points m .. m+p-1 are control points 0 .. p-1 again: fold their columns.
    matrix = matrix[:, :m].at[:, :degree].add(matrix[:, m:])
    control = jnp.linalg.solve(matrix, points)
    return jnp.concatenate([control, control[:degree]]), knots


@functools.partial(jax.jit, static_argnames=("degree", "interpolate_ends"))
def least_squares(
    u: Array,
    points: Array,
    knots: Array,
    degree: int,
    weights: Array | None = None,
    interpolate_ends: bool = True,
) -> Array:
    """Control points minimising `sum_k w_k |C(u_k) - Q_k|^2` for fixed knots (A9.7).

    The normal equations `(N^T W N) P = N^T W Q` are banded (half-bandwidth `p`) and
    assembled point by point from the `p + 1` non-zero basis functions. With
    `interpolate_ends` the first and last equations become `P_0 = Q_0` and `P_n = Q_m`
    (the curve must then be clamped at `u_0` and `u_m`).
    """
    n_control = knots.shape[0] - degree - 1
    span, funs = basis_funs(knots, degree, u)
    weighted = funs if weights is None else funs * weights[:, None]
    first = span - degree
    rows = (first[:, None] + jnp.arange(degree + 1)).ravel()
    gram = (weighted[:, :, None] * funs[:, None, :]).reshape(-1, degree + 1)
    band = band_rows(rows, jnp.repeat(first, degree + 1), gram, n_control, degree)
    rhs = jnp.zeros((n_control, points.shape[1]), points.dtype)
    rhs = rhs.at[rows].add((weighted[:, :, None] * points[:, None, :]).reshape(-1, points.shape[1]))
    if interpolate_ends:
        identity = jnp.zeros(2 * degree + 1, band.dtype).at[degree].set(1.0)
        band = band.at[0].set(identity).at[-1].set(identity)
        rhs = rhs.at[0].set(points[0]).at[-1].set(points[-1])
    return solve_banded(band, rhs)


def check_solved(control: Array) -> Array:
    """Raise when concrete least-squares control points are not finite (a singular system)."""
    values = concrete(control)
    if values is not None and not np.all(np.isfinite(values)):
        raise ValueError(
            "the least-squares system is singular: some basis function has no data point "
            "(with positive weight) where it is non-zero; use fewer control points or other knots"
        )
    return control


def approximate(
    points: ArrayLike,
    n_control: int,
    degree: int = 3,
    parametrization="centripetal",
    weights: ArrayLike | None = None,
    *,
    interpolate_ends: bool | None = None,
    knots: ArrayLike | None = None,
    closed: bool = False,
) -> NURBSCurve:
    """Least-squares B-spline curve of `n_control` control points through the end points
    (NURBS Book A9.7), or closed, optionally weighted.

    The knots follow eq. 9.68-9.69 (every span holds data), unless given. Solving the
    banded normal equations costs O(m p^2).

    A closed curve (`closed=True`) is a periodic spline held as `interpolate(...,
    closed=True)` holds it: `n_control` free control points with the first `degree`
    repeated at the end, and `n_control + 2 degree + 1` knots continuing periodically, so
    it closes with `C^(p-1)` continuity. The data is not repeated: the parameters also
    step back from the last point to the first (`parametrize(..., closed=True)`). One
    period's knots are the parameters interpolated at the positions `j m / n_control`
    (`j - 1/2` positions for even degrees, as `periodic_knots` places them), so every span
    holds data and `n_control = m` gives the closed interpolant. The normal equations
    are then cyclic banded; numbering the control points 0, n-1, 1, n-2, ... turns them
    into a plain banded system (half-bandwidth at most `2 p`) that is still symmetric
    positive definite, so the same pivot-free banded solve applies in O(m p^2), with no
    dense factorisation and no low-rank correction for the wrap (whose banded part alone
    need not be invertible).

    **Arguments:**

    - `points`: array of shape `(m, dim)`.
    - `n_control`: number of control points (free ones when closed),
      `degree + 1 <= n_control <= m`.
    - `degree`: the degree `p`.
    - `parametrization`: a method name (see `parametrize`) or `m` increasing parameters
      (`m + 1` when closed, the last closing the loop).
    - `weights`: optional `m` non-negative weights of the squared errors.
    - `interpolate_ends`: pass exactly through the first and last points (A9.7); False
      gives the plain least-squares fit (as scipy's `make_lsq_spline`). None (default):
      True for an open curve; a closed one has no ends, and True raises `ValueError`.
    - `knots`: optional `n_control + degree + 1` knots (`n_control + 2 degree + 1`
      periodic ones when closed); their domain must hold the parameters, and be
      `[u_0, u_m]` with clamped ends when `interpolate_ends`.
    - `closed`: fit a closed (periodic) curve to points given once around the loop.

    **Returns:**

    A non-rational `NURBSCurve` (with `n_control + degree` control points when closed).
    Works on traced points, parameters, weights and knots; `n_control`, `degree`,
    `interpolate_ends`, `closed`, a method name and whether `weights` and `knots` are
    given must be concrete.
    """
    degree = check_degree(degree)
    points = _data_points(points)
    check_control_count(n_control, degree, at_most=points.shape[0])
    interpolate_ends = _ends_option(interpolate_ends, closed)
    if closed:
        _check_loop(points)
    u = _parameters(points, parametrization, closed)
    if knots is None:
        knots = (closed_approximation_knots if closed else approximation_knots)(
            u, n_control, degree
        )
    else:
        knots = checked_knots(knots, points.dtype, n_control, degree, closed)
        _check_knots_fit(knots, degree, u, interpolate_ends)
    if weights is not None:
        weights = _point_weights(weights, points.shape[0])
    if closed:
        control = _periodic_least_squares(u[:-1], points, knots, degree, weights)
    else:
        control = least_squares(u, points, knots, degree, weights, interpolate_ends)
    return NURBSCurve(check_solved(control), degree, knots)


def _ends_option(interpolate_ends: bool | None, closed: bool) -> bool:
    if interpolate_ends is None:
        return not closed
    if closed and interpolate_ends:
        raise ValueError(
            "interpolate_ends applies to open curves only (a closed curve has no ends), "
            "got closed=True with interpolate_ends=True"
        )
    return interpolate_ends


def _check_loop(points: Array) -> None:
    values = concrete(points)
    if values is not None and np.array_equal(values[0], values[-1]):
        raise ValueError(
            "closed=True takes the points without repeating the first at the end; "
            "drop the last point"
        )


def checked_knots(knots: ArrayLike, dtype, n_control: int, degree: int, closed: bool) -> Array:
    """Given knots as an array of `dtype`, checked: clamped-or-not knots of `n_control`
    control points, or periodic ones of `n_control` free control points when `closed`."""
    knots = jnp.asarray(knots, dtype=dtype)
    if not closed:
        return check_knots(knots, n_control, degree)
    expected = n_control + 2 * degree + 1
    if knots.shape != (expected,):
        raise ValueError(
            f"a closed curve with {n_control} free control points of degree {degree} needs "
            f"n_control + 2 p + 1 = {expected} periodic knots, got shape {knots.shape}"
        )
    knots = check_knots(knots, n_control + degree, degree)
    values = concrete(knots)
    if values is not None:
        # Each knot and the one a period later are a period apart (to rounding).
        period = values[n_control + degree] - values[degree]
        gaps = values[n_control:] - values[:-n_control]
        if np.any(np.abs(gaps - period) > np.sqrt(np.finfo(values.dtype).eps) * period):
            raise ValueError(
                f"knots of a closed curve must repeat with the period "
                f"knots[n_control + p] - knots[p] = {period}: expected "
                f"knots[i + {n_control}] - knots[i] = {period}, got {gaps}"
            )
    return knots


@functools.partial(jax.jit, static_argnames=("n_control", "degree"))
def closed_approximation_knots(u: Array, n_control: int, degree: int) -> Array:
    """Periodic knots of a closed least-squares curve with `n_control` spans, for data at
    the parameters `u` (`m + 1` of them, the last closing the loop).

    Knot `j` of the period sits at position `j m / n_control` of the parameters (`1/2`
    earlier for even degrees), linearly interpolated, the first at `u_0` and the last at
    `u_m`; each span then covers at least one whole parameter step, so it holds a data
    point. With `n_control = m` these are `periodic_knots(u, degree)`. `degree` knots on
    each side continue the period.
    """
    m = u.shape[0] - 1
    at = np.arange(1, n_control) * (m / n_control) - (0.5 if degree % 2 == 0 else 0.0)
    index = np.floor(at).astype(int)
    alpha = (at - index).astype(u.dtype)
    period = jnp.concatenate([u[:1], (1 - alpha) * u[index] + alpha * u[index + 1], u[-1:]])
    steps = jnp.diff(period)
    wrap = np.arange(degree) % n_control
    left = period[0] - jnp.cumsum(steps[n_control - 1 - wrap])[::-1]
    right = period[-1] + jnp.cumsum(steps[wrap])
    return jnp.concatenate([left, period, right])


def band_order(n_control: int, degree: int, closed: bool) -> tuple[np.ndarray, int]:
    """`(position, half)`: the row of each control point in a banded system coupling the
    control points of every span, and the half-bandwidth in control points.

    Open curves keep the order (half-bandwidth `p`). A closed curve couples the last
    control points with the first; the order 0, n-1, 1, n-2, 2, ... puts every cyclic
    window of `p + 1` control points within `2 p` rows of each other.
    """
    index = np.arange(n_control)
    if not closed:
        return index, degree
    position = np.where(index < (n_control + 1) // 2, 2 * index, 2 * (n_control - 1 - index) + 1)
    windows = position[(index[:, None] + np.arange(degree + 1)) % n_control]
    return position, int(np.max(windows.max(axis=1) - windows.min(axis=1)))


@functools.partial(jax.jit, static_argnames="degree")
def _periodic_least_squares(
    u: Array, points: Array, knots: Array, degree: int, weights: Array | None
) -> Array:
    """Control points (the first `degree` repeated at the end) of the closed curve
    minimising `sum_k w_k |C(u_k) - Q_k|^2` for fixed periodic knots."""
    n_control = knots.shape[0] - 2 * degree - 1
    position, half = band_order(n_control, degree, closed=True)
    span, funs = basis_funs(knots, degree, u)
    weighted = funs if weights is None else funs * weights[:, None]
    # Control points n .. n+p-1 are 0 .. p-1 again: their rows and columns fold onto those.
    rows = jnp.asarray(position)[(span[:, None] - degree + jnp.arange(degree + 1)) % n_control]
    band = jnp.zeros((n_control, 2 * half + 1), funs.dtype)
    band = band.at[rows[:, :, None], rows[:, None, :] - rows[:, :, None] + half].add(
        weighted[:, :, None] * funs[:, None, :]
    )
    rhs = jnp.zeros((n_control, points.shape[1]), points.dtype)
    rhs = rhs.at[rows].add(weighted[:, :, None] * points[:, None, :])
    control = solve_banded(band, rhs)[position]
    return jnp.concatenate([control, control[:degree]])


def _check_knots_fit(knots: Array, degree: int, u: Array, interpolate_ends: bool) -> None:
    values, params = concrete(knots), concrete(u)
    if values is None or params is None:
        return
    lower, upper = values[degree], values[-degree - 1]
    if params[0] < lower or params[-1] > upper:
        raise ValueError(
            f"the parameters [{params[0]}, {params[-1]}] must lie in the knots' domain "
            f"[{lower}, {upper}]"
        )
    clamped = values[0] == lower and values[-1] == upper
    if interpolate_ends and not (clamped and params[0] == lower and params[-1] == upper):
        raise ValueError(
            "interpolate_ends needs clamped knots whose domain is [u_0, u_m] = "
            f"[{params[0]}, {params[-1]}], got knots from {values[0]} to {values[-1]} with "
            f"domain [{lower}, {upper}]"
        )


def _point_weights(weights: ArrayLike, count: int) -> Array:
    weights = jnp.asarray(weights)
    if weights.shape != (count,):
        raise ValueError(f"weights must have shape ({count},), one per point, got {weights.shape}")
    weights = check_finite(weights.astype(float_dtype(weights)), "weights")
    values = concrete(weights)
    if values is not None and np.any(values < 0):
        k = int(np.argmax(values < 0))
        raise ValueError(f"weights must be non-negative, got weights[{k}] = {values[k]}")
    return weights


def _grid(points_grid: ArrayLike, degrees: tuple[int, int]) -> Array:
    grid = jnp.asarray(points_grid)
    check_rank(grid, 3, "points_grid", "(mu, mv, dim)")
    for count, degree, axis in zip(grid.shape[:2], degrees, "uv", strict=True):
        check_control_count(count, degree, f"points along {axis}")
    return check_finite(grid.astype(float_dtype(grid)), "points_grid")


def grid_parameters(grid: Array, method: str) -> tuple[Array, Array]:
    """Parameters `(u, v)` of a grid of points (NURBS Book A9.3): each row's parameters
    averaged over the rows; rows of zero length (a pole) are left out of the average."""
    params = _grid_parameters(grid, check_parametrization(method))
    for u, axis in zip(params, "uv", strict=True):
        check_distinct_parameters(u, f"grid lines along {axis} at positions")
    return params


@functools.partial(jax.jit, static_argnames="method")
def _grid_parameters(grid: Array, method: str) -> tuple[Array, Array]:
    params = []
    for lines in (jnp.swapaxes(grid, 0, 1), grid):  # lines along u, then along v
        u, total = normalized_cumsum(chord_steps(lines, method))
        used = (total > 0)[:, None]
        count = jnp.maximum(jnp.sum(used), 1)
        params.append(jnp.sum(jnp.where(used, u, 0.0), axis=0) / count)
    return params[0], params[1]


def _along_both(grid: Array, solve_u, solve_v) -> Array:
    """Apply a curve solve `(n, k) -> (n', k)` to every column of the grid (along u), then
    to every row of the result (along v)."""
    nu, nv, dim = grid.shape
    columns = solve_u(grid.reshape(nu, nv * dim)).reshape(-1, nv, dim)
    rows = jnp.swapaxes(columns, 0, 1).reshape(nv, -1)
    return jnp.swapaxes(solve_v(rows).reshape(-1, columns.shape[0], dim), 0, 1)


def interpolate_surface(
    points_grid: ArrayLike,
    degree: tuple[int, int] = (3, 3),
    parametrization: str = "centripetal",
) -> NURBSSurface:
    """The B-spline surface through a grid of points (NURBS Book A9.4).

    Parameters by averaging over the grid lines (`grid_parameters`), knots by averaging
    (eq. 9.8), then curve interpolation through every column and every row of the result.

    **Arguments:**

    - `points_grid`: array of shape `(mu, mv, dim)`, `mu > p`, `mv > q`.
    - `degree`: `(p, q)`.
    - `parametrization`: `"uniform"`, `"chord"` or `"centripetal"`.

    **Returns:**

    A non-rational `NURBSSurface` with `S(u_k, v_l) = Q_kl`.
    """
    degrees = check_degree_pair(degree)
    grid = _grid(points_grid, degrees)
    control, knots = _interpolated_net(grid, grid_parameters(grid, parametrization), degrees)
    return NURBSSurface(control, degrees, knots)


@functools.partial(jax.jit, static_argnames="degrees")
def _interpolated_net(grid, params, degrees):
    knots = tuple(averaged_knots(u, d) for u, d in zip(params, degrees, strict=True))

    def solver(u, knots, degree):
        orders = np.zeros(u.shape[0], int)
        return lambda rhs: collocation_solve(u, orders, knots, degree, rhs)

    solvers = (solver(*args) for args in zip(params, knots, degrees, strict=True))
    return _along_both(grid, *solvers), knots


def approximate_surface(
    points_grid: ArrayLike,
    n_control: tuple[int, int],
    degree: tuple[int, int] = (3, 3),
    parametrization: str = "centripetal",
    *,
    interpolate_ends: bool = True,
) -> NURBSSurface:
    """Least-squares B-spline surface on a grid of points (NURBS Book §9.4.2).

    Curve approximation (A9.7) of every column, then of every row of the result. Without
    `interpolate_ends` this is the exact tensor-product least-squares fit (the projection
    separates by direction); with it the boundary curves of the surface are the curve
    fits of the boundary lines and the four corners are interpolated.

    **Arguments:**

    - `points_grid`: array of shape `(mu, mv, dim)`.
    - `n_control`: `(nu, nv)`, control points per direction, each from the degree plus
      one to the number of grid points in that direction.
    - `degree`: `(p, q)`.
    - `parametrization`: `"uniform"`, `"chord"` or `"centripetal"`.
    - `interpolate_ends`: pass through the boundary points as A9.7 does.

    **Returns:**

    A non-rational `NURBSSurface`.
    """
    degrees = check_degree_pair(degree)
    grid = _grid(points_grid, degrees)
    counts = check_pair(n_control, "n_control")
    for count, degree, size, axis in zip(counts, degrees, grid.shape[:2], "uv", strict=True):
        name, source = f"control points along {axis}", f"grid points along {axis}"
        check_control_count(count, degree, name, at_most=size, source=source)
    params = grid_parameters(grid, parametrization)
    control, knots = _approximated_net(grid, params, counts, degrees, interpolate_ends)
    return NURBSSurface(check_solved(control), degrees, knots)


@functools.partial(jax.jit, static_argnames=("counts", "degrees", "interpolate_ends"))
def _approximated_net(grid, params, counts, degrees, interpolate_ends):
    knots = tuple(
        approximation_knots(u, n, d) for u, n, d in zip(params, counts, degrees, strict=True)
    )

    def solver(u, knots, degree):
        return lambda rhs: least_squares(u, rhs, knots, degree, None, interpolate_ends)

    solvers = (solver(*args) for args in zip(params, knots, degrees, strict=True))
    return _along_both(grid, *solvers), knots
