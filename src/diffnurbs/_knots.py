"""Knot vectors and the parameters of data points."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._misc import safe_norm, safe_sqrt
from ._validate import check_control_count, check_degree, check_rank, concrete, float_dtype


def clamped_knots(
    n_control: int, degree: int, domain=(0.0, 1.0), dtype=None
) -> Float[Array, " n_control+p+1"]:
    """Clamped uniform knot vector: `degree + 1` equal knots at each end, interior evenly spaced.

    **Arguments:**

    - `n_control`: number of control points.
    - `degree`: the degree `p`.
    - `domain`: `(a, b)`, the parameter interval.
    - `dtype`: floating dtype; the default float type when None.

    **Returns:**

    Array of `n_control + degree + 1` knots.
    """
    degree = check_degree(degree)
    check_control_count(n_control, degree)
    a, b = domain
    dtype = jax.dtypes.canonicalize_dtype(float if dtype is None else dtype)
    if dtype not in (np.float32, np.float64):
        interior = jnp.linspace(0.0, 1.0, n_control - degree + 1, dtype=dtype)
        ones, zeros = jnp.ones(degree, dtype), jnp.zeros(degree, dtype)
        return a + (b - a) * jnp.concatenate([zeros, interior, ones])
    # In NumPy: the counts are Python ints, and eager `jnp` operations (`jnp.asarray` of a
    # NumPy array too, unlike `device_put`) would compile a program per knot count.
    # `i * (1 / div)` is what `jnp.linspace` computes (XLA turns its division by a
    # constant into this product), so the knots are the same to the bit.
    div = n_control - degree
    interior = np.arange(div, dtype=dtype) * (np.ones((), dtype) / np.asarray(div, dtype))
    knots = np.concatenate([np.zeros(degree, dtype), interior, np.ones(degree + 1, dtype)])
    if all(type(x) in (int, float) for x in (a, b)):
        # Python scalars are weakly typed: they take the knots' dtype, in NumPy as in JAX.
        return jax.device_put(a + (b - a) * knots)
    return a + (b - a) * jax.device_put(knots)


PARAMETRIZATIONS = ("uniform", "chord", "centripetal")


def check_parametrization(method: str) -> str:
    if method not in PARAMETRIZATIONS:
        raise ValueError(f"parametrization must be one of {PARAMETRIZATIONS}, got {method!r}")
    return method


def chord_steps(points: Array, method: str) -> Array:
    """Parameter steps between consecutive points along axis -2: `|Q_k - Q_{k-1}|^e` with
    `e = 0, 1, 1/2` for uniform, chord and centripetal."""
    if method == "uniform":
        return jnp.ones((*points.shape[:-2], points.shape[-2] - 1), dtype=points.dtype)
    # Safe roots: sqrt at zero has an infinite gradient, and duplicates are legal under
    # tracing (they are rejected only when the points are concrete).
    distance = safe_norm(jnp.diff(points, axis=-2))
    return distance if method == "chord" else safe_sqrt(distance)


def normalized_cumsum(steps: Array) -> tuple[Array, Array]:
    """`(u, total)`: `u_0 = 0`, `u_k = (s_1 + ... + s_k) / total` along the last axis.

    The last parameter is exactly 1 (a rounded sum could end a hair short of the domain);
    all are zero where the total is zero."""
    total = jnp.sum(steps, axis=-1)
    positive = (total > 0)[..., None]
    running = jnp.cumsum(steps[..., :-1], axis=-1) / jnp.where(positive, total[..., None], 1.0)
    zero = jnp.zeros((*steps.shape[:-1], 1), dtype=steps.dtype)
    one = jnp.where(positive, 1.0, 0.0).astype(steps.dtype)
    return jnp.concatenate([zero, running, one], axis=-1), total


def check_distinct_parameters(u: Array, what: str = "points") -> None:
    """Raise for concrete parameters that do not increase strictly (coincident points)."""
    values = concrete(u)
    if values is None:
        return
    steps = np.diff(values)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0))
        raise ValueError(
            f"{what} {k} and {k + 1} coincide, so chord and centripetal parameters repeat; "
            "expected distinct consecutive points (drop the duplicate or use "
            'parametrization="uniform")'
        )


def parametrize(
    points: ArrayLike, method: str = "centripetal", closed: bool = False
) -> Float[Array, " m"]:
    """Parameters `0 = u_0 < ... < u_last = 1` for data points (NURBS Book eq. 9.3-9.6).

    Uniform spacing, or spacing proportional to the distances between consecutive points
    (`chord`) or to their square roots (`centripetal`, Lee 1989: follows sharp turns best).

    **Arguments:**

    - `points`: array of shape `(m, dim)`.
    - `method`: `"uniform"`, `"chord"` or `"centripetal"`.
    - `closed`: also step from the last point back to the first, returning `m + 1`
      parameters (the last, 1, belongs to the first point again).

    **Returns:**

    Array of `m` parameters (`m + 1` when closed). Works on traced points; coincident
    consecutive points raise `ValueError` when the points are concrete.
    """
    method = check_parametrization(method)
    points = jnp.asarray(points)
    check_rank(points, 2, "points", "(n_points, dim)")
    points = points.astype(float_dtype(points))
    u = _parameters_of(points, method, closed)
    check_distinct_parameters(u)
    return u


@functools.partial(jax.jit, static_argnames=("method", "closed"))
def _parameters_of(points: Array, method: str, closed: bool) -> Array:
    if closed:
        points = jnp.concatenate([points, points[:1]])
    return normalized_cumsum(chord_steps(points, method))[0]


@functools.partial(jax.jit, static_argnames="degree")
def averaged_knots(u: ArrayLike, degree: int) -> Float[Array, " m+p+1"]:
    """Clamped knots by averaging `degree` consecutive parameters (NURBS Book eq. 9.8).

    `U_{j+p} = (u_j + ... + u_{j+p-1}) / p` for `j = 1 .. m-p`; every knot span then holds
    a parameter, so the interpolation matrix is nonsingular (Schoenberg-Whitney).

    **Arguments:**

    - `u`: non-decreasing parameters `u_0 .. u_m`, at least `degree + 1` of them. A
      parameter listed twice at an end stands for a derivative condition there (the book's
      eq. 9.21-9.22 for end derivatives follow).
    - `degree`: the degree `p`.

    **Returns:**

    `m + p + 2` knots from `u_0` to `u_m`.
    """
    degree = check_degree(degree)
    u = jnp.asarray(u)
    check_control_count(u.shape[0], degree, "parameters")
    windows = jnp.stack([u[i : u.shape[0] - degree + 1 + i] for i in range(degree)])
    interior = jnp.mean(windows, axis=0)[1:-1]
    return jnp.concatenate(
        [jnp.repeat(u[:1], degree + 1), interior, jnp.repeat(u[-1:], degree + 1)]
    )


@functools.partial(jax.jit, static_argnames=("n_control", "degree"))
def approximation_knots(
    u: ArrayLike, n_control: int, degree: int
) -> Float[Array, " n_control+p+1"]:
    """Clamped knots for a least-squares fit of `n_control` points to data at parameters `u`
    (NURBS Book eq. 9.68-9.69).

    With `m + 1` parameters and `d = (m + 1) / (n_control - p)`, knot `U_{p+j}` interpolates
    between `u_{i-1}` and `u_i`, `i = floor(j d)`: every knot span holds at least one
    parameter, which keeps the normal equations positive definite.

    **Arguments:**

    - `u`: non-decreasing parameters, at least `n_control` of them.
    - `n_control`: number of control points, `degree + 1 <= n_control <= len(u)`.
    - `degree`: the degree `p`.

    **Returns:**

    `n_control + degree + 1` knots from `u_0` to `u_m`.
    """
    degree = check_degree(degree)
    u = jnp.asarray(u)
    check_control_count(n_control, degree, at_most=u.shape[0], source="parameters")
    d = u.shape[0] / (n_control - degree)
    steps = [j * d for j in range(1, n_control - degree)]
    index = np.array([int(s) for s in steps], dtype=int)
    alpha = np.array([s - int(s) for s in steps], dtype=u.dtype)
    interior = (1 - alpha) * u[index - 1] + alpha * u[index]
    return jnp.concatenate(
        [jnp.repeat(u[:1], degree + 1), interior, jnp.repeat(u[-1:], degree + 1)]
    )


@functools.partial(jax.jit, static_argnames="degree")
def periodic_knots(u: ArrayLike, degree: int) -> Float[Array, " m+2p+1"]:
    """Unclamped knots for a closed curve through points at parameters `u_0 < ... < u_m`
    (`u_m` is the first point again), with domain `[u_0, u_m]`.

    The knots of one period sit at the parameters for odd degrees and halfway between them
    for even degrees, except the first, which stays at `u_0` so the curve starts at the
    first point (scipy's `make_interp_spline(..., bc_type="periodic")` places them alike);
    `degree` knots on each side continue the spacing periodically.

    **Arguments:**

    - `u`: increasing parameters, `m + 1` of them for `m` distinct points.
    - `degree`: the degree `p`.

    **Returns:**

    `m + 2 p + 1` knots; knots `p` and `m + p` bound the domain.
    """
    degree = check_degree(degree)
    u = jnp.asarray(u)
    period = u.shape[0] - 1
    if degree % 2 == 0:
        u = u.at[1:-1].set((u[:-2] + u[1:-1]) / 2)
    steps = jnp.diff(u)
    wrap = np.arange(degree) % period
    left = u[0] - jnp.cumsum(steps[period - 1 - wrap])[::-1]
    right = u[-1] + jnp.cumsum(steps[wrap])
    return jnp.concatenate([left, u, right])
