"""De Casteljau's algorithm for Bezier curves, surfaces and volumes; matrix form, subdivision
and hodographs."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._rational import from_homogeneous, to_homogeneous
from ._validate import check_degree, check_parameter, check_rank, check_weights


def _homogeneous_net(points, weights, rank, layout):
    points = jnp.asarray(points)
    points = points.astype(jnp.result_type(points.dtype, float))
    check_rank(points, rank, "control_points", layout)
    if weights is None:
        return points, False
    weights = check_weights(jnp.asarray(weights, dtype=points.dtype), points.shape[:-1])
    return to_homogeneous(points, weights), True


def _casteljau(points: Array, t: Array) -> Array:
    """Repeated linear interpolation along axis -2 of `points` (seed Listing 1.1).

    `points` may carry leading batch axes; `t[..., None, None]` broadcasts against them.
    """
    t = t[..., None, None]
    q = jnp.broadcast_to(points, jnp.broadcast_shapes(t.shape, points.shape))
    for _ in range(1, points.shape[-2]):
        q = (1.0 - t) * q[..., :-1, :] + t * q[..., 1:, :]
    return q[..., 0, :]


def de_casteljau(
    control_points: ArrayLike, t: ArrayLike, weights: ArrayLike | None = None
) -> Float[Array, "... dim"]:
    """Points of a (rational) Bezier curve by de Casteljau's algorithm.

    **Arguments:**

    - `control_points`: array of shape `(n_control, dim)`.
    - `t`: parameters, any shape; [0, 1] is the curve, values outside extend the same
      polynomial (used to draw a conic beyond its arc), unlike `NURBSCurve`, which raises.
    - `weights`: optional positive weights, shape `(n_control,)`; the curve is then rational
      and the algorithm runs on homogeneous points.

    **Returns:**

    Array of shape `t.shape + (dim,)`.
    """
    net, rational = _homogeneous_net(control_points, weights, 2, "(n_control, dim)")
    return _curve_points(net, jnp.asarray(t, dtype=net.dtype), rational)


# The evaluations below are compiled once per shape of net and parameters: run eagerly, each
# level of the triangle dispatched (and compiled) its own small programs, hundreds per chapter.
@functools.partial(jax.jit, static_argnums=2)
def _curve_points(net, t, rational):
    points = _casteljau(net, t)
    return from_homogeneous(points) if rational else points


def de_casteljau_surface(
    control_points: ArrayLike, u: ArrayLike, v: ArrayLike, weights: ArrayLike | None = None
) -> Float[Array, "... dim"]:
    """Points of a (rational) Bezier patch by de Casteljau in each direction (seed Listing 1.2).

    The `v`-curves of every row are evaluated first, then the resulting column in `u`.

    **Arguments:**

    - `control_points`: array of shape `(nu, nv, dim)`, first axis along `u`.
    - `u`, `v`: parameters in [0, 1], broadcast against each other.
    - `weights`: optional positive weights of shape `(nu, nv)`.

    **Returns:**

    Array of shape `broadcast(u, v).shape + (dim,)`.
    """
    net, rational = _homogeneous_net(control_points, weights, 3, "(nu, nv, dim)")
    return _surface_points(net, jnp.asarray(u, net.dtype), jnp.asarray(v, net.dtype), rational)


@functools.partial(jax.jit, static_argnums=3)
def _surface_points(net, u, v, rational):
    u, v = jnp.broadcast_arrays(u, v)
    rows = _casteljau(net, v[..., None])  # one point per row: (..., n + 1, D)
    points = _casteljau(rows, u)
    return from_homogeneous(points) if rational else points


def _casteljau_batched(q: Array, t: Array) -> Array:
    """De Casteljau along axis -2 of `q` of shape `t.shape + (..., k + 1, D)`, one `t` per
    leading batch index (no outer product between the batch of `q` and `t`)."""
    t = t.reshape(t.shape + (1,) * (q.ndim - t.ndim))
    for _ in range(1, q.shape[-2]):
        q = (1.0 - t) * q[..., :-1, :] + t * q[..., 1:, :]
    return q[..., 0, :]


def _check_unit_parameter(t, name):
    check_parameter(t, 0.0, 1.0, name)
    return t


def bezier_matrix(degree: int, dtype=None) -> Float[Array, "degree+1 degree+1"]:
    """The power-basis matrix `M_B` of the Bezier curves of a degree (seed 002).

    Convention (the seed's): powers in DECREASING order in a row vector on the left,
    control points in a column on the right,

    `C(t) = [t^n, t^(n-1), ..., t, 1] @ M_B @ [P_0, ..., P_n]^T`,

    so row `r` of `M_B` holds the coefficients of `t^(n - r)` and column `j` the power
    coefficients of the Bernstein polynomial `B_{j,n}`:
    `M_B[r, j] = (-1)^(k - j) C(n, j) C(n - j, k - j)` with `k = n - r` (zero for `k < j`).
    For `n = 3` this is `[[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 3, 0, 0], [1, 0, 0, 0]]`.

    **Arguments:**

    - `degree`: the degree `n >= 0`, a Python int.
    - `dtype`: floating dtype of the result (default: JAX's default float).

    **Returns:**

    Array of shape `(degree + 1, degree + 1)`; its entries are integers.
    """
    n = check_degree(degree, minimum=0)
    matrix = np.zeros((n + 1, n + 1))
    for r in range(n + 1):
        k = n - r
        for j in range(k + 1):
            matrix[r, j] = (-1) ** (k - j) * math.comb(n, j) * math.comb(n - j, k - j)
    return jnp.asarray(matrix, dtype=dtype if dtype is not None else jnp.result_type(float))


def subdivide(control_points: ArrayLike, t: ArrayLike, weights: ArrayLike | None = None):
    """Split a (rational) Bezier curve at `t` into the curves on `[0, t]` and `[t, 1]`.

    The control points of the two halves are the two outer edges of de Casteljau's
    triangle: `left[k] = P_0^k` (first point of level `k`) and
    `right[k] = P_k^(n - k)` (last point of level `n - k`). Each half, reparametrised to
    `[0, 1]`, is the same curve: `C_left(s) = C(t s)`, `C_right(s) = C(t + (1 - t) s)`.
    Rational curves are split in homogeneous coordinates, which also splits the weights.

    **Arguments:**

    - `control_points`: array of shape `(n_control, dim)`.
    - `t`: split parameter(s) in [0, 1], any shape.
    - `weights`: optional positive weights of shape `(n_control,)`.

    **Returns:**

    Without weights, `(left, right)`: two arrays of shape `t.shape + (n_control, dim)`.
    With weights, `((left, left_weights), (right, right_weights))`, the weights of shape
    `t.shape + (n_control,)`.
    """
    net, rational = _homogeneous_net(control_points, weights, 2, "(n_control, dim)")
    t = jnp.asarray(t, dtype=net.dtype)
    _check_unit_parameter(t, "t")
    return _subdivide(net, t, rational)


@functools.partial(jax.jit, static_argnums=2)
def _subdivide(net, t, rational):
    tt = t[..., None, None]
    q = jnp.broadcast_to(net, t.shape + net.shape)
    left, right = [q[..., 0, :]], [q[..., -1, :]]
    for _ in range(1, net.shape[0]):
        q = (1.0 - tt) * q[..., :-1, :] + tt * q[..., 1:, :]
        left.append(q[..., 0, :])
        right.append(q[..., -1, :])
    left, right = jnp.stack(left, axis=-2), jnp.stack(right[::-1], axis=-2)
    if not rational:
        return left, right
    return (
        (from_homogeneous(left), left[..., -1]),
        (from_homogeneous(right), right[..., -1]),
    )


def bezier_derivative_points(control_points: ArrayLike, order: int = 1) -> Float[Array, "m dim"]:
    """Control points of the derivative (hodograph) of a polynomial Bezier curve.

    `C'(t) = sum_{i=0}^{n-1} B_{i,n-1}(t) n (P_{i+1} - P_i)`: the derivative of a degree
    `n` Bezier curve is a Bezier curve of degree `n - 1`. With `order = k` the rule is
    applied `k` times, giving the `n - k + 1` control points of `C^(k)`. (For rational
    curves the derivative is not a Bezier curve of this kind: use
    `NURBSCurve.derivatives`.)

    **Arguments:**

    - `control_points`: array of shape `(n_control, dim)`.
    - `order`: the derivative order `1 <= k <= n`.

    **Returns:**

    Array of shape `(n_control - k, dim)`.
    """
    points = jnp.asarray(control_points)
    points = points.astype(jnp.result_type(points.dtype, float))
    check_rank(points, 2, "control_points", "(n_control, dim)")
    order = check_degree(order, minimum=1, name="order")
    n = points.shape[0] - 1
    if order > n:
        raise ValueError(
            f"derivative order must be <= the degree n = {n} ({n + 1} control points), got {order}"
        )
    for k in range(order):
        points = (n - k) * (points[1:] - points[:-1])
    return points


def de_casteljau_volume(
    control_points: ArrayLike,
    u: ArrayLike,
    v: ArrayLike,
    w: ArrayLike,
    weights: ArrayLike | None = None,
) -> Float[Array, "... dim"]:
    """Points of a trivariate (rational) Bezier volume (seed 002).

    `B(u, v, w) = sum_i sum_j sum_k B_{i,l}(u) B_{j,m}(v) B_{k,n}(w) P_{ijk}`, evaluated by
    de Casteljau along `w`, then `v`, then `u`.

    **Arguments:**

    - `control_points`: array of shape `(nu, nv, nw, dim)`; axes 0, 1, 2 run
      along `u`, `v`, `w`.
    - `u`, `v`, `w`: parameters in [0, 1], broadcast against each other.
    - `weights`: optional positive weights of shape `(nu, nv, nw)`.

    **Returns:**

    Array of shape `broadcast(u, v, w).shape + (dim,)`.
    """
    net, rational = _homogeneous_net(control_points, weights, 4, "(nu, nv, nw, dim)")
    u, v, w = jnp.broadcast_arrays(*(jnp.asarray(x, net.dtype) for x in (u, v, w)))
    for x, name in ((u, "u"), (v, "v"), (w, "w")):
        _check_unit_parameter(x, name)
    return _volume_points(net, u, v, w, rational)


@functools.partial(jax.jit, static_argnums=4)
def _volume_points(net, u, v, w, rational):
    q = jnp.broadcast_to(net, u.shape + net.shape)
    for t in (w, v, u):  # contract the last parameter axis: w, then v, then u
        q = _casteljau_batched(q, t)
    return from_homogeneous(q) if rational else q
