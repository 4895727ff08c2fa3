"""Planar PH cubics as cardinal spline segments (seed 004): the direct problem, exact length,
speed, the segment as a Bezier curve, and exact rational offsets.

A PH cubic has the hodograph `P'(u) = (f^2 - v^2, 2 f v)` with `f = a0 + a1 u`,
`v = b0 + b1 u` (seed eq. 2, 4, 7), so `|P'(u)| = f^2 + v^2` (eq. 3). In complex notation,
with `w(u) = f + i v = alpha0 + alpha1 u` (`alpha0 = a0 + i b0`, `alpha1 = a1 + i b1`),
the hodograph is simply `P'(u) = w(u)^2`. Everything here is written in that form: it
turns the seed's six real equations (8), (9) into three complex ones.

The segment of the cardinal spline on `P_{k-1}, P_k, P_{k+1}, P_{k+2}` (eq. 5) is the
Hermite segment from `P_k` to `P_{k+1}` with end derivatives `s (P_{k+1} - P_{k-1})` and
`s (P_{k+2} - P_k)`, `s = (1 - tension) / 2`. Matching its derivative (eq. 6) with `w^2`
term by term (eq. 8) gives the direct problem (eq. 9):

    P_{k+1} = P_{k-1} + w(0)^2 / s,
    P_k     = P_{k+1} - (alpha0^2 + alpha0 alpha1 + alpha1^2 / 3),   (the chord, int_0^1 w^2)
    P_{k+2} = P_k + w(1)^2 / s.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._arclength import increasing_root
from ._bezier import bezier_matrix, subdivide
from ._cubic import hermite_segment
from ._curve import NURBSCurve
from ._misc import safe_divide
from ._rational import from_homogeneous
from ._validate import check_degree, check_finite, check_parameter, concrete, float_dtype


def as_coeffs(coeffs: ArrayLike, batched: bool = True) -> Array:
    """`(a0, a1, b0, b1)` as a float array of shape `(..., 4)` (`(4,)` if not `batched`)."""
    coeffs = jnp.asarray(coeffs)
    coeffs = coeffs.astype(float_dtype(coeffs))
    if coeffs.ndim < 1 or coeffs.shape[-1] != 4 or (not batched and coeffs.ndim != 1):
        layout = "(..., 4)" if batched else "(4,)"
        raise ValueError(f"coeffs must have shape {layout}: (a0, a1, b0, b1), got {coeffs.shape}")
    return check_finite(coeffs, "coeffs")


def as_point(point: ArrayLike, name: str, dtype=None) -> Array:
    """A planar point of shape `(2,)`, finite, as a float array."""
    point = jnp.asarray(point)
    if point.shape != (2,):
        raise ValueError(f"{name} must be a planar point of shape (2,), got {point.shape}")
    return check_finite(point.astype(dtype or float_dtype(point)), name)


def tension_scale(tension: ArrayLike, dtype) -> Array:
    """The seed's `s = (1 - tension) / 2`; `ValueError` when it is zero (tension 1)."""
    tension = jnp.asarray(tension, dtype=dtype)
    if tension.ndim != 0:
        raise ValueError(f"tension must be a scalar, got shape {tension.shape}")
    s = (1 - tension) / 2
    value = concrete(s)
    if value is None:
        return eqx.error_if(s, ~jnp.isfinite(s) | (s == 0), "tension must be finite and != 1")
    if not np.isfinite(value):
        raise ValueError(f"tension must be finite, got {concrete(tension)}")
    if value == 0:
        raise ValueError(
            "tension 1 makes s = (1 - tension) / 2 = 0: every tangent of the cardinal spline "
            "vanishes and eq. 9 divides by s; expected tension != 1"
        )
    return s


def to_complex(points: Array) -> Array:
    return points[..., 0] + 1j * points[..., 1]


def to_real(z: Array) -> Array:
    return jnp.stack([z.real, z.imag], axis=-1)


def alphas(coeffs: Array) -> tuple[Array, Array]:
    """`alpha0 = a0 + i b0`, `alpha1 = a1 + i b1`: `w(u) = f(u) + i v(u) = alpha0 + alpha1 u`."""
    return coeffs[..., 0] + 1j * coeffs[..., 2], coeffs[..., 1] + 1j * coeffs[..., 3]


