"""Fitting a B-spline surface to a scattered point cloud: penalised least squares with
parameter correction.

Each data point `Q_k` gets parameters `(u_k, v_k)` from a base surface: by default the
plane of the cloud's principal components (PCA), the parameters being the coordinates in
that plane scaled to `[0, 1]` over the cloud's extent; or a given surface, onto which the
points are projected. The control points of a B-spline surface with uniform clamped knots
on `[0, 1]^2` then minimise

    (1/m) sum_k |S(u_k, v_k) - Q_k|^2 + penalty * E(S),
    E(S) = integral over [0, 1]^2 of |S_uu|^2 + 2 |S_uv|^2 + |S_vv|^2,

the thin-plate energy, a quadratic form `vec(P)^T R vec(P)` with
`R = K2u (x) M0v + 2 K1u (x) K1v + M0u (x) K2v` (`Kk` the Gram matrices of the k-th
derivatives of the basis functions of one direction, computed exactly by Gauss-Legendre
quadrature in each knot span). Its null space is the affine maps of `(u, v)`, which any
three data points not on a line determine: with `penalty > 0` the system is positive
definite however the data are spread (short of a line), and control points without data
nearby follow the least-bending continuation of the rest (a hole is filled fairly).

Parameter correction alternates (a) the linear solve for fixed parameters and (b) the
projection of every point onto the current surface, warm-started from its current
parameters: the projected Newton iteration of `_inversion`, without its global search
(`closest_point` of 10^5 points on a 20 x 20 bicubic took 235 s of CPU, compilation
included; the surface moves little between rounds, so the current parameters are good
starts, and a round costs about as much as the solve). Neither step raises the objective,
so it falls monotonically; the rate is linear, slowest along the surface, where the
residual hardly depends on the parameters (a joint Gauss-Newton step on parameters and
control points, as `fit_curve` takes, would converge faster but couples every point to the
net).
"""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._basis import basis_funs
from ._fit_curve import fit_report
from ._interpolate import _data_points, check_solved
from ._inversion import _bounds, _minimise, _surface_model
from ._knots import clamped_knots
from ._smooth import _band_entries, penalty_band
from ._surface import AbstractSurface, NURBSSurface
from ._validate import (
    check_control_count,
    check_degree,
    check_degree_pair,
    check_pair,
    check_solver_options,
    concrete,
)

# Points whose normal-equation contributions are summed at once (bounds the memory of the
# per-point 16 x 16 blocks of a bicubic to a few MB).
_CHUNK = 4096
# The second principal variance of a cloud on a line is rounding: below this many epsilons
# of the first.
_FLATNESS = 64


class SurfaceFitReport(eqx.Module):
    """What `fit_surface` did.

    - `steps`: rounds of parameter correction (projections onto the surface); 0 without.
    - `rms_residual`, `max_residual`: root mean square and largest distance
      `|S(u_k, v_k) - Q_k|` from the data points to the surface at their parameters (with
      parameter correction, their projections onto the returned surface).
    - `parameters`: the parameters `(u_k, v_k)` of the data points, shape `(m, 2)`.
    - `converged`: whether a round lowered the objective by less than `tol` times itself
      within `max_steps` rounds (always True without parameter correction).
    """

    steps: Array
    rms_residual: Array
    max_residual: Array
    parameters: Float[Array, "m 2"]
    converged: Array


