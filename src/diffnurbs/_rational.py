"""Homogeneous coordinates and the Leibniz rule for derivatives of rational maps.

A rational curve is the projection of a polynomial curve `Cw = (w C, w)` one dimension
up. Its derivatives follow from those of `A = w C` and `w` (seed 000 eq. 1.26,
NURBS Book A4.2 and A4.4) without differentiating a quotient.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float


def to_homogeneous(points: ArrayLike, weights: ArrayLike) -> Float[Array, "... dim+1"]:
    """`(w P, w)`: weighted points with the weight appended as a last coordinate.

    **Arguments:**

    - `points`: array of shape `(..., dim)`.
    - `weights`: array of shape `(...)`.

    **Returns:**

    Array of shape `(..., dim + 1)`.
    """
    return _to_homogeneous(jnp.asarray(points), jnp.asarray(weights))


# Compiled as one program: eagerly, each operation would compile on its own for every
# shape of control net.
@jax.jit
def _to_homogeneous(points, weights):
    return jnp.concatenate([points * weights[..., None], weights[..., None]], axis=-1)


def from_homogeneous(points: ArrayLike) -> Float[Array, "... dim"]:
    """The projection `(x, w) -> x / w`, inverse of `to_homogeneous`.

    **Arguments:**

    - `points`: array of shape `(..., dim + 1)`, last coordinate the weight.

    **Returns:**

    Array of shape `(..., dim)`.
    """
    return _from_homogeneous(jnp.asarray(points))


@jax.jit
def _from_homogeneous(points):
    return points[..., :-1] / points[..., -1:]


def rational_curve_derivatives(
    a_ders: Float[Array, "... k dim"], w_ders: Float[Array, "... k"]
) -> Float[Array, "... k dim"]:
    """Derivatives of `C = A / w` from those of `A` and `w` (seed Listing 1.6, A4.2).

    `C^(k) = (A^(k) - sum_{i=1}^{k} binom(k, i) w^(i) C^(k-i)) / w`.

    **Arguments:**

    - `a_ders`: `A^(0..d)`, shape `(..., d + 1, dim)`.
    - `w_ders`: `w^(0..d)`, shape `(..., d + 1)`.

    **Returns:**

    `C^(0..d)`, shape `(..., d + 1, dim)`.
    """
    count = a_ders.shape[-2]
    ders = _quotient_rule(
        [a_ders[..., k, :] for k in range(count)], [w_ders[..., k, None] for k in range(count)]
    )
    return jnp.stack(ders, axis=-2)


def _quotient_rule(a_ders: list, w_ders: list) -> list:
    """`C^(k) = (A^(k) - sum_{i=1}^{k} binom(k, i) w^(i) C^(k-i)) / w` for lists of
    broadcastable arrays `A^(k)`, `w^(k)`; one reciprocal of `w`, one product per term."""
    reciprocal = 1 / w_ders[0]
    ders = []
    for k, v in enumerate(a_ders):
        for i in range(1, k + 1):
            v = v - math.comb(k, i) * w_ders[i] * ders[k - i]
        ders.append(v * reciprocal)
    return ders


def rational_columns(a_ders: list[list[Array]], w_ders: list[Array]) -> list[list[Array]]:
    """`rational_curve_derivatives` on one array per order and coordinate: `a_ders[k][d]`
    and `w_ders[k]` give `C^(k)_d` as `result[k][d]`.

    XLA fuses each element of a stacked array with everything it depends on, so a caller
    that has its derivatives as separate arrays keeps them apart until its result is
    stacked; multiplying by `1 / w` once keeps one division per point.
    """
    by_coordinate = [
        _quotient_rule([row[d] for row in a_ders], w_ders) for d in range(len(a_ders[0]))
    ]
    return [list(row) for row in zip(*by_coordinate, strict=True)]


def rational_surface_derivatives(
    a_ders: Float[Array, "... k l dim"], w_ders: Float[Array, "... k l"]
) -> Float[Array, "... k l dim"]:
    """Mixed partial derivatives of `S = A / w` (NURBS Book A4.4, for every k and l).

    **Arguments:**

    - `a_ders`: `d^(k+l) A / du^k dv^l`, shape `(..., K + 1, L + 1, dim)`.
    - `w_ders`: the same for `w`, shape `(..., K + 1, L + 1)`.

    **Returns:**

    The derivatives of `S`, shape `(..., K + 1, L + 1, dim)`.
    """
    rows, cols = a_ders.shape[-3], a_ders.shape[-2]
    skl = [[None] * cols for _ in range(rows)]
    for k in range(rows):
        for l in range(cols):
            v = a_ders[..., k, l, :]
            for i in range(k + 1):
                for j in range(l + 1):
                    if i == j == 0:
                        continue
                    coeff = math.comb(k, i) * math.comb(l, j)
                    v = v - coeff * w_ders[..., i, j, None] * skl[k - i][l - j]
            skl[k][l] = v / w_ders[..., 0, 0, None]
    return jnp.stack([jnp.stack(row, axis=-2) for row in skl], axis=-3)


class AbstractRationalSpline(eqx.Module):
    """What curves and surfaces share: control points, optional weights, homogeneous form."""

    control_points: eqx.AbstractVar[Array]
    weights: eqx.AbstractVar[Array | None]

    @property
    def rational(self) -> bool:
        """True when the spline has weights (None means a non-rational B-spline)."""
        return self.weights is not None

    @property
    def dim(self) -> int:
        """Dimension of the space the control points live in."""
        return self.control_points.shape[-1]

    def homogeneous_points(self) -> Array:
        """Control points as `(w P, w)`; the plain points when the spline is not rational."""
        if self.weights is None:
            return self.control_points
        return to_homogeneous(self.control_points, self.weights)
