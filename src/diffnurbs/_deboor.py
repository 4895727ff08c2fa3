"""De Boor's construction: the intermediate points of the algorithm at one parameter."""

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._basis import find_span
from ._rational import from_homogeneous, to_homogeneous
from ._validate import check_parameter


def de_boor_levels(curve, u: ArrayLike) -> list[Float[Array, "count dim"]]:
    """Every level of de Boor's algorithm for `curve` at one parameter `u`.

    Level 0 is the `p + 1` control points that act on the span holding `u`; level `r`
    has `p + 1 - r` points, each on the segment between two neighbours of level `r - 1`,
    split in the ratio `(u - U[i]) : (U[i + p + 1 - r] - u)`; level `p` is the single point
    `curve(u)`. For a Bezier curve these are de Casteljau's levels. A rational curve's
    construction runs on the homogeneous points and is projected level by level.

    **Arguments:**

    - `curve`: a `NURBSCurve`.
    - `u`: one parameter in the curve's domain.

    **Returns:**

    A list of `p + 1` arrays, level `r` of shape `(p + 1 - r, dim)`.
    """
    u = jnp.asarray(u, dtype=curve.knots.dtype)
    if u.ndim != 0:
        raise ValueError(f"de_boor_levels takes one parameter u, got shape {u.shape}")
    check_parameter(u, *curve.domain, "u")
    p, knots = curve.degree, curve.knots
    span = find_span(knots, p, u)
    points = curve.control_points
    if curve.weights is not None:
        points = to_homogeneous(points, curve.weights)
    level = jnp.stack([points[span - p + j] for j in range(p + 1)])
    levels = [level]
    for r in range(1, p + 1):
        # Point j of level r (j = r..p in the NURBS Book's numbering) blends points j - 1
        # and j of level r - 1 over the knots U[span - p + j] .. U[span + 1 + j - r].
        j = jnp.arange(r, p + 1)
        lower, upper = knots[span - p + j], knots[span + 1 + j - r]
        alpha = ((u - lower) / (upper - lower))[:, None]
        level = (1.0 - alpha) * level[:-1] + alpha * level[1:]
        levels.append(level)
    if curve.weights is not None:
        levels = [from_homogeneous(level) for level in levels]
    return levels
