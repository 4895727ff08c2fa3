"""Gradient-based fitting of (rational) B-spline curves to points, open or closed.

The unknowns are the control points, the weights and, optionally, the parameters of the
data; Levenberg-Marquardt minimises `sum_k |C(u_k) - Q_k|^2` over them. The start is the
linear least-squares fit of `approximate` (ends free), whose knots stay fixed.

Parameter correction runs jointly: the interior parameters are unknowns of the same
solve, kept in the domain. The alternative, solving for the curve, re-projecting the
data onto it (`closest_point`) and solving again, corrects the parameters only to first
order per round and converges linearly, slowest along the curve, where the residual hardly
depends on them; the joint Gauss-Newton steps converge quadratically on data a curve of
the family fits exactly (a conic sampled, for a rational quadratic), so such data are
recovered to rounding in a few steps. At the joint optimum each residual is orthogonal to
the curve, `C'(u_k) . (C(u_k) - Q_k) = 0`, exactly what re-projection aims at.

The structure makes a step O(m). Residual `k` depends on its own parameter `u_k` and on
the `p + 1` control points (and weights) of its span only. With `theta` the curve's
unknowns (per control point its coordinates, then its log-weight) the Gauss-Newton matrix
is `[[A^T A, A^T D], [D^T A, D^T D]]` with `D^T D` diagonal, one entry per parameter, so
eliminating the parameters leaves the Schur complement
`A^T A - A^T D (D^T D)^-1 D^T A` in `theta` alone, assembled point by point from blocks of
`(p + 1)(dim + 1)` unknowns: it is banded (the order of `band_order`). A step costs
O(m (p dim)^2) to assemble and a banded solve, where a dense QR of the whole Jacobian
costs O(m^3). The same elimination solves with the exact Hessian for the implicit
derivative of the optimum. The loop is written here rather than with optimistix, whose
solvers would need this structured solve as a custom lineax solver.
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._banded import solve_banded
from ._basis import ders_basis_funs
from ._curve import NURBSCurve
from ._interpolate import (
    _check_loop,
    _data_points,
    _parameters,
    approximate,
    band_order,
    checked_knots,
)
from ._misc import safe_norm
from ._validate import check_control_count, check_degree, check_solver_options, concrete

_POLISH_STEPS = 4  # Gauss-Newton steps after Levenberg-Marquardt (see `_levenberg_marquardt`)
_ROUNDING_SLACK = 64  # ulps of the sum of squares a final step may add
_INITIAL_DAMPING = 1e-3  # times the largest diagonal entry of the Gauss-Newton matrix


class CurveFitReport(eqx.Module):
    """What `fit_curve` did.

    - `steps`: solver steps taken: Levenberg-Marquardt (rejected ones included), then
      the Gauss-Newton polish.
    - `rms_residual`, `max_residual`: root mean square and largest distance
      `|C(u_k) - Q_k|` from the data points to the curve at their parameters.
    - `parameters`: the parameters `u_k` of the data points on the fitted curve (the
      corrected ones with parameter correction).
    - `converged`: whether Levenberg-Marquardt met its tolerance within `max_steps`.
    """

    steps: Array
    rms_residual: Array
    max_residual: Array
    parameters: Float[Array, " m"]
    converged: Array


def _check_options(rational, correct_parameters, closed, max_steps, tol) -> bool:
    """The options checked; returns whether the parameters are corrected."""
    for name, flag in (("rational", rational), ("closed", closed)):
        if not isinstance(flag, bool):
            raise ValueError(f"{name} must be True or False, got {flag!r}")
    if correct_parameters is not None and not isinstance(correct_parameters, bool):
        raise ValueError(
            f"correct_parameters must be True, False or None, got {correct_parameters!r}"
        )
    check_solver_options(max_steps, tol)
    return rational if correct_parameters is None else correct_parameters


def fit_curve(
    points: ArrayLike,
    n_control: int | None = None,
    degree: int = 3,
    *,
    rational: bool = False,
    parametrization="centripetal",
    correct_parameters: bool | None = None,
    closed: bool = False,
    max_steps: int = 256,
    tol: float | None = None,
    full_output: bool = False,
    knots: ArrayLike | None = None,
):
    """Fit a B-spline or NURBS curve to points by Levenberg-Marquardt.

    Minimises `sum_k |C(u_k) - Q_k|^2` over the control points, with `rational` also over
    the weights (as logarithms, so they stay positive; the first is held at 1, since
    scaling all weights changes nothing) and with parameter correction also over the
    parameters of the data: the interior ones of an open curve (the end points keep the
    ends of the domain), all but the first of a closed one (the first point keeps the
    start of the domain, which fixes where the seam is). They stay in the domain: an
    open curve's are clamped to it, a closed curve's wrap around the period. The
    knots are fixed; the start is the linear least-squares fit `approximate(points,
    n_control, degree, parametrization, interpolate_ends=False, closed=closed)` with all
    weights 1. With parameter correction and a single rational segment
    (`n_control == degree + 1`, open) the last weight is held at 1 as well: a rational
    reparametrisation moves any positive end weights to 1 without changing the curve
    (NURBS Book §6.4), and holding it keeps the problem free of that flat direction.

    Data sampled from a curve of the family are recovered to rounding: a conic arc by a
    rational quadratic, parameter correction being the default for rational fits.

    A step costs O(m) for `m` points (see the module notes: the parameters are eliminated
    from each step's linear system point by point), so 10^4 points take seconds.

    **Arguments:**

    - `points`: array of shape `(m, dim)`, `m >= n_control`; once around the loop, not
      repeating the first point, when `closed`.
    - `n_control`: number of control points (free ones when closed),
      `p + 1 <= n_control <= m`; None gives `p + 1` (one Bezier segment, or the fewest
      periodic ones).
    - `degree`: the degree `p >= 1`.
    - `rational`: also fit the weights.
    - `parametrization`: `"uniform"`, `"chord"`, `"centripetal"` (see `parametrize`) or
      `m` increasing parameters (`m + 1` when closed, the last closing the loop): the
      start, or the fixed parameters without correction.
    - `correct_parameters`: also fit the parameters; None (default) corrects them for a
      rational fit (where it recovers conics) and not for a polynomial one (where the
      fit on fixed parameters is the linear least-squares curve).
    - `closed`: fit a closed periodic curve, `C^(p-1)` at the seam, as
      `approximate(..., closed=True)` builds it.
    - `max_steps`: limit on the Levenberg-Marquardt steps.
    - `tol`: relative and absolute tolerance of the solver on the unknowns, the points
      scaled to unit size; None gives the square root of the machine epsilon of the
      points' dtype.
    - `full_output`: also return a `CurveFitReport`.
    - `knots`: optional knots to use instead of `approximation_knots`: clamped ones,
      `n_control + degree + 1` of them, or when closed `n_control + 2 degree + 1`
      periodic ones; parameters from a method name are scaled to their domain.

    **Returns:**

    The fitted `NURBSCurve` (rational if `rational`; with `n_control + degree` control
    points, the first `degree` repeated, when closed); with `full_output`, `(curve,
    report)`. `jax.grad` (and `jax.jvp`) of anything computed from them reaches the points
    by implicit differentiation of the optimum, which must be isolated (a parameter held
    at an end of the domain counts as fixed there). `degree`, `n_control`, the flags,
    `max_steps`, `tol` and a method name must be concrete. When the solver does not
    converge within `max_steps` the last iterate is returned; the report says so.
    """
    degree = check_degree(degree)
    points = _data_points(points)
    n_control = degree + 1 if n_control is None else n_control
    check_control_count(n_control, degree, at_most=points.shape[0])
    correct = _check_options(rational, correct_parameters, closed, max_steps, tol)
    if knots is not None:
        knots = checked_knots(knots, points.dtype, n_control, degree, closed)
        if not closed:
            _check_clamped(knots, degree)
    if closed:
        _check_loop(points)
    u = _parameters(points, parametrization, closed)
    if knots is not None and isinstance(parametrization, str):
        lower, upper = knots[degree], knots[-degree - 1]
        u = lower + (upper - lower) * u
    # The linear least-squares curve: for a polynomial fit on fixed parameters it is
    # already the optimum, and Levenberg-Marquardt only confirms it.
    start = approximate(
        points, n_control, degree, u, knots=knots, interpolate_ends=False, closed=closed
    )
    u = u[:-1] if closed else u
    tol = float(np.sqrt(np.finfo(points.dtype).eps)) if tol is None else float(tol)
    hold_last = rational and correct and not closed and n_control == degree + 1
    control, weights, u, steps, converged = _solve(
        points,
        start.control_points[:n_control],
        start.knots,
        u,
        degree=degree,
        rational=rational,
        correct=correct,
        closed=closed,
        hold_last=hold_last,
        max_steps=int(max_steps),
        tol=tol,
    )
    if closed:
        control = jnp.concatenate([control, control[:degree]])
        weights = None if weights is None else jnp.concatenate([weights, weights[:degree]])
    curve = NURBSCurve(control, degree, start.knots, weights)
    if not full_output:
        return curve
    return curve, fit_report(CurveFitReport, curve(u) - points, steps, u, converged)


def fit_report(kind, errors: Array, steps: Array, parameters: Array, converged: Array):
    """A `CurveFitReport` or `SurfaceFitReport` (`kind`) from the vectors `errors` from
    the data points to the fitted shape at their parameters."""
    distances = safe_norm(errors)
    return kind(
        steps=steps,
        rms_residual=jnp.sqrt(jnp.mean(distances**2)),
        max_residual=jnp.max(distances),
        parameters=parameters,
        converged=converged,
    )


def _check_clamped(knots: Array, degree: int) -> None:
    values = concrete(knots)
    if values is None:
        return
    ends = values[: degree + 1], values[-degree - 1 :]
    if not all(np.all(end == end[0]) for end in ends):
        raise ValueError(
            f"knots must be clamped (the first and last {degree + 1} equal), got {values}"
        )


class _Layout(eqx.Module):
    """Static shape of a fit: which unknowns there are and where they sit in the banded
    system of `theta` (rows `position[j] * block + c` for coordinate `c` of control point
    `j`; the log-weight is coordinate `dim`)."""

    degree: int = eqx.field(static=True)
    rational: bool = eqx.field(static=True)
    closed: bool = eqx.field(static=True)
    hold_last: bool = eqx.field(static=True)
    n_control: int = eqx.field(static=True)
    dim: int = eqx.field(static=True)
    correct: bool = eqx.field(static=True)

    @property
    def block(self) -> int:
        return self.dim + self.rational

    def rows(self) -> tuple[np.ndarray, int]:
        """`(rows, half)`: the band row of every entry of `theta` (`(n_control, block)`)
        and the half-bandwidth of the banded system."""
        position, half = band_order(self.n_control, self.degree, self.closed)
        rows = position[:, None] * self.block + np.arange(self.block)
        return rows, (half + 1) * self.block - 1

    def theta_free(self) -> np.ndarray:
        """Which entries of `theta` are unknowns (the held log-weights are not)."""
        free = np.ones((self.n_control, self.block), bool)
        if self.rational:
            free[0, self.dim] = False
            free[-1, self.dim] &= not self.hold_last
        return free

    def interior(self, m: int) -> np.ndarray:
        """Which parameters may be corrected: not the first (nor, open, the last)."""
        index = np.arange(m)
        if not self.correct:
            return np.zeros(m, bool)
        return (index > 0) & ((index < m - 1) | self.closed)

    def local(self, span: Array) -> Array:
        """Indices of the free control points acting on each span."""
        local = span[:, None] - self.degree + jnp.arange(self.degree + 1)
        return local % self.n_control if self.closed else local


def _local_curve(theta: Array, t: Array, funs: Array, rational: bool) -> Array:
    """`C(u + t)` from the `p + 1` rows of `theta` acting at `u` (coordinates, then the
    log-weight) and `funs[j]`, the j-th derivatives of their basis functions at `u`: the
    basis is expanded to the order given in `t`, so the derivatives in `t` at `t = 0`
    are exact up to that order."""
    basis = sum(t**j / (1, 1, 2)[j] * funs[j] for j in range(funs.shape[0]))
    if not rational:
        return basis @ theta
    basis = basis * jnp.exp(theta[:, -1])
    return basis @ theta[:, :-1] / jnp.sum(basis)


def _point_blocks(layout, theta, u, knots, points, order):
    """Per point: residual, the Jacobian (order 1) or the Hessian of the half squared
    residual (order 2) in its local unknowns `(theta rows of its span, then u_k)`, and the
    band rows of those theta entries."""
    span, funs = ders_basis_funs(knots, layout.degree, u, order)
    local = layout.local(span)
    rows, _ = layout.rows()
    local_rows = jnp.asarray(rows)[local].reshape(local.shape[0], -1)
    local_theta = theta[local]
    shape = local_theta.shape[1:]

    def curve(z, funs):
        return _local_curve(z[:-1].reshape(shape), z[-1], funs, layout.rational)

    z = jnp.concatenate(
        [local_theta.reshape(local.shape[0], -1), jnp.zeros((local.shape[0], 1), u.dtype)], 1
    )
    residuals = jax.vmap(curve)(z, funs) - points
    if order == 1:
        derivative = jax.vmap(jax.jacfwd(curve))(z, funs)
    else:

        def half_square(z, funs, point):
            return 0.5 * jnp.sum((curve(z, funs) - point) ** 2)

        derivative = jax.vmap(jax.hessian(half_square))(z, funs, points)
    return residuals, derivative, local_rows


def _reduced_solve(layout, blocks, rhs_theta, rhs_u, local_rows, u_free, damping):
    """Solve `(H + damping I) [x_theta, x_u] = [rhs_theta, rhs_u]` where `H` is the sum
    of the per-point blocks (local theta entries, then the point's parameter), held
    unknowns (weights held, parameters not free) solved as 0.

    The parameters are eliminated point by point (`H_uu` is diagonal): the Schur
    complement in theta is banded and positive definite for `damping > 0` or at an
    isolated minimum, so the pivot-free banded solve applies. `rhs_theta` and the result
    are in band order.
    """
    rows, half = layout.rows()
    inverse = np.argsort(rows.ravel())
    theta_free = jnp.asarray(layout.theta_free().ravel()[inverse])
    size = local_rows.shape[1]
    mask = jnp.concatenate([theta_free[local_rows], u_free[:, None]], 1)
    blocks = blocks * mask[:, :, None] * mask[:, None, :]
    inner, coupling, diagonal = (
        blocks[:, :size, :size],
        blocks[:, :size, size],
        blocks[:, size, size],
    )
    diagonal = jnp.where(u_free, diagonal + damping, 1.0)
    rhs_u = jnp.where(u_free, rhs_u, 0.0)
    reduced = inner - coupling[:, :, None] * coupling[:, None, :] / diagonal[:, None, None]
    band = jnp.zeros((rhs_theta.shape[0], 2 * half + 1), blocks.dtype)
    band = band.at[
        local_rows[:, :, None], local_rows[:, None, :] - local_rows[:, :, None] + half
    ].add(reduced)
    band = band.at[:, half].add(jnp.where(theta_free, damping, 1.0))
    rhs = rhs_theta - jnp.zeros_like(rhs_theta).at[local_rows].add(
        coupling * (rhs_u / diagonal)[:, None]
    )
    x_theta = solve_banded(band, jnp.where(theta_free, rhs, 0.0)[:, None])[:, 0]
    x_u = (rhs_u - jnp.sum(coupling * x_theta[local_rows], 1)) / diagonal
    return x_theta, x_u


def _to_band(layout, theta):
    rows, _ = layout.rows()
    return theta.ravel()[np.argsort(rows.ravel())]


def _from_band(layout, flat):
    rows, _ = layout.rows()
    return flat[rows]


def _linearise(layout, theta, u, knots, points):
    """`(loss, Gauss-Newton blocks, gradient in band order, gradient in u, band rows)`."""
    residuals, jacobian, local_rows = _point_blocks(layout, theta, u, knots, points, 1)
    local_gradient = jnp.einsum("kdi,kd->ki", jacobian, residuals)
    blocks = jnp.einsum("kdi,kdj->kij", jacobian, jacobian)
    size = local_rows.shape[1]
    gradient = jnp.zeros(theta.size, theta.dtype).at[local_rows].add(local_gradient[:, :size])
    gradient = gradient * jnp.asarray(_to_band(layout, layout.theta_free()))
    gradient_u = local_gradient[:, size] * layout.interior(u.shape[0])
    return 0.5 * jnp.sum(residuals**2), blocks, gradient, gradient_u, local_rows


def _levenberg_marquardt(layout, points, knots, theta, u, *, max_steps, tol):
    """Levenberg-Marquardt with the damping update of Madsen, Nielsen and Tingleff
    (2004, alg. 3.16), parameters projected onto the domain, then a Gauss-Newton polish.
    Returns `(theta, u, steps, converged)`."""
    lower, upper = knots[layout.degree], knots[-layout.degree - 1]
    interior = jnp.asarray(layout.interior(u.shape[0]))
    size = (layout.degree + 1) * layout.block

    def linearise(theta, u):
        return _linearise(layout, theta, u, knots, points)

    loss, blocks, gradient, gradient_u, local_rows = linearise(theta, u)
    diagonal = (
        jnp.zeros(theta.size, theta.dtype)
        .at[local_rows]
        .add(jnp.diagonal(blocks, axis1=1, axis2=2)[:, :size])
    )
    largest = jnp.maximum(jnp.max(diagonal), jnp.max(blocks[:, size, size] * interior))
    damping = _INITIAL_DAMPING * jnp.where(largest > 0, largest, 1.0)
    nu, steps, done = jnp.asarray(2.0, loss.dtype), jnp.asarray(0, jnp.int32), jnp.asarray(False)
    state = (theta, u, loss, blocks, gradient, gradient_u, local_rows, damping, nu, steps, done)

    def step(state, polish):
        theta, u, loss, blocks, gradient, gradient_u, local_rows, damping, nu, steps, _ = state
        # Parameters of an open curve at an end of the domain that the gradient pushes
        # outwards stay there.
        blocked = ((u <= lower) & (gradient_u > 0)) | ((u >= upper) & (gradient_u < 0))
        u_free = interior & ~(blocked & (not layout.closed))
        h_theta, h_u = _reduced_solve(
            layout, blocks, -gradient, -gradient_u, local_rows, u_free, 0.0 if polish else damping
        )
        scale = jnp.maximum(jnp.max(jnp.abs(theta)), jnp.max(jnp.abs(u)))
        largest = jnp.maximum(jnp.max(jnp.abs(h_theta)), jnp.max(jnp.abs(h_u)))
        small = largest <= tol * (scale + tol)
        new_theta = theta + _from_band(layout, h_theta)
        if layout.closed:  # a parameter leaving the period comes back at its other end
            new_u = lower + jnp.mod(u + h_u - lower, upper - lower)
        else:
            new_u = jnp.clip(u + h_u, lower, upper)
        new = linearise(new_theta, new_u)
        rounding = _ROUNDING_SLACK * jnp.finfo(loss.dtype).eps * loss
        if polish:
            # Kept unless it raises the loss beyond rounding, where the loss no longer
            # tells better from worse but the zero of the gradient is still found.
            accept = jnp.isfinite(new[0]) & (new[0] <= loss + rounding)
            done = ~accept | small
        else:
            predicted = 0.5 * (
                damping * (jnp.sum(h_theta**2) + jnp.sum(h_u**2))
                - jnp.dot(h_theta, gradient)
                - jnp.dot(h_u, gradient_u)
            )
            rho = (loss - new[0]) / jnp.where(predicted > 0, predicted, 1.0)
            # A small step ends the solve; it is kept unless it raises the loss beyond
            # rounding (then it brings the error from about the step down to about its
            # square).
            accept = jnp.where(small, new[0] <= loss + rounding, (predicted > 0) & (rho > 0))
            accept &= jnp.isfinite(new[0])
            # Madsen-Nielsen-Tingleff shrink the damping at most 3-fold per good step;
            # 10-fold lets the steps turn into Gauss-Newton ones (quadratic convergence)
            # within a few steps, which conics need to reach rounding.
            damping = jnp.where(
                accept, damping * jnp.maximum(1 / 10, 1 - (2 * rho - 1) ** 3), damping * nu
            )
            nu = jnp.where(accept, 2.0, 2 * nu)
            done = small
        old = (theta, u, loss, blocks, gradient, gradient_u, local_rows)
        chosen = jax.tree.map(lambda a, b: jnp.where(accept, a, b), (new_theta, new_u, *new), old)
        return (*chosen, damping, nu, steps + 1, done)

    state = jax.lax.while_loop(
        lambda state: ~state[-1] & (state[-2] < max_steps),
        functools.partial(step, polish=False),
        state,
    )
    converged = state[-1]
    # Levenberg-Marquardt stops on a small step, which also comes after rejected steps
    # have raised the damping short of the optimum; undamped Gauss-Newton steps from there
    # converge to the zero of the gradient. Only after convergence: far from the optimum
    # they can diverge.
    polish_until = state[-2] + jnp.where(converged, _POLISH_STEPS, 0)
    state = (*state[:-1], jnp.asarray(False))
    state = jax.lax.while_loop(
        lambda state: ~state[-1] & (state[-2] < polish_until),
        functools.partial(step, polish=True),
        state,
    )
    return state[0], state[1], state[-2], converged


def _free_parameters(layout, u, knots):
    """Parameters that are unknowns at the optimum: correctable and inside the domain."""
    lower, upper = knots[layout.degree], knots[-layout.degree - 1]
    inside = (u > lower) & (u < upper)
    return jnp.asarray(layout.interior(u.shape[0])) & (inside | layout.closed)


def _held_parameters(layout, u, u_given, knots):
    """The values of the parameters that are not unknowns, as functions of the inputs:
    given ones, or the end of the domain where one is held (open curves only)."""
    lower, upper = knots[layout.degree], knots[-layout.degree - 1]
    interior = jnp.asarray(layout.interior(u.shape[0])) & (not layout.closed)
    return jnp.where(
        interior & (u <= lower), lower, jnp.where(interior & (u >= upper), upper, u_given)
    )


def _gradient(layout, free, theta, u, args):
    """Gradient of the half sum of squares in `(theta, u)`, held unknowns masked out."""
    points, u_given, knots = args

    def loss(theta, u):
        theta = jnp.where(jnp.asarray(layout.theta_free()), theta, 0.0)
        held = _held_parameters(layout, jax.lax.stop_gradient(u), u_given, knots)
        u = jnp.where(free, u, held)
        span, funs = ders_basis_funs(knots, layout.degree, u, 0)
        curve = jax.vmap(lambda theta, funs: _local_curve(theta, 0.0, funs, layout.rational))
        residuals = curve(theta[layout.local(span)], funs) - points
        return 0.5 * jnp.sum(residuals**2)

    return jax.grad(loss, argnums=(0, 1))(theta, u)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _at_optimum(layout, args, theta, u):
    """`(theta, u)` of the optimum found for `args = (points, given parameters, knots)`,
    differentiable in `args` by the implicit function theorem: the gradient of the sum of
    squares vanishes there, so `H dx = -d(gradient)/d(args) d(args)`, `H` the Hessian."""
    del layout, args
    return theta, u


@_at_optimum.defjvp
def _at_optimum_jvp(layout, primals, tangents):
    args, theta, u = primals
    d_args = tangents[0]
    points, _, knots = args
    free = _free_parameters(layout, u, knots)

    def gradient(x, args):
        return _gradient(layout, free, *x, args)

    _, d_gradient = jax.jvp(lambda args: gradient((theta, u), args), (args,), (d_args,))
    _, hessian, local_rows = _point_blocks(layout, theta, u, knots, points, 2)

    def matvec(x):
        return jax.jvp(lambda x: gradient(x, args), ((theta, u),), (x,))[1]

    def solve(_, rhs):
        x_theta, x_u = _reduced_solve(
            layout, hessian, _to_band(layout, rhs[0]), rhs[1], local_rows, free, 0.0
        )
        return _from_band(layout, x_theta), x_u

    rhs = jax.tree.map(jnp.negative, d_gradient)
    d_theta, d_u = jax.lax.custom_linear_solve(matvec, rhs, solve, symmetric=True)
    held, d_held = jax.jvp(
        lambda args: _held_parameters(layout, u, args[1], args[2]), (args,), (d_args,)
    )
    return (theta, jnp.where(free, u, held)), (d_theta, jnp.where(free, d_u, d_held))


@functools.partial(
    jax.jit,
    static_argnames=(
        "degree",
        "rational",
        "correct",
        "closed",
        "hold_last",
        "max_steps",
        "tol",
    ),
)
def _solve(
    points, control, knots, u, *, degree, rational, correct, closed, hold_last, max_steps, tol
):
    """`(control points, weights or None, parameters, steps, converged)` of the fit
    (the free control points of a closed curve)."""
    # Solve for points scaled to unit size around the origin, so that `tol` is relative to
    # the data; NURBS are affine invariant, so the map carries over to the control points.
    centre = jnp.mean(points, axis=0)
    size = jnp.max(jnp.abs(points - centre))
    scale = jnp.where(size > 0, size, 1.0)
    layout = _Layout(
        degree, rational, closed, hold_last, control.shape[0], points.shape[1], correct
    )
    theta = (control - centre) / scale
    if rational:
        theta = jnp.concatenate([theta, jnp.zeros((theta.shape[0], 1), theta.dtype)], 1)
    # Everything the residuals depend on goes in through `args`, so the implicit
    # derivative of the optimum reaches it (the parameters and knots depend on the points).
    args = ((points - centre) / scale, u, knots)
    theta, u_found, steps, converged = _levenberg_marquardt(
        layout,
        *jax.lax.stop_gradient((args[0], knots, theta, u)),
        max_steps=max_steps,
        tol=tol,
    )
    theta, u = _at_optimum(layout, args, theta, u_found)
    control = centre + scale * theta[:, : points.shape[1]]
    weights = jnp.exp(theta[:, -1]) if rational else None
    return control, weights, u, steps, converged
