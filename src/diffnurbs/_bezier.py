"""De Casteljau's algorithm for Bezier and rational Bezier curves and surfaces."""

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._rational import from_homogeneous, to_homogeneous
from ._validate import check_rank, check_weights


def _homogeneous_net(points, weights, rank, layout):
    points = jnp.asarray(points)
    points = points.astype(jnp.result_type(points.dtype, float))
    check_rank(points, rank, "control_points", layout)
    if weights is None:
        return points, False
    weights = check_weights(jnp.asarray(weights, dtype=points.dtype), points.shape[:-1])
    return to_homogeneous(points, weights), True


def _casteljau(points: Array, t: Array) -> Array:
    """Repeated linear interpolation along axis -2 of `points` (seed Listing 1.1)."""
    t = t[..., None, None]
    q = jnp.broadcast_to(points, t.shape[:-2] + points.shape)
    for _ in range(1, points.shape[-2]):
        q = (1.0 - t) * q[..., :-1, :] + t * q[..., 1:, :]
    return q[..., 0, :]


def de_casteljau(
    control_points: ArrayLike, t: ArrayLike, weights: ArrayLike | None = None
) -> Float[Array, "... dim"]:
    """Points of a (rational) Bezier curve by de Casteljau's algorithm.

    **Arguments:**

    - `control_points`: array of shape `(n + 1, dim)`.
    - `t`: parameters in [0, 1], any shape.
    - `weights`: optional positive weights, shape `(n + 1,)`; the curve is then rational
      and the algorithm runs on homogeneous points.

    **Returns:**

    Array of shape `t.shape + (dim,)`.
    """
    net, rational = _homogeneous_net(control_points, weights, 2, "(n + 1, dim)")
    points = _casteljau(net, jnp.asarray(t, dtype=net.dtype))
    return from_homogeneous(points) if rational else points


def de_casteljau_surface(
    control_points: ArrayLike, u: ArrayLike, v: ArrayLike, weights: ArrayLike | None = None
) -> Float[Array, "... dim"]:
    """Points of a (rational) Bezier patch by de Casteljau in each direction (seed Listing 1.2).

    The `v`-curves of every row are evaluated first, then the resulting column in `u`.

    **Arguments:**

    - `control_points`: array of shape `(n + 1, m + 1, dim)`, first axis along `u`.
    - `u`, `v`: parameters in [0, 1], broadcast against each other.
    - `weights`: optional positive weights of shape `(n + 1, m + 1)`.

    **Returns:**

    Array of shape `broadcast(u, v).shape + (dim,)`.
    """
    net, rational = _homogeneous_net(control_points, weights, 3, "(n + 1, m + 1, dim)")
    u, v = jnp.broadcast_arrays(jnp.asarray(u, net.dtype), jnp.asarray(v, net.dtype))
    rows = _casteljau(net, v[..., None])  # one point per row: (..., n + 1, D)
    points = _casteljau(rows, u)
    return from_homogeneous(points) if rational else points