def fit_surface(
    points: ArrayLike,
    n_control: tuple[int, int],
    degree: tuple[int, int] = (3, 3),
    *,
    base: AbstractSurface | None = None,
    penalty: float | None = None,
    correct_parameters: bool = True,
    max_steps: int = 16,
    tol: float | None = None,
    full_output: bool = False,
):
    """Fit a B-spline surface to an unstructured point cloud in 3D.

    Minimises `(1/m) sum_k |S(u_k, v_k) - Q_k|^2 + penalty * E(S)`, `E` the thin-plate
    energy `integral |S_uu|^2 + 2 |S_uv|^2 + |S_vv|^2` over the parameter square `[0, 1]^2`
    (see the module notes), over the control points of a B-spline surface with uniform
    clamped knots on `[0, 1]^2`. The parameters come from the PCA plane of the cloud or
    from `base`; `correct_parameters` then alternates solving and re-projecting the points
    onto the surface.

    Data the model represents exactly are recovered to rounding with `penalty=0`: a
    plane; a polynomial height field `z(x, y)` of degree at most `degree` whose PCA plane
    is the `xy` plane (the parameters are then affine in `x` and `y`); a B-spline height
    field with the same knots, its points parametrised by projection onto the `xy` plane
    as `base`.

    The normal equations are solved densely by Cholesky: for up to a few thousand control
    points (40 x 40) that costs about as much as assembling them from 10^5 points, and it
    compiles in a fraction of a second for any size, whereas the banded solver of the
    library unrolls the half-bandwidth `p nv + q` into the compiled program.

    **Arguments:**

    - `points`: array of shape `(m, 3)`, not all on a line; with `penalty == 0` at least
      `nu nv` of them, and every basis function must be non-zero at some point.
    - `n_control`: `(nu, nv)`, control points per direction, each at least the degree + 1.
    - `degree`: `(p, q)`.
    - `base`: a surface in 3D to project the points onto for their first parameters (its
      domain scaled to `[0, 1]^2`); None gives the PCA plane.
    - `penalty`: weight `>= 0` of the thin-plate energy (scale-free: both terms are
      squared lengths). Its effect grows fast with the number of control points (the
      energy of a wiggle of a net grows like the fourth power of the spans' count): on a
      20 x 20 net, 1e-8 already smooths visibly. None gives a regularisation only,
      `sqrt(eps) trace(A^T A / m) / trace(R)` (`A` the basis matrix at the first
      parameters, `eps` that of the points' dtype): it changes a fit of well-spread data
      at the level of `sqrt(eps)` yet keeps the system regular, so regions without data
      (a hole, the corners of the PCA rectangle that a rotated cloud leaves empty) get
      the least-bending continuation of the rest. That continuation follows the nearby
      data, noise included: over a hole in noisy data, a real weight (`penalty > 0`)
      is what keeps the surface fair.
    - `correct_parameters`: alternate the solve with projections onto the surface.
    - `max_steps`: limit on the rounds of parameter correction.
    - `tol`: stop correcting when a round lowers the objective by less than `tol` times
      itself; None gives `1e-3`.
    - `full_output`: also return a `SurfaceFitReport`.

    **Returns:**

    The fitted non-rational `NURBSSurface` (domain `[0, 1]^2`); with `full_output`,
    `(surface, report)`. `jax.grad` of anything computed from them reaches the points and
    `penalty`: through the PCA plane (or the projection onto `base`) and the linear
    solve. With `correct_parameters` the corrected parameters count as constants: the
    derivative is that of the last solve at fixed parameters, not of the alternating
    iteration (at its limit the parameters move with the points too, which this leaves
    out). `n_control`, `degree`, the flags and `max_steps` must be concrete; the checks of
    values (NaNs, a cloud on a line, a singular system) need concrete points.
    """
    degrees = check_degree_pair(degree)
    points = _data_points(points)
    if points.shape[1] != 3:
        raise ValueError(f"points must have shape (m, 3) (a cloud in 3D), got {points.shape}")
    counts = tuple(
        check_degree(count, name=f"n_control along {axis}")
        for count, axis in zip(check_pair(n_control, "n_control"), "uv", strict=True)
    )
    for count, d, axis in zip(counts, degrees, "uv", strict=True):
        check_control_count(count, d, f"control points along {axis}")
    penalty = _check_penalty(penalty, points.dtype)
    if penalty is not None and concrete(penalty) == 0 and points.shape[0] < counts[0] * counts[1]:
        raise ValueError(
            f"expected at least nu * nv = {counts[0] * counts[1]} points for "
            f"{counts[0]} x {counts[1]} control points with penalty = 0, got "
            f"{points.shape[0]} (use fewer control points or penalty > 0)"
        )
    _check_options(correct_parameters, max_steps, tol, full_output)
    uv = _plane_parameters(points) if base is None else _base_parameters(base, points)
    control, uv, steps, converged = _fit(
        points,
        uv,
        penalty,
        jnp.asarray(max_steps),
        1e-3 if tol is None else float(tol),
        counts=counts,
        degrees=degrees,
        correct_parameters=correct_parameters,
    )
    surface = NURBSSurface(check_solved(control), degrees)
    if not full_output:
        return surface
    errors = surface._points(uv[:, 0], uv[:, 1]) - points
    return surface, fit_report(SurfaceFitReport, errors, steps, uv, converged)


