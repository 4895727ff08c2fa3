"""Adaptive Gauss-Legendre quadrature with static shapes, so it compiles and differentiates."""

import jax
import jax.numpy as jnp
import numpy as np

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(16)
# Nodes on [0, 1] for the whole panel and for its two halves, in one array: the
# integrand is then traced once per use, not three times.
_UNIT_NODES = np.concatenate([(_NODES + 1) / 2, (_NODES + 1) / 4, (_NODES + 3) / 4])


def _halves(integrand, lo, hi):
    """Integral over each panel from its two halves, and the error estimate |halves - whole|."""
    width = hi - lo
    x = lo[:, None] + width[:, None] * jnp.asarray(_UNIT_NODES, dtype=lo.dtype)
    values = integrand(x).reshape(lo.shape[0], 3, -1) @ jnp.asarray(_WEIGHTS, dtype=lo.dtype)
    whole = 0.5 * width * values[:, 0]
    halves = 0.25 * width * (values[:, 1] + values[:, 2])
    return halves, jnp.abs(halves - whole)


def _panel_ends(lo, hi, owner, start, stop):
    """Sub-panels given as fractions `[start, stop]` of the original panel `owner`."""
    width = hi[owner] - lo[owner]
    return lo[owner] + start * width, lo[owner] + stop * width


def refined_panels(integrand, lo, hi, rounds=8):
    """The sub-panels of `[lo_i, hi_i]` after adaptive bisection, as two arrays of ends.

    Each round bisects the `len(lo)` sub-panels with the largest error estimate, so a
    panel holding a sharp feature is halved once per round. Sub-panels are kept as
    fractions of the original panels: the refinement is a discrete choice, and integrals
    over the sub-panels stay smooth functions of `lo`, `hi` and the integrand, so `grad`
    is exact. Array sizes depend only on `len(lo)` and `rounds`, so this works under `jit`.

    **Arguments:**

    - `integrand`: vectorised function of the parameters, any shape to the same shape.
    - `lo`, `hi`: 1-D arrays of panel ends (empty panels stay empty).
    - `rounds`: number of refinement rounds.

    **Returns:**

    `(a, b)`: the `len(lo) * (rounds + 1)` sub-panels' ends, in no particular order.
    """
    count = lo.shape[0]
    size = count * (rounds + 1)
    owner = jnp.concatenate([jnp.arange(count), jnp.zeros(size - count, dtype=int)])
    start = jnp.zeros(size, dtype=lo.dtype)
    stop = jnp.concatenate([jnp.ones(count, lo.dtype), jnp.zeros(size - count, lo.dtype)])

    def refine(round_index, state):
        owner, start, stop = state
        errors = _halves(integrand, *_panel_ends(lo, hi, owner, start, stop))[1]
        worst = jax.lax.top_k(errors, count)[1]
        middle = 0.5 * (start[worst] + stop[worst])
        free = count * (round_index + 1)
        owner = jax.lax.dynamic_update_slice(owner, owner[worst], (free,))
        start = jax.lax.dynamic_update_slice(start, middle, (free,))
        stop = jax.lax.dynamic_update_slice(stop.at[worst].set(middle), stop[worst], (free,))
        return owner, start, stop

    owner, start, stop = jax.lax.stop_gradient(
        jax.lax.fori_loop(0, rounds, refine, (owner, start, stop))
    )
    return _panel_ends(lo, hi, owner, start, stop)


def panel_integrals(integrand, a, b):
    """The integral of `integrand` over each panel `[a_i, b_i]` (two 16-point rules, one
    per half)."""
    return _halves(integrand, a, b)[0]


def integrate_panels(integrand, lo, hi, rounds=8):
    """Sum of the integrals of `integrand` over the panels `[lo_i, hi_i]`, refined adaptively
    (`refined_panels`).

    **Arguments:**

    - `integrand`: vectorised function of the parameters, any shape to the same shape.
    - `lo`, `hi`: 1-D arrays of panel ends (empty panels contribute zero).
    - `rounds`: number of refinement rounds.

    **Returns:**

    The scalar integral.
    """
    return jnp.sum(panel_integrals(integrand, *refined_panels(integrand, lo, hi, rounds)))


def gauss_legendre(integrand, a, b):
    """The 16-point Gauss-Legendre rule on each interval `[a_i, b_i]` (arrays of one shape)."""
    nodes = jnp.asarray((_NODES + 1) / 2, dtype=a.dtype)
    x = a[..., None] + (b - a)[..., None] * nodes
    return 0.5 * (b - a) * (integrand(x) @ jnp.asarray(_WEIGHTS, dtype=a.dtype))
