"""The inverse problem of seed 004: a PH cardinal segment through three given points.

Given `P_{k-1}, P_k, P_{k+1}` and the tension, seed eq. 8 is six real equations in
`a0, a1, b0, b1` and the unknown `P_{k+2}`. In complex form (`w = alpha0 + alpha1 u`,
`s = (1 - tension) / 2`, chord `D = P_{k+1} - P_k`) it reads

    alpha0^2 = s (P_{k+1} - P_{k-1}),     alpha0 alpha1 + alpha1^2 / 3 = D - alpha0^2,

plus one equation fixing `P_{k+2} = P_k + w(1)^2 / s`. So `alpha0 = +-sqrt(s (P_{k+1} -
P_{k-1}))` and, for each sign, `alpha1` solves a quadratic: four solutions `(alpha0, alpha1)`
in pairs `(alpha0, alpha1), (-alpha0, -alpha1)` with the same `w^2`, hence the same curve.
Generically there are exactly two distinct curves. In terms of `beta = w(1)`:

    beta = (-alpha0 +- sqrt(3 (4 D - alpha0^2))) / 2,

and the two curves coincide when `4 D = alpha0^2`, i.e. `4 (P_{k+1} - P_k) =
s (P_{k+1} - P_{k-1})`. The two `beta` sum to `-alpha0`, which makes the two arc lengths
equal: `L = (|alpha0|^2 + Re(alpha0 conj(beta)) + |beta|^2) / 3` and
`Re(alpha0 conj(beta_1)) + |beta_1|^2 = Re(conj(beta_1) (alpha0 + beta_1)) =
-Re(conj(beta_1) beta_2)`, symmetric in the two roots, so `L = (|alpha0|^2 -
Re(conj(beta_1) beta_2)) / 3` for both: the two curves have the same length and differ
in shape.

`solve_cardinal` solves eq. 8 as the seed does, numerically: Newton's method (optimistix)
from 16 starts, after moving `P_k` to the origin and scaling the points to unit size. The
equation for `alpha0` does not involve `alpha1`, so its Newton iterates converge to the root
`+-sqrt` on the side of the start (two starts 90 degrees apart, one of them well inside);
the starts of `alpha1` lie on a circle wide enough to be on both sides of the line that
separates the basins of the two roots of the quadratic. `solve_cardinal_closed_form`
evaluates the formula above; the tests check one against the other.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float

from ._cubic import cubic_matrix
from ._ph_cubic import alphas, as_point, tension_scale, to_complex, to_real
from ._validate import concrete, float_dtype

_FRAME_NAMES = ("p_prev", "p_k", "p_next")
_ALPHA1_STARTS = 8


def cardinal_matrix(s: Array) -> Array:
    """`M(s)` with `P(u) = [u^3, u^2, u, 1] @ M(s) @ (P_{k-1}, P_k, P_{k+1}, P_{k+2})` (eq. 5).

    The Hermite form of the segment: `(P_k, P_{k+1}, s (P_{k+1} - P_{k-1}), s (P_{k+2} - P_k))`
    is a linear map of the four points. At `s = 1/2` this is the Catmull-Rom matrix.
    """
    zero, one = jnp.zeros_like(s), jnp.ones_like(s)
    hermite_geometry = jnp.stack(
        [
            jnp.stack([zero, one, zero, zero]),
            jnp.stack([zero, zero, one, zero]),
            jnp.stack([-s, zero, s, zero]),
            jnp.stack([zero, -s, zero, s]),
        ]
    )
    return cubic_matrix("hermite", s.dtype) @ hermite_geometry


def eq8_residual(unknowns: Array, args: tuple[Array, Array]) -> Array:
    """Seed eq. 8 as six real residuals of `(a0, a1, b0, b1, x_{k+2}, y_{k+2})`.

    The cubic's power coefficients `[c3, c2, c1, c0] = M(s) @ frame` give
    `P'(u) = c1 + 2 c2 u + 3 c3 u^2`; eq. 8 equates them with `w^2 = alpha0^2 +
    2 alpha0 alpha1 u + alpha1^2 u^2`.
    """
    known, s = args  # known: complex (P_{k-1}, P_k, P_{k+1})
    alpha0, alpha1 = alphas(unknowns[:4])
    frame = jnp.concatenate([known, (unknowns[4] + 1j * unknowns[5])[None]])
    c3, c2, c1, _ = cardinal_matrix(s) @ frame
    residual = jnp.stack([alpha0**2 - c1, alpha0 * alpha1 - c2, alpha1**2 - 3 * c3])
    return jnp.concatenate([residual.real, residual.imag])


def frame_points(p_prev: ArrayLike, p_k: ArrayLike, p_next: ArrayLike, tension: ArrayLike):
    """The three given points as a `(3, 2)` array and `s`, checked: shapes, finite,
    pairwise distinct, `s != 0`."""
    raw = [jnp.asarray(p) for p in (p_prev, p_k, p_next)]
    dtype = float_dtype(*raw)
    points = jnp.stack(
        [as_point(p, name, dtype) for p, name in zip(raw, _FRAME_NAMES, strict=True)]
    )
    s = tension_scale(tension, dtype)
    return check_distinct(points), s


def check_distinct(points: Array) -> Array:
    """`points` (rows `P_{k-1}, P_k, P_{k+1}`), after checking they are pairwise distinct."""
    pairs = ((0, 1), (0, 2), (1, 2))
    values = concrete(points)
    if values is None:
        same = jnp.stack([jnp.all(points[i] == points[j]) for i, j in pairs])
        return eqx.error_if(points, jnp.any(same), "p_prev, p_k, p_next must be distinct")
    for i, j in pairs:
        if np.all(values[i] == values[j]):
            raise ValueError(
                f"{_FRAME_NAMES[i]} and {_FRAME_NAMES[j]} coincide at {values[i].tolist()}: "
                "the inverse problem needs three distinct points (P_{k-1} = P_{k+1} makes the "
                "tangent at P_k zero and the two solutions merge into a cusp; P_k = P_{k+1} "
                "leaves no chord; P_{k-1} = P_k is a repeated point of the frame)"
            )
    return points


def normalise(points: Array) -> tuple[Array, Array, Array]:
    """Complex points moved so that `P_k = 0` and scaled to unit size, with the origin and
    scale. The scale is held constant under differentiation: the solution scales exactly
    with it (`w -> sqrt(scale) w`), so its own derivative would contribute nothing."""
    z = to_complex(points)
    origin = z[1]
    scale = jax.lax.stop_gradient(jnp.abs(z[2] - z[0]) + jnp.abs(z[2] - z[1]))
    return (z - origin) / scale, origin, scale


def _starts(known: Array, s: Array) -> Array:
    """16 Newton starts: 2 for `alpha0` (90 degrees apart) times 8 for `alpha1` (a circle
    of radius twice a bound on both roots' moduli)."""
    c0 = s * (known[2] - known[0])
    rest = known[2] - known[1] - c0
    r0 = jnp.sqrt(jnp.abs(c0))
    radius = 2 * (3 * r0 + jnp.sqrt(3 * jnp.abs(rest)))
    dtype = r0.dtype
    alpha0 = r0 * jnp.exp(1j * jnp.asarray([np.pi / 8, 5 * np.pi / 8], dtype))
    angles = 2 * np.pi * np.arange(_ALPHA1_STARTS) / _ALPHA1_STARTS + np.pi / 16
    alpha1 = radius * jnp.exp(1j * jnp.asarray(angles, dtype))
    alpha0, alpha1 = (x.ravel() for x in jnp.meshgrid(alpha0, alpha1, indexing="ij"))
    after = jnp.broadcast_to(known[2], alpha0.shape)
    return jnp.stack(
        [alpha0.real, alpha1.real, alpha0.imag, alpha1.imag, after.real, after.imag], axis=-1
    )


def _tolerance(dtype) -> float:
    return float(np.sqrt(np.finfo(dtype).eps))


def _newton_pair(known: Array, s: Array) -> tuple[Array, Array, Array]:
    """Two roots of eq. 8 (normalised) as rows `(a0, a1, b0, b1, x_{k+2}, y_{k+2})`: the best
    converged start, and the converged one whose `P_{k+2}` is farthest from it; with their
    separation (in `P_{k+2}`) and whether any start converged."""
    tol = _tolerance(s.dtype)
    solver = optx.Newton(rtol=tol, atol=tol)

    def solve(start, args):
        return optx.root_find(eq8_residual, solver, start, args, throw=False).value

    starts = _starts(*jax.lax.stop_gradient((known, s)))  # a start only picks a basin
    # Every start gets its own copy of the arguments: vmapping the implicit adjoint over
    # starts with shared (unbatched) arguments fails to transpose in optimistix/equinox.
    args = jax.tree.map(lambda x: jnp.broadcast_to(x, starts.shape[:1] + x.shape), (known, s))
    roots = jax.vmap(solve)(starts, args)
    residuals = jnp.max(jnp.abs(jax.vmap(eq8_residual, (0, None))(roots, (known, s))), axis=-1)
    converged = residuals <= 10 * tol
    first = jnp.argmin(jnp.where(converged, residuals, jnp.inf))
    after = roots[:, 4] + 1j * roots[:, 5]
    gap = jnp.where(converged, jnp.abs(after - after[first]), -1.0)
    second = jnp.argmax(gap)
    return roots[jnp.stack([first, second])], gap[second], jnp.any(converged)


def _closed_form_pair(known: Array, s: Array) -> tuple[Array, Array, Array]:
    """The two roots of eq. 8 from `beta = (-alpha0 +- sqrt(3 (4 D - alpha0^2))) / 2`."""
    c0 = s * (known[2] - known[0])
    alpha0 = jnp.sqrt(c0)
    root = jnp.sqrt(3 * (4 * (known[2] - known[1]) - c0))
    beta = (-alpha0 + jnp.stack([root, -root])) / 2
    alpha1 = beta - alpha0
    after = known[1] + beta**2 / s
    alpha0 = jnp.broadcast_to(alpha0, alpha1.shape)
    roots = jnp.stack(
        [alpha0.real, alpha1.real, alpha0.imag, alpha1.imag, after.real, after.imag], axis=-1
    )
    return roots, jnp.abs(after[0] - after[1]), jnp.array(True)


def canonical_sign(coeffs: Array) -> Array:
    """`(a0, a1, b0, b1)` or its negative (the same curve), whichever has `a0 > 0` (or
    `a0 = 0`, `b0 >= 0`)."""
    flip = (coeffs[..., 0] < 0) | ((coeffs[..., 0] == 0) & (coeffs[..., 2] < 0))
    return jnp.where(flip[..., None], -coeffs, coeffs)


def turning(coeffs: Array) -> Array:
    """Signed total turning of the tangent along the PH cubic, `2 arg(w(1) / w(0))`, in
    `(-2 pi, 2 pi)`: `w` runs along a segment that misses the origin."""
    alpha0, alpha1 = alphas(coeffs)
    return 2 * jnp.angle((alpha0 + alpha1) * jnp.conj(alpha0))


def _order(turns: Array) -> Array:
    """`[0, 1]` or `[1, 0]`: less absolute turning first; on a tie (to `sqrt(eps)`: the
    mirror images of a collinear frame) the counter-clockwise one first."""
    size = jnp.abs(turns)
    tie = jnp.abs(size[0] - size[1]) <= _tolerance(turns.dtype) * (1 + jnp.max(size))
    swap = jnp.where(tie, turns[1] > turns[0], size[1] < size[0])
    return jnp.where(swap, jnp.array([1, 0]), jnp.array([0, 1]))


@eqx.filter_jit
def solve_pair(points: Array, s: Array, closed_form: bool = False):
    """Both solutions for the frame `points` (rows `P_{k-1}, P_k, P_{k+1}`), less turning
    first: `(coeffs (2, 4), p_next2 (2, 2), separation, converged)`, the separation of the
    two `P_{k+2}` relative to the size of the frame."""
    known, origin, scale = normalise(points)
    roots, gap, converged = (_closed_form_pair if closed_form else _newton_pair)(known, s)
    roots = roots[_order(turning(roots[:, :4]))]
    coeffs = canonical_sign(roots[:, :4]) * jnp.sqrt(scale)
    p_next2 = to_real(origin + scale * (roots[:, 4] + 1j * roots[:, 5]))
    return coeffs, p_next2, gap, converged


def _distinct(coeffs, p_next2, gap, converged):
    """Concrete results: one solution when the two coincide (a double root, which Newton
    resolves only to about sqrt(eps), so the tolerance is eps^(1/3) of the frame size)."""
    if any(concrete(x) is None for x in (coeffs, p_next2, gap, converged)):
        return coeffs, eqx.error_if(p_next2, ~converged, "no Newton start converged")
    if not bool(converged):
        raise RuntimeError("solve_cardinal: Newton's method converged from none of its starts")
    if float(gap) <= np.finfo(coeffs.dtype).eps ** (1 / 3):
        return coeffs[:1], p_next2[:1]
    return coeffs, p_next2


def solve_cardinal(
    p_prev: ArrayLike, p_k: ArrayLike, p_next: ArrayLike, tension: ArrayLike = 0.0
) -> tuple[Float[Array, "m 4"], Float[Array, "m 2"]]:
    """The inverse problem (seed eq. 8): every PH cubic segment of the cardinal spline whose
    first three points are given, solved with optimistix's Newton method.

    There are two distinct solutions, one when `4 (P_{k+1} - P_k) = s (P_{k+1} - P_{k-1})`
    (a double root); each also has its negative `(-a0, -a1, -b0, -b1)`, the same curve, which
    is not listed. Both solutions always have the same arc length. Differentiable in the
    points and the tension (implicit differentiation through the root).

    **Arguments:**

    - `p_prev`, `p_k`, `p_next`: `P_{k-1}, P_k, P_{k+1}`, each of shape `(2,)`, pairwise
      distinct (`ValueError` otherwise).
    - `tension`: scalar `t != 1`, `s = (1 - t) / 2` (`t = 0`: Catmull-Rom).

    **Returns:**

    `(coeffs, p_next2)`: `coeffs` of shape `(m, 4)`, rows `(a0, a1, b0, b1)` with the sign
    fixed by `a0 > 0` (or `a0 = 0`, `b0 >= 0`), and `p_next2` of shape `(m, 2)`, the point
    `P_{k+2}` of each. Ordered by the absolute turning `|2 arg(w(1) / w(0))|` of the
    tangent, the flatter curve first; on a tie (the two mirror images of a collinear frame)
    the counter-clockwise one first. `m = 2`, or `m = 1` when the two agree to within
    `eps^(1/3)` of the frame's size. Under `jit`/`vmap`/`grad` the shape must be static, so
    `m = 2` always (the rows are then equal at a double root).
    """
    points, s = frame_points(p_prev, p_k, p_next, tension)
    return _distinct(*solve_pair(points, s))


def solve_cardinal_closed_form(
    p_prev: ArrayLike, p_k: ArrayLike, p_next: ArrayLike, tension: ArrayLike = 0.0
) -> tuple[Float[Array, "m 4"], Float[Array, "m 2"]]:
    """`solve_cardinal` by the closed form, same arguments, returns and order.

    `alpha0 = sqrt(s (P_{k+1} - P_{k-1}))` (principal root), `w(1) = beta =
    (-alpha0 +- sqrt(3 (4 (P_{k+1} - P_k) - alpha0^2))) / 2`, `alpha1 = beta - alpha0`,
    `P_{k+2} = P_k + beta^2 / s` (complex notation, `alpha0 = a0 + i b0`,
    `alpha1 = a1 + i b1`).
    """
    points, s = frame_points(p_prev, p_k, p_next, tension)
    return _distinct(*solve_pair(points, s, closed_form=True))
