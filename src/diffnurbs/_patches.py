"""Bicubic patches in matrix form (seed 002): `S(u, v) = U M G M^T V^T`.

A cubic segment in matrix form is `C(t) = [t^3, t^2, t, 1] @ M @ G` with a 4 x 4 basis
matrix `M` and four geometry points `G`. The same geometry gives different curves with
different bases: the Bezier basis interpolates `G_0` and `G_3`; the uniform cubic B-spline
basis interpolates none of them (one C2 segment of a uniform B-spline); the Catmull-Rom
basis interpolates `G_1` and `G_2` (the segment between the middle points). The tensor
product of two such segments is a bicubic patch.

The basis matrices come from `cubic_matrix`.
"""

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._cubic import basis_or_matrix
from ._validate import check_parameter, check_rank


def _power_row(t):
    return jnp.stack([t**3, t**2, t, jnp.ones_like(t)], axis=-1)


def bicubic_patch(
    geometry: ArrayLike, u: ArrayLike, v: ArrayLike, basis: str | ArrayLike = "bezier"
) -> Float[Array, "... dim"]:
    """Points of a bicubic patch in matrix form, `S(u, v) = U M G M^T V^T` (seed 002).

    `U = [u^3, u^2, u, 1]`, `V = [v^3, v^2, v, 1]`, and the geometry matrix `G` holds the
    16 points `G[i, j]`, the first index along `u`. With the Bezier basis this is the
    tensor-product Bezier patch `sum_ij B_{i,3}(u) B_{j,3}(v) G_ij`.

    **Arguments:**

    - `geometry`: array of shape `(4, 4, dim)`.
    - `u`, `v`: parameters in [0, 1], broadcast against each other.
    - `basis`: a name of `cubic_matrix` (`"bezier"`, `"bspline"`, `"catmull-rom"`,
      `"hermite"`), or a `(4, 4)` basis matrix.

    **Returns:**

    Array of shape `broadcast(u, v).shape + (dim,)`.
    """
    geometry = jnp.asarray(geometry)
    geometry = geometry.astype(jnp.result_type(geometry.dtype, float))
    check_rank(geometry, 3, "geometry", "(4, 4, dim)")
    if geometry.shape[:2] != (4, 4):
        raise ValueError(f"geometry must have shape (4, 4, dim), got {geometry.shape}")
    matrix = basis_or_matrix(basis, geometry.dtype)
    u, v = jnp.broadcast_arrays(jnp.asarray(u, geometry.dtype), jnp.asarray(v, geometry.dtype))
    check_parameter(u, 0.0, 1.0, "u")
    check_parameter(v, 0.0, 1.0, "v")
    bu = _power_row(u) @ matrix  # (..., 4): the four blending functions in u
    bv = _power_row(v) @ matrix
    return jnp.einsum("...i,...j,ijd->...d", bu, bv, geometry)
