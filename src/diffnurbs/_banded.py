"""Banded linear systems, solved in O(n) by a scan: B-spline collocation and normal equations."""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._basis import ders_basis_funs


def band_rows(rows: Array, first: Array, values: Array, n: int, half: int) -> Array:
    """The band of a matrix with `values[k, r]` at column `first[k] + r` of row `rows[k]`.

    **Returns:**

    Array of shape `(n, 2 half + 1)` holding `A[i, i - half + j]` at `[i, j]`; entries of
    the same place are summed (as the normal equations need).
    """
    offsets = first[:, None] + jnp.arange(values.shape[1]) - rows[:, None] + half
    band = jnp.zeros((n, 2 * half + 1), dtype=values.dtype)
    return band.at[jnp.broadcast_to(rows[:, None], offsets.shape), offsets].add(values)


@jax.jit
def solve_banded(band: Float[Array, "n 2h+1"], rhs: Float[Array, "n k"]) -> Float[Array, "n k"]:
    """Solve `A x = rhs` for a band matrix `A` of half-bandwidth `h` by Gaussian elimination
    without pivoting.

    No pivoting keeps the band (L and U have half-bandwidth `h`) and is stable for the
    matrices met here: B-spline collocation matrices are totally positive (de Boor) and
    normal equations are positive definite. A forward scan eliminates row by row with the
    `h` rows above; a backward scan substitutes. Differentiable through both scans.

    **Arguments:**

    - `band`: `band[i, j] = A[i, i - h + j]` (entries outside the matrix are zero).
    - `rhs`: right-hand sides, one column each.

    **Returns:**

    `x` of the shape of `rhs`.
    """
    half = (band.shape[1] - 1) // 2
    if half == 0:
        return rhs / band
    # The h previous rows of U (diagonal first) and their right-hand sides; identity rows
    # stand in above the matrix, where the band holds zeros to eliminate.
    upper0 = jnp.zeros((half, half + 1), band.dtype).at[:, 0].set(1.0)
    y0 = jnp.zeros((half, *rhs.shape[1:]), rhs.dtype)

    def eliminate(carry, row_and_rhs):
        upper, ys = carry
        row, y = row_and_rhs
        for i in range(half):  # column i of the row is the diagonal of upper[i]
            factor = row[i] / upper[i, 0]
            row = row.at[i : i + half + 1].add(-factor * upper[i])
            y = y - factor * ys[i]
        new_upper = row[half:]
        carry = (jnp.concatenate([upper[1:], new_upper[None]]), jnp.concatenate([ys[1:], y[None]]))
        return carry, (new_upper, y)

    _, (upper, y) = jax.lax.scan(eliminate, (upper0, y0), (band, rhs))

    def substitute(xs, upper_and_y):
        row, y = upper_and_y
        x = (y - jnp.tensordot(row[1:], xs, axes=1)) / row[0]
        return jnp.concatenate([x[None], xs[:-1]]), x

    x0 = jnp.zeros((half, *rhs.shape[1:]), rhs.dtype)
    _, x = jax.lax.scan(substitute, x0, (upper, y), reverse=True)
    return x


def collocation_solve(
    sites: Array, orders: np.ndarray, knots: Array, degree: int, rhs: Array
) -> Array:
    """Control points `P` with `C^(orders[k])(sites[k]) = rhs[k]` for every row `k`.

    The rows must be ordered so that row `k` involves control points `k - p .. k + p`
    (increasing sites, each derivative row next to its end), which makes the system banded;
    it is solved by `solve_banded`.
    """
    span, ders = ders_basis_funs(knots, degree, sites, int(orders.max()))
    count = sites.shape[0]
    funs = ders[np.arange(count), orders]
    band = band_rows(jnp.arange(count), span - degree, funs, count, degree)
    return solve_banded(band, rhs)