def chord(alpha0: Array, alpha1: Array) -> Array:
    """`P(1) - P(0) = int_0^1 w(u)^2 du = alpha0^2 + alpha0 alpha1 + alpha1^2 / 3`."""
    return alpha0 * alpha0 + alpha0 * alpha1 + alpha1 * alpha1 / 3


def cardinal_points(
    coeffs: ArrayLike, p_prev: ArrayLike, tension: ArrayLike = 0.0
) -> Float[Array, "... 4 2"]:
    """The direct problem (seed eq. 9): the four cardinal-spline points of a PH cubic.

    Given `f(u) = a0 + a1 u`, `v(u) = b0 + b1 u` and the point `P_{k-1}`, the segment of
    eq. 5 on the returned points has the hodograph `(f^2 - v^2, 2 f v)` of eq. 7, so it is a
    PH curve with speed `f^2 + v^2`.

    **Arguments:**

    - `coeffs`: `(a0, a1, b0, b1)`, shape `(..., 4)`.
    - `p_prev`: the point `P_{k-1}`, shape `(..., 2)` (broadcast against `coeffs`).
    - `tension`: the cardinal spline's tension `t` (scalar, `!= 1`); `s = (1 - t) / 2`,
      and `t = 0` is the Catmull-Rom spline.

    **Returns:**

    `(P_{k-1}, P_k, P_{k+1}, P_{k+2})`, shape `(..., 4, 2)`.
    """
    coeffs = as_coeffs(coeffs)
    p_prev = jnp.asarray(p_prev)
    if p_prev.ndim < 1 or p_prev.shape[-1] != 2:
        raise ValueError(f"p_prev must have shape (..., 2), got {p_prev.shape}")
    p_prev = check_finite(p_prev.astype(float_dtype(coeffs, p_prev)), "p_prev")
    s = tension_scale(tension, p_prev.dtype)
    alpha0, alpha1 = alphas(coeffs)
    prev = to_complex(p_prev)
    nxt = prev + alpha0 * alpha0 / s
    start = nxt - chord(alpha0, alpha1)
    after = start + (alpha0 + alpha1) ** 2 / s
    prev, start, nxt, after = jnp.broadcast_arrays(prev, start, nxt, after)
    return to_real(jnp.stack([prev, start, nxt, after], axis=-1))


def speed(coeffs: ArrayLike, u: ArrayLike) -> Float[Array, "..."]:
    """The speed `|P'(u)| = f(u)^2 + v(u)^2` of the PH cubic (seed eq. 3), a polynomial.

    **Arguments:**

    - `coeffs`: `(a0, a1, b0, b1)`, shape `(..., 4)`.
    - `u`: parameters in [0, 1]; `coeffs[..., k]` and `u` broadcast together.

    **Returns:**

    The speeds, shape `broadcast(coeffs.shape[:-1], u.shape)`.
    """
    coeffs = as_coeffs(coeffs)
    u = jnp.asarray(u, dtype=coeffs.dtype)
    check_parameter(u, 0.0, 1.0)
    a0, a1, b0, b1 = (coeffs[..., k] for k in range(4))
    return (a0 + a1 * u) ** 2 + (b0 + b1 * u) ** 2


def arc_length(coeffs: ArrayLike) -> Float[Array, "..."]:
    """The exact length `int_0^1 (f^2 + v^2) du` of the PH cubic, in closed form.

    `L = (a0^2 + b0^2) + (a0 a1 + b0 b1) + (a1^2 + b1^2) / 3`: the integral of the
    polynomial speed, no square root and no quadrature. (Seed eq. 11 is not this: it is
    `x(u) - x_k`, the integral of `x'(u)` alone; see the chapter.)

    **Arguments:**

    - `coeffs`: `(a0, a1, b0, b1)`, shape `(..., 4)`.

    **Returns:**

    The lengths, shape `coeffs.shape[:-1]`.
    """
    coeffs = as_coeffs(coeffs)
    a0, a1, b0, b1 = (coeffs[..., k] for k in range(4))
    return a0**2 + b0**2 + (a0 * a1 + b0 * b1) + (a1**2 + b1**2) / 3