def _check_penalty(penalty, dtype) -> Array | None:
    if penalty is None:
        return None
    value = concrete(penalty)
    if value is not None and not (value.ndim == 0 and np.isfinite(value) and value >= 0):
        raise ValueError(f"penalty must be a finite number >= 0, got {penalty!r}")
    if value is None and jnp.ndim(penalty) != 0:
        raise ValueError(f"penalty must be a scalar, got shape {jnp.shape(penalty)}")
    return jnp.asarray(penalty, dtype=dtype)


def _check_options(correct_parameters, max_steps, tol, full_output):
    for name, flag in (("correct_parameters", correct_parameters), ("full_output", full_output)):
        if not isinstance(flag, bool):
            raise ValueError(f"{name} must be True or False, got {flag!r}")
    check_solver_options(max_steps, tol)


def _check_spread(uv: Array, variances: Array, what: str) -> Array:
    """`uv`, checked: raise when the two largest of the ascending `variances` say that
    the points lie on a line (the second is rounding next to the first)."""
    small, large = variances[-2], variances[-1]
    flat = small <= _FLATNESS * jnp.finfo(variances.dtype).eps * large
    values = concrete(flat)
    if values is None:
        return eqx.error_if(uv, flat, f"{what}: expected a cloud spread in two directions")
    if values:
        raise ValueError(
            f"{what} (principal variances {np.asarray(variances)}): expected a cloud "
            "spread in two directions"
        )
    return uv


def _plane_parameters(points: Array) -> Array:
    uv, variances = _principal_coordinates(points)
    return _check_spread(uv, variances, "the points lie on a line, so their PCA plane is undefined")


@jax.jit
def _principal_coordinates(points: Array) -> tuple[Array, Array]:
    """`(uv, variances)`: the coordinates along the two principal directions scaled to
    `[0, 1]`, and the ascending eigenvalues of the scatter matrix."""
    centred = points - jnp.mean(points, axis=0)
    variances, directions = jnp.linalg.eigh(centred.T @ centred)
    plane = directions[:, :0:-1]  # the two largest, largest first
    # eigh's signs are arbitrary: make each direction's largest component positive, so a
    # small change of the points cannot flip the parametrisation.
    biggest = jnp.take_along_axis(plane, jnp.argmax(jnp.abs(plane), axis=0)[None], axis=0)
    coordinates = centred @ (plane * jnp.sign(biggest))
    lower, upper = jnp.min(coordinates, axis=0), jnp.max(coordinates, axis=0)
    return (coordinates - lower) / (upper - lower), variances


def _base_parameters(base, points: Array) -> Array:
    if not isinstance(base, AbstractSurface):
        raise ValueError(f"base must be a surface (AbstractSurface) or None, got {base!r}")
    if base.dim != 3:
        raise ValueError(f"base must be a surface in 3D, got dim = {base.dim}")
    u, v = base.closest_point(points)
    (u0, u1), (v0, v1) = base.domain
    uv = jnp.stack([(u - u0) / (u1 - u0), (v - v0) / (v1 - v0)], axis=-1).astype(points.dtype)
    centred = uv - jnp.mean(uv, axis=0)
    variances = jnp.linalg.eigvalsh(centred.T @ centred)
    return _check_spread(uv, variances, "the points' parameters on base lie on a line")


