"""Knot vectors."""

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._validate import check_control_count, check_degree


def clamped_knots(
    n_control: int, degree: int, domain=(0.0, 1.0), dtype=None
) -> Float[Array, " n+p+1"]:
    """Clamped uniform knot vector: `degree + 1` equal knots at each end, interior evenly spaced.

    **Arguments:**

    - `n_control`: number of control points `n + 1`.
    - `degree`: the degree `p`.
    - `domain`: `(a, b)`, the parameter interval.
    - `dtype`: floating dtype; the default float type when None.

    **Returns:**

    Array of `n_control + degree + 1` knots.
    """
    degree = check_degree(degree)
    check_control_count(n_control, degree)
    a, b = domain
    interior = jnp.linspace(0.0, 1.0, n_control - degree + 1, dtype=dtype)
    knots = jnp.concatenate(
        [jnp.zeros(degree, dtype=interior.dtype), interior, jnp.ones(degree, dtype=interior.dtype)]
    )
    return a + (b - a) * knots