def parameter_at_length(coeffs: ArrayLike, s: ArrayLike) -> Float[Array, "..."]:
    """The parameter at arc length `s` from the start of the PH cubic, exactly: the root in
    [0, 1] of the cubic polynomial `s(u) = c0 u + c1 u^2 / 2 + c2 u^3 / 3`, the integral of
    the speed `c0 + c1 u + c2 u^2 = f^2 + v^2`. No quadrature: Newton's method on the
    polynomial (safeguarded by bisection where the speed vanishes), to rounding.
    `jax.grad` reaches `s` and `coeffs` (implicit function theorem).

    **Arguments:**

    - `coeffs`: `(a0, a1, b0, b1)`, shape `(..., 4)`.
    - `s`: lengths in `[0, arc_length(coeffs)]`; `coeffs[..., k]` and `s` broadcast together.

    **Returns:**

    The parameters, shape `broadcast(coeffs.shape[:-1], s.shape)`.
    """
    coeffs = as_coeffs(coeffs)
    s = jnp.asarray(s, dtype=coeffs.dtype)
    total = arc_length(coeffs)
    values, lengths = concrete(s), concrete(total)
    if values is not None and lengths is not None:
        values, lengths = np.broadcast_arrays(values, lengths)
        outside = ~((values >= 0) & (values <= lengths * (1 + 1e-12)))
        if np.any(outside):
            where = tuple(int(i) for i in np.argwhere(outside)[0])
            raise ValueError(
                f"s must lie in [0, {lengths[where]}] (0 to the curve's length), "
                f"got {values[where]}" + (f" at index {where}" if where else "")
            )
    a0, a1, b0, b1 = (coeffs[..., k] for k in range(4))
    c0, c1, c2 = a0**2 + b0**2, 2 * (a0 * a1 + b0 * b1), a1**2 + b1**2
    c0, c1, c2, s, total = jnp.broadcast_arrays(c0, c1, c2, s, total)

    def length(u, c0, c1, c2):
        return u * (c0 + u * (c1 / 2 + u * c2 / 3))

    def speed(u, c0, c1, c2):
        return c0 + u * (c1 + u * c2)

    fixed = [jax.lax.stop_gradient(x) for x in (c0, c1, c2, s)]
    tolerance = 8 * jnp.finfo(s.dtype).eps * jnp.maximum(jax.lax.stop_gradient(total), 1.0)
    u = increasing_root(
        lambda u: length(u, *fixed[:3]) - fixed[3],
        lambda u: speed(u, *fixed[:3]),
        jnp.clip(safe_divide(fixed[3], jax.lax.stop_gradient(total)), 0.0, 1.0),
        jnp.zeros_like(s),
        jnp.ones_like(s),
        tolerance,
    )
    # One more Newton step, outside the loop: its derivative is the implicit-function one.
    u = u - safe_divide(length(u, c0, c1, c2) - s, speed(u, c0, c1, c2))
    return jnp.where(u < 0, 0.0, jnp.where(u > 1, 1.0, u))


def equal_arc_parameters(coeffs: ArrayLike, count: int) -> Float[Array, "... count"]:
    """`count` parameters, both ends included, that cut the PH cubic into pieces of equal
    length, exactly (`parameter_at_length`; no quadrature).

    **Arguments:**

    - `coeffs`: `(a0, a1, b0, b1)`, shape `(..., 4)`.
    - `count`: the number of parameters, `>= 2`.

    **Returns:**

    Increasing parameters from 0 to 1, shape `coeffs.shape[:-1] + (count,)`.
    """
    count = check_degree(count, minimum=2, name="count")
    coeffs = as_coeffs(coeffs)
    fractions = jnp.linspace(0.0, 1.0, count, dtype=coeffs.dtype)
    s = arc_length(coeffs)[..., None] * fractions
    u = parameter_at_length(coeffs[..., None, :], s)
    return u.at[..., 0].set(0.0).at[..., -1].set(1.0)


