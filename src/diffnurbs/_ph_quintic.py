"""Planar PH quintic Hermite interpolation (Farouki and Neff 1995).

A PH quintic has the hodograph `r'(t) = w(t)^2` with `w` a complex quadratic in Bernstein
form, `w(t) = w0 (1 - t)^2 + 2 w1 (1 - t) t + w2 t^2`. Interpolating the end points
`p0, p1` and end derivatives `d0, d1` gives `w0^2 = d0`, `w2^2 = d1` and
`int_0^1 w^2 dt = p1 - p0`, a quadratic in `w1`:

    w1 = -3/4 (w0 + w2) +- 1/4 sqrt(120 (p1 - p0) - 15 (d0 + d1) + 10 w0 w2).

With the sign of `w0` fixed (the overall sign of `w` does not change `w^2`), the two signs
of `w2` and the two of the square root give four distinct interpolants. Farouki and Neff
pick the one with the least bending energy `int kappa^2 ds`.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from ._curve import NURBSCurve
from ._ph_cubic import as_point, to_complex, to_real
from ._quadrature import integrate_panels
from ._validate import concrete, float_dtype

_PANELS = 4


class QuinticHermite(eqx.Module):
    """The four PH quintic Hermite interpolants of `quintic_hermite`, with their bending
    energies. Interpolant `2 j + k` takes `w2 = (-1)^j sqrt(d1)` and the sign `(-1)^k` of
    the square root in `w1` (principal square roots, `w0 = sqrt(d0)`)."""

    control_points: Float[Array, "4 6 2"]
    bending_energy: Float[Array, " 4"]

    @property
    def best(self) -> Int[Array, ""]:
        """Index of the interpolant with the least bending energy (Farouki and Neff's choice)."""
        return jnp.argmin(self.bending_energy)

    def curve(self, index: int | Int[Array, ""] | None = None) -> NURBSCurve:
        """Interpolant `index` (default: `best`) as a quintic Bezier `NURBSCurve` on [0, 1]."""
        index = self.best if index is None else index
        return NURBSCurve(self.control_points[index], 5)


def _bernstein_quadratic(w: Array, t: Array) -> tuple[Array, Array]:
    """`w(t)` and `w'(t)` of the complex quadratic with Bernstein coefficients `w`."""
    value = w[0] * (1 - t) ** 2 + 2 * w[1] * (1 - t) * t + w[2] * t**2
    slope = 2 * ((w[1] - w[0]) * (1 - t) + (w[2] - w[1]) * t)
    return value, slope


def _bending_energy(w: Array) -> Array:
    """`int kappa^2 ds = 4 int_0^1 Im(conj(w) w')^2 / |w|^6 dt`: for `r' = w^2`,
    `kappa = 2 Im(conj(w) w') / |w|^4` and `ds = |w|^2 dt`. An interpolant with a cusp
    (`w = 0` inside) has infinite energy: the quadrature then gives a huge value (`inf` if a
    node falls on the zero), so it is never the `best`."""

    def integrand(t):
        value, slope = _bernstein_quadratic(w, t)
        modulus2 = value.real**2 + value.imag**2
        regular = modulus2 > 0
        safe = jnp.where(regular, modulus2, 1.0)
        return jnp.where(regular, 4 * jnp.imag(jnp.conj(value) * slope) ** 2 / safe**3, jnp.inf)

    edges = jnp.linspace(0.0, 1.0, _PANELS + 1, dtype=w.real.dtype)
    return integrate_panels(integrand, edges[:-1], edges[1:])


def _check_nonzero(d: Array, name: str) -> Array:
    value = concrete(d)
    if value is None:
        return eqx.error_if(d, jnp.all(d == 0), f"{name} must be non-zero")
    if np.all(value == 0):
        raise ValueError(
            f"{name} must be a non-zero end derivative: w^2 = 0 puts a cusp at that end"
        )
    return d


def quintic_hermite(p0: ArrayLike, p1: ArrayLike, d0: ArrayLike, d1: ArrayLike) -> QuinticHermite:
    """The four planar PH quintics with `r(0) = p0`, `r(1) = p1`, `r'(0) = d0`, `r'(1) = d1`.

    Bezier control points (complex notation): `p0`, `p0 + w0^2 / 5`, `+ w0 w1 / 5`,
    `+ (2 w1^2 + w0 w2) / 15`, `+ w1 w2 / 5`, `+ w2^2 / 5` (the last is `p1`).

    **Arguments:**

    - `p0`, `p1`: end points, shape `(2,)`.
    - `d0`, `d1`: end derivatives, shape `(2,)`, non-zero.

    **Returns:**

    A `QuinticHermite`: `control_points` of shape `(4, 6, 2)`, `bending_energy` of shape
    `(4,)`, `best` the index of the least energy, `curve(index)` a `NURBSCurve`.
    """
    raw = [jnp.asarray(x) for x in (p0, p1, d0, d1)]
    dtype = float_dtype(*raw)
    p0, p1, d0, d1 = (
        as_point(x, n, dtype) for x, n in zip(raw, ("p0", "p1", "d0", "d1"), strict=True)
    )
    return _interpolants(p0, p1, _check_nonzero(d0, "d0"), _check_nonzero(d1, "d1"))


@eqx.filter_jit
def _interpolants(p0: Array, p1: Array, d0: Array, d1: Array) -> QuinticHermite:
    start, delta = to_complex(p0), to_complex(p1) - to_complex(p0)
    d0, d1 = to_complex(d0), to_complex(d1)
    w0 = jnp.sqrt(d0)
    w2 = jnp.sqrt(d1) * jnp.array([1.0, 1.0, -1.0, -1.0], dtype=d1.real.dtype)
    root = jnp.sqrt(120 * delta - 15 * (d0 + d1) + 10 * w0 * w2)
    w1 = -0.75 * (w0 + w2) + 0.25 * root * jnp.array([1.0, -1.0, 1.0, -1.0], dtype=w2.real.dtype)
    w0 = jnp.broadcast_to(w0, w1.shape)
    steps = jnp.stack(
        [w0**2 / 5, w0 * w1 / 5, (2 * w1**2 + w0 * w2) / 15, w1 * w2 / 5, w2**2 / 5], axis=-1
    )
    points = start + jnp.concatenate([jnp.zeros_like(w1)[:, None], jnp.cumsum(steps, -1)], -1)
    energy = jax.vmap(_bending_energy)(jnp.stack([w0, w1, w2], axis=-1))
    return QuinticHermite(to_real(points), energy)
