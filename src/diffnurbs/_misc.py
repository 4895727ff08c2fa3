"""Numeric helpers whose gradients stay finite where the plain formulas give NaN or inf.

Each uses the double `where`: the branch that is not taken never sees the bad value, so
its gradient is not computed from a division by zero or a square root at zero.
"""

import jax.numpy as jnp
from jaxtyping import Array


def safe_divide(num: Array, den: Array) -> Array:
    """`num / den`, and 0 where `den == 0` (the 0/0 = 0 convention of the B-spline
    recursions), with a finite gradient there."""
    zero = den == 0
    return jnp.where(zero, 0.0, num / jnp.where(zero, 1.0, den))


def safe_sqrt(x: Array) -> Array:
    """Square root with a zero (not infinite) gradient at zero; negatives map to zero."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def safe_norm(x: Array, axis: int = -1) -> Array:
    """Euclidean norm whose gradient is zero, not NaN, at the zero vector."""
    return safe_sqrt(jnp.sum(x * x, axis=axis))


def safe_normalize(x: Array) -> Array:
    """`x / |x|` along the last axis; the zero vector maps to zero."""
    norm = safe_norm(x)[..., None]
    return jnp.where(norm > 0, x / jnp.where(norm > 0, norm, 1.0), 0.0)


def clamp_to_domain(u: Array, lower: Array, upper: Array) -> Array:
    """`u` clipped to `[lower, upper]`.

    `where` rather than `jnp.clip`: at `u == lower` the gradient passes to `u` whole
    (`jnp.clip` would split it between `u` and the bound).
    """
    return jnp.where(u < lower, lower, jnp.where(u > upper, upper, u))
