"""Gradient-based fitting of (rational) B-spline curves to points with optimistix.

The unknowns are the control points, the weights and, optionally, the parameters of the
data; Levenberg-Marquardt minimises `sum_k |C(u_k) - Q_k|^2` over them, with Jacobians by
forward-mode autodiff. The start is the linear least-squares fit of `approximate` (ends
free), whose knots stay fixed.

Parameter correction runs jointly: the interior parameters are unknowns of the same
solve, clamped to the domain. The alternative, solving for the curve, re-projecting the
data onto it (`closest_point`) and solving again, corrects the parameters only to first
order per round and converges linearly, slowest along the curve, where the residual hardly
depends on them; the joint Gauss-Newton steps converge quadratically on data a curve of
the family fits exactly (a conic sampled, for a rational quadratic), so such data are
recovered to rounding in a few steps. At the joint optimum each residual is orthogonal to
the curve, `C'(u_k) . (C(u_k) - Q_k) = 0`, exactly what re-projection aims at.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float

from ._curve import NURBSCurve
from ._interpolate import _data_points, _parameters, approximate
from ._misc import clamp_to_domain, safe_norm
from ._validate import check_control_count, check_degree, check_knots, concrete

_POLISH_STEPS = 4  # Gauss-Newton steps after Levenberg-Marquardt (see `_solve`)
_ROUNDING_SLACK = 64  # ulps of the sum of squares the polish may add (see `_solve`)


class CurveFitReport(eqx.Module):
    """What `fit_curve` did.

    - `steps`: solver steps taken: Levenberg-Marquardt, then the Gauss-Newton polish.
    - `rms_residual`, `max_residual`: root mean square and largest distance
      `|C(u_k) - Q_k|` from the data points to the curve at their parameters.
    - `parameters`: the parameters `u_k` of the data points on the fitted curve (the
      corrected ones with `correct_parameters`).
    - `converged`: whether Levenberg-Marquardt met its tolerance within `max_steps`.
    """

    steps: Array
    rms_residual: Array
    max_residual: Array
    parameters: Float[Array, " m"]
    converged: Array


def _check_options(rational, correct_parameters, max_steps, tol):
    for name, flag in (("rational", rational), ("correct_parameters", correct_parameters)):
        if not isinstance(flag, bool):
            raise ValueError(f"{name} must be True or False, got {flag!r}")
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)):
        raise ValueError(f"max_steps must be a Python int, got {max_steps!r}")
    if max_steps <= 0:
        raise ValueError(f"max_steps must be positive, got {max_steps}")
    if tol is not None and not (np.ndim(tol) == 0 and np.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be a finite number > 0, got {tol!r}")


def fit_curve(
    points: ArrayLike,
    n_control: int | None = None,
    degree: int = 3,
    *,
    rational: bool = False,
    parametrization="centripetal",
    correct_parameters: bool = False,
    max_steps: int = 256,
    tol: float | None = None,
    full_output: bool = False,
    knots: ArrayLike | None = None,
):
    """Fit a B-spline or NURBS curve to points by Levenberg-Marquardt (optimistix).

    Minimises `sum_k |C(u_k) - Q_k|^2` over the control points, with `rational` also over
    the weights (as logarithms, so they stay positive; the first is held at 1, since
    scaling all weights changes nothing) and with `correct_parameters` also over the
    interior parameters `u_1 .. u_{m-2}` (clamped to the domain; the end points keep the
    ends of the domain). The knots are fixed; the start is the linear least-squares fit
    `approximate(points, n_control, degree, parametrization, interpolate_ends=False)` with
    all weights 1. With `correct_parameters` and a single
    rational segment (`n_control == degree + 1`) the last weight is held at 1 as well: a
    rational reparametrisation moves any positive end weights to 1 without changing the
    curve (NURBS Book §6.4), and holding it keeps the problem free of that flat direction.

    Data sampled from a curve of the family are recovered to rounding: a conic arc by a
    rational quadratic with `correct_parameters=True`.

    A step costs a dense QR of the Jacobian, `(m dim) x` the number of unknowns, which
    with `correct_parameters` grows with the number of points `m`: O(m^3) per step, so
    parameter correction suits up to a few hundred points (10^3 points take minutes).

    **Arguments:**

    - `points`: array of shape `(m, dim)`, `m >= n_control`.
    - `n_control`: number of control points, `p + 1 <= n_control <= m`; None gives
      `p + 1` (one Bezier segment).
    - `degree`: the degree `p >= 1`.
    - `rational`: also fit the weights.
    - `parametrization`: `"uniform"`, `"chord"`, `"centripetal"` (see `parametrize`) or
      `m` increasing parameters: the start, or the fixed parameters without
      `correct_parameters`.
    - `correct_parameters`: also fit the interior parameters.
    - `max_steps`: limit on the Levenberg-Marquardt steps.
    - `tol`: relative and absolute tolerance of the solver on the unknowns and the
      residuals, the points scaled to unit size; None gives the square root of the
      machine epsilon of the points' dtype.
    - `full_output`: also return a `CurveFitReport`.
    - `knots`: optional clamped knots, `n_control + degree + 1` of them, to use instead
      of `approximation_knots`; parameters from a method name are scaled to their domain.

    **Returns:**

    The fitted `NURBSCurve` (rational if `rational`); with `full_output`, `(curve,
    report)`. `jax.grad` of anything computed from them reaches the points (implicit
    differentiation of the optimum). `degree`, `n_control`, the flags, `max_steps`,
    `tol` and a method name must be concrete. When the solver does not converge within
    `max_steps` the last iterate is returned; the report says so.
    """
    degree = check_degree(degree)
    points = _data_points(points)
    n_control = degree + 1 if n_control is None else n_control
    check_control_count(n_control, degree, at_most=points.shape[0])
    _check_options(rational, correct_parameters, max_steps, tol)
    if knots is not None:
        knots = check_knots(jnp.asarray(knots, dtype=points.dtype), n_control, degree)
        _check_clamped(knots, degree)
    u = _parameters(points, parametrization)
    if knots is not None and isinstance(parametrization, str):
        lower, upper = knots[degree], knots[-degree - 1]
        u = lower + (upper - lower) * u
    # The linear least-squares curve: for a polynomial fit on fixed parameters it is
    # already the optimum, and Levenberg-Marquardt only confirms it.
    start = approximate(points, n_control, degree, u, knots=knots, interpolate_ends=False)
    tol = float(np.sqrt(np.finfo(points.dtype).eps)) if tol is None else float(tol)
    hold_last = rational and correct_parameters and n_control == degree + 1
    control, weights, u, steps, converged = _solve(
        points,
        start.control_points,
        start.knots,
        u,
        degree=degree,
        rational=rational,
        correct_parameters=correct_parameters,
        hold_last=hold_last,
        max_steps=int(max_steps),
        tol=tol,
    )
    curve = NURBSCurve(control, degree, start.knots, weights)
    if not full_output:
        return curve
    distances = safe_norm(curve(u) - points)
    report = CurveFitReport(
        steps=steps,
        rms_residual=jnp.sqrt(jnp.mean(distances**2)),
        max_residual=jnp.max(distances),
        parameters=u,
        converged=converged,
    )
    return curve, report


def _check_clamped(knots: Array, degree: int) -> None:
    values = concrete(knots)
    if values is None:
        return
    ends = values[: degree + 1], values[-degree - 1 :]
    if not all(np.all(end == end[0]) for end in ends):
        raise ValueError(
            f"knots must be clamped (the first and last {degree + 1} equal), got {values}"
        )


@functools.partial(
    jax.jit,
    static_argnames=(
        "degree",
        "rational",
        "correct_parameters",
        "hold_last",
        "max_steps",
        "tol",
    ),
)
def _solve(
    points, control, knots, u, *, degree, rational, correct_parameters, hold_last, max_steps, tol
):
    """`(control points, weights or None, parameters, steps, converged)` of the fit."""
    # Solve for points scaled to unit size around the origin, so that `tol` is relative to
    # the data; NURBS are affine invariant, so the map carries over to the control points.
    centre = jnp.mean(points, axis=0)
    size = jnp.max(jnp.abs(points - centre))
    scale = jnp.where(size > 0, size, 1.0)
    n_weights = control.shape[0] - 1 - hold_last

    def unpack(unknowns, u, knots):
        scaled_control, log_weights, interior = unknowns
        if interior is not None:
            interior = clamp_to_domain(interior, knots[degree], knots[-degree - 1])
            u = u.at[1:-1].set(interior)
        weights = None
        if log_weights is not None:
            held = jnp.zeros(1 + hold_last, log_weights.dtype)
            weights = jnp.exp(jnp.concatenate([held[:1], log_weights, held[1:]]))
        return scaled_control, weights, u

    # Everything the residuals depend on goes in through `args`, so the implicit
    # derivative of the optimum reaches it (the parameters and knots depend on the points).
    def residuals(unknowns, args):
        scaled_points, u, knots = args
        scaled_control, weights, params = unpack(unknowns, u, knots)
        return NURBSCurve(scaled_control, degree, knots, weights)(params) - scaled_points

    start = (
        (control - centre) / scale,
        jnp.zeros(n_weights, points.dtype) if rational else None,
        u[1:-1] if correct_parameters else None,
    )
    # The implicit derivative solves with the Hessian of the sum of squares, singular where
    # a parameter sits clamped at an end: least squares (SVD) handles that.
    adjoint = optx.ImplicitAdjoint(linear_solver=lx.SVD())
    args = ((points - centre) / scale, u, knots)
    damped = optx.least_squares(
        residuals,
        optx.LevenbergMarquardt(rtol=tol, atol=tol),
        start,
        args=args,
        max_steps=max_steps,
        throw=False,
        adjoint=adjoint,
    )
    converged = damped.result == optx.RESULTS.successful

    # Levenberg-Marquardt stops when an accepted step is small, which also happens after
    # rejected steps have shrunk its trust region short of the optimum (seen at 1e-9 from
    # it with tol 1e-13): there the sum of squares no longer tells better from worse.
    # Undamped Gauss-Newton steps (normal equations, pseudo-inverse for the flat
    # directions) from there converge fast; they are kept unless they raise the residual
    # beyond its rounding. Only after convergence: far from the optimum they can diverge.
    def polish(y):
        polished = optx.least_squares(
            residuals,
            optx.GaussNewton(rtol=tol, atol=tol, linear_solver=lx.Normal(lx.SVD())),
            y,
            args=args,
            max_steps=_POLISH_STEPS,
            throw=False,
            adjoint=adjoint,
        )
        loss = _sum_squares(residuals(y, args))
        slack = _ROUNDING_SLACK * jnp.finfo(loss.dtype).eps * loss
        better = _sum_squares(residuals(polished.value, args)) <= loss + slack
        value = jax.tree.map(lambda a, b: jnp.where(better, a, b), polished.value, y)
        return value, polished.stats["num_steps"]

    def keep(y):
        return y, jnp.zeros((), damped.stats["num_steps"].dtype)

    value, polish_steps = jax.lax.cond(converged, polish, keep, damped.value)
    scaled_control, weights, params = unpack(value, u, knots)
    steps = damped.stats["num_steps"] + polish_steps
    return centre + scale * scaled_control, weights, params, steps, converged


def _sum_squares(residuals: Array) -> Array:
    return jnp.sum(residuals**2)