def ph_cubic(coeffs: ArrayLike, start: ArrayLike) -> NURBSCurve:
    """The PH cubic with hodograph `(f^2 - v^2, 2 f v)` starting at `start`, as a Bezier curve.

    Its Bezier control points are `b0 = start`, `b1 = b0 + w(0)^2 / 3`,
    `b2 = b1 + w(0) w(1) / 3`, `b3 = b2 + w(1)^2 / 3` (complex notation): the Hermite segment
    with end derivatives `w(0)^2`, `w(1)^2` and chord `int_0^1 w^2`.

    **Arguments:**

    - `coeffs`: `(a0, a1, b0, b1)`, shape `(4,)`.
    - `start`: the point `P(0)`, shape `(2,)`.

    **Returns:**

    A cubic `NURBSCurve` (4 control points, domain [0, 1]).
    """
    coeffs = as_coeffs(coeffs, batched=False)
    start = as_point(start, "start", float_dtype(coeffs, jnp.asarray(start)))
    alpha0, alpha1 = alphas(coeffs.astype(start.dtype))
    end = to_complex(start) + chord(alpha0, alpha1)
    return hermite_segment(start, to_real(end), to_real(alpha0**2), to_real((alpha0 + alpha1) ** 2))


def cardinal_curve(coeffs: ArrayLike, p_prev: ArrayLike, tension: ArrayLike = 0.0) -> NURBSCurve:
    """The cardinal spline segment of eq. 5 on `cardinal_points(coeffs, p_prev, tension)`.

    This is the Hermite segment from `P_k` to `P_{k+1}` with end derivatives
    `s (P_{k+1} - P_{k-1})` and `s (P_{k+2} - P_k)`; it equals `ph_cubic(coeffs, P_k)`.

    **Arguments:**

    - `coeffs`: `(a0, a1, b0, b1)`, shape `(4,)`.
    - `p_prev`: `P_{k-1}`, shape `(2,)`.
    - `tension`: scalar `!= 1`.

    **Returns:**

    A cubic `NURBSCurve` (4 control points, domain [0, 1]) from `P_k` to `P_{k+1}`.
    """
    coeffs = as_coeffs(coeffs, batched=False)
    as_point(p_prev, "p_prev")
    points = cardinal_points(coeffs, p_prev, tension)
    s = tension_scale(tension, points.dtype)
    before, start, end, after = points
    return hermite_segment(start, end, s * (end - before), s * (after - start))


def _power_product(a: Array, b: Array) -> Array:
    """Ascending power coefficients of the product of two polynomials (a convolution)."""
    out = jnp.zeros(a.shape[0] + b.shape[0] - 1, dtype=jnp.result_type(a, b))
    for i in range(a.shape[0]):
        out = out.at[i : i + b.shape[0]].add(a[i] * b)
    return out


def _squared_modulus(z: Array) -> Array:
    return z.real**2 + z.imag**2


def _offset_split(alpha0: Array, alpha1: Array) -> Array:
    """A parameter splitting `[0, 1]` so that `w` turns by less than 90 degrees on each part.

    On an interval `[p, q]` the Bernstein coefficients of `sigma = |w|^2` are `|w(p)|^2`,
    `Re(w(p) conj(w(q)))`, `|w(q)|^2`: all positive when `w` turns by less than 90 degrees.
    `w(u)` runs along a straight line that misses the origin, so it turns by less than
    180 degrees over [0, 1]: when it turns by more than 90, the point where `w` points along
    the bisector of `w(0)` and `w(1)` halves the turn.
    """
    beta = alpha0 + alpha1
    bisector = alpha0 / jnp.abs(alpha0) + beta / jnp.abs(beta)
    across = jnp.imag(jnp.conj(bisector) * alpha1)
    wide = jnp.real(alpha0 * jnp.conj(beta)) <= 0
    # Double where: `across` is zero for a straight line (which never turns, so is not wide).
    safe = jnp.where(wide, across, 1.0)
    return jnp.where(wide, -jnp.imag(jnp.conj(bisector) * alpha0) / safe, 0.5)