def _gram_matrices(knots: Array, degree: int) -> Array:
    """`G[k, i, j] = integral N_i^(k) N_j^(k)` over the domain, `k = 0, 1, 2`: the penalty
    matrices of `smooth` (exact Gauss-Legendre), dense; zero above the degree."""
    n = knots.shape[0] - degree - 1
    rows, cols = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    return jnp.stack(
        [
            _band_entries(penalty_band(knots, degree, k), rows, cols)
            if k <= degree
            else jnp.zeros((n, n), knots.dtype)
            for k in range(3)
        ]
    )


def _thin_plate(knots: tuple[Array, Array], degrees: tuple[int, int]) -> Array:
    """`R` with `vec(P)^T R vec(P) = integral |S_uu|^2 + 2 |S_uv|^2 + |S_vv|^2` for one
    coordinate of the net, `vec` running over `v` fastest."""
    (m0u, k1u, k2u), (m0v, k1v, k2v) = (
        _gram_matrices(k, d) for k, d in zip(knots, degrees, strict=True)
    )
    return jnp.kron(k2u, m0v) + 2 * jnp.kron(k1u, k1v) + jnp.kron(m0u, k2v)


def _normal_equations(points, uv, knots, degrees):
    """`(A^T A, A^T Q)` of the basis matrix `A[k, i nv + j] = N_i(u_k) N_j(v_k)`, assembled
    from the `(p + 1)(q + 1)` non-zero functions at each point, cell by cell of the knot
    grid (a segment sum) and then into the net."""
    (p, q), (knots_u, knots_v) = degrees, knots
    nu, nv = knots_u.shape[0] - p - 1, knots_v.shape[0] - q - 1
    span_u, funs_u = basis_funs(knots_u, p, uv[:, 0])
    span_v, funs_v = basis_funs(knots_v, q, uv[:, 1])
    m, size = points.shape[0], (p + 1) * (q + 1)
    local = (funs_u[:, :, None] * funs_v[:, None, :]).reshape(m, size)
    cells = (nu - p) * (nv - q)
    cell = (span_u - p) * (nv - q) + (span_v - q)
    chunk = min(m, _CHUNK)
    pad = -m % chunk
    chunks = (
        jnp.pad(local, ((0, pad), (0, 0))).reshape(-1, chunk, size),  # zero rows add nothing
        jnp.pad(cell, (0, pad)).reshape(-1, chunk),
    )

    def blocks(chunk):
        values, cell = chunk
        outer = (values[:, :, None] * values[:, None, :]).reshape(values.shape[0], -1)
        return jax.ops.segment_sum(outer, cell, cells)

    summed = jnp.sum(jax.lax.map(blocks, chunks), axis=0).reshape(cells, size, size)
    # The net indices of the cell (i, j)'s functions: rows i..i+p, columns j..j+q.
    first = jnp.arange(cells)
    first = (first // (nv - q)) * nv + first % (nv - q)
    offsets = (jnp.arange(p + 1)[:, None] * nv + jnp.arange(q + 1)).ravel()
    index = first[:, None] + offsets
    n = nu * nv
    gram = jnp.zeros((n, n), points.dtype).at[index[:, :, None], index[:, None, :]].add(summed)
    point_index = (
        ((span_u - p)[:, None] + jnp.arange(p + 1))[:, :, None] * nv
        + ((span_v - q)[:, None] + jnp.arange(q + 1))[:, None, :]
    ).reshape(m, size)
    rhs = jnp.zeros((n, 3), points.dtype).at[point_index].add(local[:, :, None] * points[:, None])
    return gram, rhs


def _solve(points, uv, penalty, knots, degrees):
    """Control points `(nu, nv, 3)` of the penalised fit at parameters `uv`; NaN where the
    system is singular (Cholesky fails)."""
    m = points.shape[0]
    # Both terms ignore translations (the basis sums to one, the energy has second
    # derivatives only): solving for the points about their centroid saves digits.
    centre = jnp.mean(points, axis=0)
    gram, rhs = _normal_equations(points - centre, uv, knots, degrees)
    factor = jax.scipy.linalg.cho_factor(gram / m + penalty)
    control = jax.scipy.linalg.cho_solve(factor, rhs / m) + centre
    return control.reshape(knots[0].shape[0] - degrees[0] - 1, -1, 3)


def _objective(control, uv, points, penalty, knots, degrees):
    """Mean squared distance at the parameters `uv` plus the penalty term, of a net."""
    surface = NURBSSurface(control, degrees, knots)
    squares = jnp.sum((surface._points(uv[:, 0], uv[:, 1]) - points) ** 2, axis=-1)
    flat = control.reshape(-1, 3)
    return jnp.mean(squares) + jnp.sum(flat * (penalty @ flat))


def _regularising(uv, knots, degrees, energy):
    """`sqrt(eps) trace(A^T A / m) / trace(R)`: a weight that makes the penalty a
    perturbation of relative size `sqrt(eps)` of the normal equations (so it biases the
    fit at that level), yet holds the control points without data (the system is solved
    to about `sqrt(eps)` there too)."""
    (p, q), (knots_u, knots_v) = degrees, knots
    squares_u = jnp.sum(basis_funs(knots_u, p, uv[:, 0])[1] ** 2, axis=-1)
    squares_v = jnp.sum(basis_funs(knots_v, q, uv[:, 1])[1] ** 2, axis=-1)
    eps = jnp.finfo(uv.dtype).eps
    return jnp.sqrt(eps) * jnp.mean(squares_u * squares_v) / jnp.trace(energy)


def _project(control, uv, points, knots, degrees):
    """Parameters of the points' feet on the surface, by projected Newton from `uv`."""
    surface = NURBSSurface(control, degrees, knots)
    lower, upper = _bounds(surface)
    done = jnp.zeros(uv.shape[0], bool)
    uv, _ = _minimise(lambda x: _surface_model(surface, x), uv, points, lower, upper, done)
    return uv


@functools.partial(jax.jit, static_argnames=("counts", "degrees", "correct_parameters"))
def _fit(points, uv, weight, max_steps, tol, *, counts, degrees, correct_parameters):
    """`(control points, parameters, steps, converged)` of the fit; `weight` that of the
    thin-plate energy."""
    knots = tuple(
        clamped_knots(n, d, dtype=points.dtype) for n, d in zip(counts, degrees, strict=True)
    )
    energy = _thin_plate(knots, degrees)
    if weight is None:
        # A regularisation, not a model parameter: a constant for the derivatives.
        weight = jax.lax.stop_gradient(_regularising(uv, knots, degrees, energy))
    penalty = weight * energy
    if not correct_parameters:
        control = _solve(points, uv, penalty, knots, degrees)
        return control, uv, jnp.asarray(0), jnp.asarray(True)

    # The rounds run on values without gradients (a while loop has no reverse derivative);
    # the last solve is repeated on the live values below.
    frozen_points, frozen_penalty = jax.lax.stop_gradient((points, penalty))

    def solve(uv):
        return _solve(frozen_points, uv, frozen_penalty, knots, degrees)

    # State: rounds done, the parameters of the last solve and its net, the objective
    # after the last round, the projected parameters, and whether the rounds converged.
    # A round projects onto the net and, unless that ends the search, solves again at the
    # projected parameters (so the net returned is the one the parameters are feet on).
    def round_(state):
        step, solved_at, control, previous, _, _ = state
        projected = _project(control, solved_at, frozen_points, knots, degrees)
        value = _objective(control, projected, frozen_points, frozen_penalty, knots, degrees)
        converged = previous - value <= tol * previous
        stop = converged | (step + 1 >= max_steps)
        solved_at, control = jax.lax.cond(
            stop, lambda: (solved_at, control), lambda: (projected, solve(projected))
        )
        return step + 1, solved_at, control, value, projected, converged

    start = jax.lax.stop_gradient(uv)
    control = solve(start)
    value = _objective(control, start, frozen_points, frozen_penalty, knots, degrees)
    state = (0, start, control, value, start, jnp.asarray(False))
    steps, solved_at, _, _, projected, converged = jax.lax.while_loop(
        lambda state: ~(state[-1] | (state[0] >= max_steps)), round_, state
    )
    control = _solve(points, solved_at, penalty, knots, degrees)
    return control, projected, steps, converged
