"""PH cardinal splines marched segment by segment, and the PH segment nearest four points."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float, Int

from ._cubic import _piecewise_bezier
from ._curve import NURBSCurve
from ._ph_cubic import alphas, arc_length, chord, tension_scale, to_complex, to_real
from ._ph_solve import (
    canonical_sign,
    check_distinct,
    frame_points,
    normalise,
    solve_pair,
)
from ._validate import check_finite, check_rank, concrete, float_dtype


class PHChain(eqx.Module):
    """A cardinal spline whose every segment is a PH cubic, with its exact length.

    Segment `j` is the cardinal segment (seed eq. 5) on `points[j : j + 4]`, from
    `points[j + 1]` to `points[j + 2]`, with hodograph coefficients `coeffs[j]`.
    """

    points: Float[Array, "n+3 2"]
    coeffs: Float[Array, "n 4"]
    tension: Float[Array, ""]

    @property
    def lengths(self) -> Float[Array, " n"]:
        """Exact length of each segment (`arc_length` of its coefficients)."""
        return arc_length(self.coeffs)

    @property
    def length(self) -> Float[Array, ""]:
        """Exact total length."""
        return jnp.sum(self.lengths)

    def curve(self) -> NURBSCurve:
        """The whole spline as one cubic `NURBSCurve`, segment `j` on `[j, j + 1]` (its
        Bezier form, knots of multiplicity 3 at the joints; C1 there)."""
        s = (1 - self.tension) / 2
        p = self.points
        starts, ends = p[1:-2], p[2:-1]
        inner1 = starts + s * (ends - p[:-3]) / 3
        inner2 = ends - s * (p[3:] - starts) / 3
        return _piecewise_bezier(starts, inner1, inner2, ends[-1], p.dtype)


def cardinal_chain(
    p0: ArrayLike,
    p1: ArrayLike,
    p2: ArrayLike,
    segments: int,
    tension: ArrayLike = 0.0,
    choices: ArrayLike | None = None,
) -> PHChain:
    """March a PH cardinal spline from three points, one inverse problem per segment.

    Segment 0 solves `solve_cardinal(P0, P1, P2)`; its `P3` is fixed by the chosen solution,
    and segment `j` then solves the frame `(P_j, P_{j+1}, P_{j+2})` (Newton, as
    `solve_cardinal`). The spline runs from `P1` to `P_{n+1}`: `P0` only sets the first
    tangent `s (P2 - P0)`, and the last point `P_{n+2}` the last one. Consecutive segments of
    a cardinal spline share the tangent at their joint, so the chain is C1 and PH throughout.

    **Arguments:**

    - `p0`, `p1`, `p2`: the first three points, shape `(2,)`, pairwise distinct.
    - `segments`: number of segments `n >= 1`, a Python int.
    - `tension`: scalar `!= 1`, shared by all segments.
    - `choices`: which solution each segment takes, `n` entries of 0 or 1, indices into
      `solve_cardinal`'s order (0: the flatter curve, less turning of the tangent). Default:
      all 0.

    **Returns:**

    A `PHChain` with `n + 3` points, `n` coefficient rows, `.length` the exact total length
    and `.curve()` the spline as a `NURBSCurve` on `[0, n]`.
    """
    if isinstance(segments, bool) or not isinstance(segments, (int, np.integer)) or segments < 1:
        raise ValueError(f"segments must be a Python int >= 1, got {segments!r}")
    points, s = frame_points(p0, p1, p2, tension)
    choices = jnp.zeros(segments, int) if choices is None else jnp.asarray(choices)
    if choices.shape != (segments,):
        raise ValueError(f"choices must have shape ({segments},), got {choices.shape}")
    values = concrete(choices)
    if values is not None and not np.all((values == 0) | (values == 1)):
        raise ValueError(f"choices must be 0 or 1 (index of a solution), got {values.tolist()}")
    return _march(points, s, choices)


@eqx.filter_jit
def _march(points: Array, s: Array, choices: Int[Array, " n"]) -> PHChain:
    def step(frame, choice):
        coeffs, p_next2, _, converged = solve_pair(check_distinct(frame), s)
        p_next2 = eqx.error_if(p_next2, ~converged, "no Newton start converged")
        return jnp.stack([frame[1], frame[2], p_next2[choice]]), (coeffs[choice], p_next2[choice])

    _, (coeffs, after) = jax.lax.scan(step, points, choices)
    return PHChain(jnp.concatenate([points, after]), coeffs, 1 - 2 * s)


def _frame(unknowns: Array, s: Array) -> Array:
    """The complex cardinal frame (eq. 9) of `unknowns = (a0, a1, b0, b1, x_{k-1}, y_{k-1})`."""
    alpha0, alpha1 = alphas(unknowns[:4])
    prev = unknowns[4] + 1j * unknowns[5]
    nxt = prev + alpha0**2 / s
    start = nxt - chord(alpha0, alpha1)
    return jnp.stack([prev, start, nxt, start + (alpha0 + alpha1) ** 2 / s])


def _fit_residual(unknowns: Array, args: tuple[Array, Array]) -> Array:
    targets, s = args
    return to_real(_frame(unknowns, s) - targets).ravel()


def fit_cardinal(
    points: ArrayLike, tension: ArrayLike = 0.0
) -> tuple[Float[Array, " 4"], Float[Array, "4 2"]]:
    """The PH cardinal segment whose four frame points are nearest `points` (least squares).

    Four arbitrary points are 8 numbers; a PH frame has 6 degrees of freedom (the four
    coefficients and `P_{k-1}`), so the exact inverse problem with `P_{k+2}` prescribed
    has no solution in general. This minimises
    `sum_i |cardinal_points(coeffs, q)[i] - points[i]|^2` over `coeffs` and `q` with
    Levenberg-Marquardt, polished by Gauss-Newton (optimistix), started from both exact
    solutions through the first three points, and keeps the better fit. Differentiable
    (implicit differentiation at the minimum).

    **Arguments:**

    - `points`: `(P_{k-1}, P_k, P_{k+1}, P_{k+2})`, shape `(4, 2)`; the first three pairwise
      distinct.
    - `tension`: scalar `!= 1`.

    **Returns:**

    `(coeffs, fitted)`: `(a0, a1, b0, b1)` with `a0 >= 0`, shape `(4,)`, and the fitted
    frame `cardinal_points(coeffs, fitted[0], tension)`, shape `(4, 2)`.
    """
    points = jnp.asarray(points)
    check_rank(points, 2, "points", "(4, 2)")
    if points.shape != (4, 2):
        raise ValueError(f"points must have shape (4, 2), got {points.shape}")
    points = check_finite(points.astype(float_dtype(points)), "points")
    s = tension_scale(tension, points.dtype)
    return _fit(check_distinct(points[:3]), points, s)


@eqx.filter_jit
def _fit(frame: Array, points: Array, s: Array):
    # The starts (the closed-form solutions through the first three points) only pick a
    # basin: no derivative flows through them.
    coeffs = solve_pair(*jax.lax.stop_gradient((frame, s)), closed_form=True)[0]
    known, origin, scale = normalise(frame)
    targets = (to_complex(points) - origin) / scale
    starts = jnp.concatenate(
        [coeffs / jnp.sqrt(scale), jnp.broadcast_to(to_real(known[0]), (2, 2))], axis=-1
    )
    # Levenberg-Marquardt stops on a rejected (damped) step, which can leave the minimiser
    # off by ~1e-9; undamped Gauss-Newton steps from there converge to rounding level.
    tol = float(np.finfo(points.dtype).eps ** (2 / 3))
    robust = optx.LevenbergMarquardt(rtol=1e3 * tol, atol=1e3 * tol)
    polish = optx.GaussNewton(rtol=tol, atol=tol)

    def fit(start):
        # Derivatives come from the polished minimum alone (implicitly), not from its start.
        args = jax.lax.stop_gradient((targets, s))
        near = optx.least_squares(_fit_residual, robust, start, args, throw=False).value
        return optx.least_squares(_fit_residual, polish, near, (targets, s), throw=False).value

    fits = jax.vmap(fit)(starts)
    costs = jnp.sum(jax.vmap(_fit_residual, (0, None))(fits, (targets, s)) ** 2, axis=-1)
    best = fits[jnp.argmin(costs)]
    return canonical_sign(best[:4]) * jnp.sqrt(scale), to_real(origin + scale * _frame(best, s))