def _check_regular(alpha0: Array, alpha1: Array) -> Array:
    """`alpha0`, unchanged, after checking that `w` has no zero on [0, 1] (no cusp)."""
    # |w(u)|^2 is a convex quadratic: its minimum on [0, 1] is at the clipped vertex.
    steep = _squared_modulus(alpha1) > 0
    safe = jnp.where(steep, _squared_modulus(alpha1), 1.0)
    vertex = jnp.where(steep, -jnp.real(alpha0 * jnp.conj(alpha1)) / safe, 0.0)
    lowest = jnp.abs(alpha0 + alpha1 * jnp.clip(vertex, 0.0, 1.0))
    scale = jnp.abs(alpha0) + jnp.abs(alpha1)
    value = concrete(lowest)
    if value is None:
        return eqx.error_if(alpha0, lowest <= 0, "offset_curve needs a curve without cusps")
    if not value > np.finfo(value.dtype).eps * concrete(scale):
        raise ValueError(
            "offset_curve needs a regular PH cubic: its speed f^2 + v^2 vanishes at "
            f"u = {float(np.clip(concrete(vertex), 0, 1))} (a cusp, where the normal is undefined)"
        )
    return alpha0


def offset_curve(coeffs: ArrayLike, start: ArrayLike, distance: ArrayLike) -> NURBSCurve:
    """The exact offset `P(u) + d N(u)` of a PH cubic, as a rational curve of degree 5.

    `N(u)` is the unit normal to the left of the direction of travel, `i P'(u) / |P'(u)|`
    in complex notation. For a PH curve `|P'| = sigma = f^2 + v^2` is a polynomial, so

        P_d(u) = (sigma(u) P(u) + i d w(u)^2) / sigma(u)

    is rational: numerator of degree 5, denominator `sigma` of degree 2 (raised to 5).
    The homogeneous polynomial `(sigma P + i d w^2, sigma)` is converted to Bernstein form
    with `bezier_matrix(5)` and split at one parameter (see `_offset_split`), so that every
    weight is positive: the result is two rational Bezier pieces of degree 5 joined at that
    knot, together exactly the offset, parametrised by the same `u` as `P`.

    **Arguments:**

    - `coeffs`: `(a0, a1, b0, b1)`, shape `(4,)`, of a regular PH cubic (speed `> 0` on
      [0, 1]; `ValueError` at a cusp).
    - `start`: `P(0)`, shape `(2,)`.
    - `distance`: signed scalar offset distance `d` (positive: to the left).

    **Returns:**

    A rational `NURBSCurve` of degree 5, 11 control points, knots
    `[0] * 6 + [u*] * 5 + [1] * 6`, domain [0, 1], with `P_d(u)` at every `u`.
    """
    coeffs = as_coeffs(coeffs, batched=False)
    start = as_point(start, "start", float_dtype(coeffs, jnp.asarray(start)))
    dtype = start.dtype
    distance = jnp.asarray(distance, dtype=dtype)
    if distance.ndim != 0:
        raise ValueError(f"distance must be a scalar, got shape {distance.shape}")
    distance = check_finite(distance, "distance")
    alpha0, alpha1 = alphas(coeffs.astype(dtype))
    return _offset(_check_regular(alpha0, alpha1), alpha1, start, distance)


@eqx.filter_jit
def _offset(alpha0: Array, alpha1: Array, start: Array, distance: Array) -> NURBSCurve:
    dtype = start.dtype
    # Ascending power coefficients of P(u), of P'(u) = w^2 and of sigma = |w|^2.
    curve = jnp.stack([to_complex(start), alpha0**2, alpha0 * alpha1, alpha1**2 / 3])
    hodograph = jnp.stack([alpha0**2, 2 * alpha0 * alpha1, alpha1**2, jnp.zeros_like(alpha0)])
    cross = 2 * jnp.real(alpha0 * jnp.conj(alpha1))
    sigma = jnp.stack([_squared_modulus(alpha0), cross, _squared_modulus(alpha1)])
    numerator = _power_product(sigma.astype(curve.dtype), curve)
    numerator = numerator.at[:4].add(1j * distance * hodograph)
    weight = jnp.concatenate([sigma, jnp.zeros(3, dtype)])
    power = jnp.stack([numerator.real, numerator.imag, weight], axis=-1)  # ascending powers
    homogeneous = jnp.linalg.solve(bezier_matrix(5, dtype), power[::-1])
    split = _offset_split(alpha0, alpha1)
    left, right = subdivide(homogeneous, split)
    points = jnp.concatenate([left, right[1:]])
    knots = jnp.concatenate(
        [jnp.zeros(6, dtype), jnp.full(5, split, dtype=dtype), jnp.ones(6, dtype)]
    )
    return NURBSCurve(from_homogeneous(points), 5, knots, points[:, -1])
