"""Bicubic patches in matrix form (seed 002): `S(u, v) = U M G M^T V^T`.

A cubic segment in matrix form is `C(t) = [t^3, t^2, t, 1] @ M @ G` with a 4 x 4 basis
matrix `M` and four geometry points `G`. The same geometry gives different curves with
different bases: the Bezier basis interpolates `G_0` and `G_3`; the uniform cubic B-spline
basis interpolates none of them (one C2 segment of a uniform B-spline); the Catmull-Rom
basis interpolates `G_1` and `G_2` (the segment between the middle points). The tensor
product of two such segments is a bicubic patch.

The matrices are stored as NumPy float64 constants (JAX arrays made at import time would
be frozen at the dtype of that moment) and converted when used.
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._validate import check_parameter, check_rank

BEZIER_MATRIX = np.array(
    [[-1.0, 3.0, -3.0, 1.0], [3.0, -6.0, 3.0, 0.0], [-3.0, 3.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]]
)
"""The cubic Bezier basis matrix `M_B` (rows: coefficients of t^3, t^2, t, 1)."""

BSPLINE_MATRIX = (
    np.array(
        [[-1.0, 3.0, -3.0, 1.0], [3.0, -6.0, 3.0, 0.0], [-3.0, 0.0, 3.0, 0.0], [1.0, 4.0, 1.0, 0.0]]
    )
    / 6.0
)
"""The uniform cubic B-spline basis matrix `(1/6) [[-1,3,-3,1],[3,-6,3,0],[-3,0,3,0],[1,4,1,0]]`."""

CATMULL_ROM_MATRIX = (
    np.array(
        [
            [-1.0, 3.0, -3.0, 1.0],
            [2.0, -5.0, 4.0, -1.0],
            [-1.0, 0.0, 1.0, 0.0],
            [0.0, 2.0, 0.0, 0.0],
        ]
    )
    / 2.0
)
"""The Catmull-Rom basis matrix `(1/2) [[-1,3,-3,1],[2,-5,4,-1],[-1,0,1,0],[0,2,0,0]]`."""

_BASES = {"bezier": BEZIER_MATRIX, "bspline": BSPLINE_MATRIX, "catmull-rom": CATMULL_ROM_MATRIX}


def cubic_basis_matrix(kind: str, dtype=None) -> Float[Array, "4 4"]:
    """One of the three cubic basis matrices of seed 002.

    **Arguments:**

    - `kind`: `"bezier"`, `"bspline"` (uniform cubic B-spline) or `"catmull-rom"`.
    - `dtype`: floating dtype of the result (default: JAX's default float).

    **Returns:**

    Array of shape `(4, 4)`, rows the coefficients of `t^3, t^2, t, 1`.
    """
    if not isinstance(kind, str) or kind.lower() not in _BASES:
        raise ValueError(f"kind must be one of {sorted(_BASES)}, got {kind!r}")
    return jnp.asarray(_BASES[kind.lower()], dtype=dtype or jnp.result_type(float))


def basis_or_matrix(basis, dtype, named=cubic_basis_matrix) -> Float[Array, "4 4"]:
    """The matrix `named(basis, dtype)` when `basis` is a name, else `basis` as a `(4, 4)` array."""
    if isinstance(basis, str):
        return named(basis, dtype)
    matrix = jnp.asarray(basis, dtype=dtype)
    if matrix.shape != (4, 4):
        raise ValueError(f"a basis matrix must have shape (4, 4), got {matrix.shape}")
    return matrix


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
    - `basis`: `"bezier"`, `"bspline"`, `"catmull-rom"`, or a `(4, 4)` basis matrix.

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
