"""Point inversion: the parameters of the point of a curve or surface nearest to a point.

Two stages, both vectorised over many query points (NURBS Book §6.1):

1. starts: a polyline through samples in every knot span and spread evenly over the
   domain (the grid lines through such samples, for a surface); each query starts from
   its foot on the nearest segment, and also from three others where they could hold
   a nearer point (a second minimum close by, the twin across the seam of a closed
   curve, a second branch) — see `_starts`;
2. a projected Newton method on `f(x) = |S(x) - P|^2 / 2` with Levenberg damping: the exact
   Hessian `J^T J + sum_k r_k S_xx,k` from the analytic second derivatives (Gauss-Newton
   where it is indefinite), a coordinate at a bound of the domain held there while the
   gradient pushes it outwards (ends of a curve, edges and corners of a surface), a step
   accepted only if `f` does not grow.

A general solver (`optimistix.minimise`) knows neither the box of the domain nor the
analytic Hessian, and a batch of solves runs until its slowest member stops; this loop
uses both, and finishes the few slow queries in compact groups (`_minimise`).

The loop runs on values without gradients. A last Newton step on the live values then
gives the derivatives of the optimum by the implicit function theorem
(`dx/dθ = -H^{-1} dg/dθ`, since `g = 0` there); a coordinate held at a bound follows the
bound. `jax.grad` reaches the query points, control points, weights and knots.
"""

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._misc import safe_divide
from ._validate import check_degree, check_finite

# Newton steps: all points together, then the stragglers in groups (see `_minimise`).
_BULK_STEPS = 8
_MAX_STEPS = 50
_STRAGGLERS = 32
# Levenberg damping (relative to |S_x|^2): none at first, this much after the first
# rejected step, then tenfold up after each rejection and down after each success.
_FIRST_DAMPING = 1e-3
# Query points times samples held at once while the nearest sample is searched.
_SEARCH_BLOCK = 2**22


def _query_points(point, dim, dtype):
    """`(flat (N, dim) points, batch shape)`, with the checks of point inversion."""
    point = jnp.asarray(point)
    if point.ndim == 0 or point.shape[-1] != dim:
        raise ValueError(
            f"point must have shape (..., {dim}) (the dimension of the geometry), "
            f"got shape {point.shape}"
        )
    point = check_finite(point.astype(dtype), "point")
    return point.reshape(-1, dim), point.shape[:-1]


def _domain_samples(breaks, count):
    """`count` parameters in every span between the sorted `breaks` (the knots of the
    domain) and as many again spread evenly over the domain (sorted, ends included); the
    steps between them and each sample's gap (the larger of its two steps), neither less
    than the even spacing.

    Both sets: a short span may hold much of the curve (dense control points there), a
    long one may wind around more than once; the nearest sample must lie in the right
    basin in either case. The floor on steps and gaps keeps a cluster of short spans
    from passing for separate basins in `_starts`."""
    starts, ends = breaks[:-1], breaks[1:]
    fractions = jnp.arange(count, dtype=breaks.dtype) / count
    per_span = starts[:, None] + (ends - starts)[:, None] * fractions
    even = jnp.linspace(0.0, 1.0, per_span.size + 1, dtype=breaks.dtype)
    even = starts[0] + (ends[-1] - starts[0]) * even
    samples = jnp.sort(jnp.concatenate([per_span.ravel(), even]))
    steps = jnp.maximum(jnp.diff(samples), even[1] - even[0])
    gaps = jnp.maximum(jnp.pad(steps, (1, 0)), jnp.pad(steps, (0, 1)))
    return samples, steps, gaps


class _Segments(NamedTuple):
    """A polyline through samples of a curve or surface: segment ends `a`, `b` (shape
    `(S, dim)`), their parameters (`(S, d)`), the size of the parameter cell around each
    segment (`(S, d)`), and how far the geometry bulges from each segment (twice the
    distance at the middle parameter, shape `(S,)`)."""

    a: Array
    b: Array
    a_params: Array
    b_params: Array
    extent: Array
    bulge: Array


def _segments(evaluate, a_params, b_params, extent):
    """`_Segments` between the parameters `a_params` and `b_params`, `evaluate(params)`
    giving the points of the geometry."""
    a, b = evaluate(a_params), evaluate(b_params)
    middle = evaluate((a_params + b_params) / 2)
    bulge = 2 * jnp.sqrt(jnp.sum((middle - (a + b) / 2) ** 2, axis=-1))
    return _Segments(a, b, a_params, b_params, extent, bulge)


def _starts(segments, points):
    """Four start parameters per query point, from the polyline segments nearest to it,
    and whether the last three are needed.

    The foot of a query on its nearest segment, with linearly interpolated parameters,
    is the first start: within `O(h^2)` of the geometry's own foot when the query is
    near it. The others: the nearest segment whose foot differs from the first (where
    the geometry turns sharply within a sample spacing, two minima can share one stretch
    of the polyline); the nearest whose foot lies farther from the first foot, in some
    parameter, than the cells of the two segments reach (across the seam of a closed
    curve or surface, the twin of the first; where two branches are almost equally near,
    the other branch); and the segment along which the geometry could come nearest, its
    distance less its bulge (a short segment that cuts a corner of a curved piece). A
    start is needed only if the geometry could come nearer there than at the first;
    Newton runs from each needed start and the nearest result wins.

    Distances are compared as `|A + tD - P|^2 - |P|^2` (matrix products, in blocks so
    that `N x S` never sits in memory whole), after moving the origin to the middle of
    the samples to limit cancellation.

    **Returns:**

    `(starts, needed)` of shapes `(N, 4, d)` and `(N, 3)`.
    """
    origin = jnp.mean(segments.a, axis=0)
    a, points = segments.a - origin, points - origin
    d, d_params = segments.b - segments.a, segments.b_params - segments.a_params
    aa, ad, dd = jnp.sum(a * a, -1), jnp.sum(a * d, -1), jnp.sum(d * d, -1)
    max_aa = jnp.max(aa)

    def foot(along, length2):
        return jnp.clip(safe_divide(along, length2), 0.0, 1.0)

    def start(point, k):
        t = foot(jnp.dot(point - a[k], d[k]), dd[k])
        distance = jnp.sqrt(jnp.sum((a[k] + t * d[k] - point) ** 2))
        return segments.a_params[k] + t * d_params[k], distance

    def nearest(point):
        along = d @ point - ad
        t = foot(along, dd)
        score = aa - 2 * (a @ point) - 2 * t * along + t * t * dd
        # Ties (segments sharing the nearest vertex, all meridians at a pole) go to the
        # segment most nearly perpendicular to the way to the query: the one along which
        # the distance grows slowest, e.g. the meridian towards the query.
        slack = 64 * jnp.finfo(score.dtype).eps * (max_aa + jnp.dot(point, point))
        slope = (t * dd - along) ** 2  # (D . (foot - P))^2, zero for a foot inside
        slope = slope / jnp.maximum(dd * (score + jnp.dot(point, point)), jnp.finfo(dd.dtype).tiny)
        # A segment of zero length (a repeated sample, a grid line squeezed into a pole)
        # has no direction to offer.
        slope = jnp.where(dd == 0, jnp.finfo(dd.dtype).max, slope)

        def best(allowed):
            masked = jnp.where(allowed, score, jnp.inf)
            tied = masked <= jnp.min(masked) + slack
            return jnp.argmin(jnp.where(tied, slope, jnp.inf))

        first = best(True)
        feet = segments.a_params + t[:, None] * d_params
        apart = jnp.abs(feet - feet[first])
        elsewhere = jnp.any(apart > 0, axis=-1)
        far = jnp.any(apart > segments.extent[first] + segments.extent, axis=-1)
        lower = jnp.sqrt(jnp.maximum(score + jnp.dot(point, point), 0.0)) - segments.bulge
        others = jnp.stack(
            [best(elsewhere), best(far), jnp.argmin(jnp.where(elsewhere, lower, jnp.inf))]
        )
        x1, d1 = start(point, first)
        x, distance = jax.vmap(lambda k: start(point, k))(others)
        needed = distance - segments.bulge[others] <= d1 + segments.bulge[first]
        return jnp.concatenate([x1[None], x]), needed

    block = max(1, _SEARCH_BLOCK // a.shape[0])
    return jax.lax.map(nearest, points, batch_size=block)


def _objective(model, x, points):
    """`f`, gradient, Hessian and Gauss-Newton matrix `J^T J` of `|S(x) - P|^2 / 2`."""
    value, jac, hess = model(x)
    residual = value - points
    f = 0.5 * jnp.sum(residual * residual, axis=-1)
    gradient = jnp.einsum("nka,nk->na", jac, residual)
    gauss_newton = jnp.einsum("nka,nkb->nab", jac, jac)
    hessian = gauss_newton + jnp.einsum("nk,nkab->nab", residual, hess)
    return f, gradient, hessian, gauss_newton


def _held(gradient, x, lower, upper):
    """`(at lower, at upper)`: coordinates at a bound whose gradient pushes them outwards."""
    return (x <= lower) & (gradient > 0), (x >= upper) & (gradient < 0)


def _reduce(gradient, hessian, x, lower, upper):
    """The Newton system on the free coordinates: held ones (see `_held`) get an identity
    row and a zero right-hand side."""
    at_lower, at_upper = _held(gradient, x, lower, upper)
    free = ~(at_lower | at_upper)
    eye = jnp.eye(x.shape[-1], dtype=x.dtype)
    hessian = jnp.where(free[:, :, None] & free[:, None, :], hessian, eye)
    return jnp.where(free, gradient, 0.0), hessian


def _newton_step(gradient, hessian):
    """`(-H^{-1} g, H positive definite)` for 1x1 or 2x2 systems; the step is zero where
    `H` is not positive definite (double where: no division by zero, finite gradients)."""
    if gradient.shape[-1] == 1:
        h = hessian[:, 0, 0]
        definite = h > 0
        step = -jnp.where(definite, gradient[:, 0] / jnp.where(definite, h, 1.0), 0.0)
        return step[:, None], definite
    a, b, c = hessian[:, 0, 0], hessian[:, 0, 1], hessian[:, 1, 1]
    g0, g1 = gradient[:, 0], gradient[:, 1]
    det = a * c - b * b
    definite = (a > 0) & (det > 0)
    safe = jnp.where(definite, det, 1.0)
    step = jnp.stack([(b * g1 - c * g0) / safe, (b * g0 - a * g1) / safe], axis=-1)
    return jnp.where(definite[:, None], step, 0.0), definite


def _newton(model, x, points, lower, upper, done, max_steps):
    """The damped projected Newton loop from `x`, except where `done` already; at most
    `max_steps` steps. Returns `(x, f, done)`.

    Where the damped Hessian is not positive definite (far from the curve, beyond a
    centre of curvature) the step is the damped Gauss-Newton one, with `J^T J`.
    """
    tolerance = math.sqrt(jnp.finfo(x.dtype).eps) * (upper - lower)
    tiny = jnp.finfo(x.dtype).tiny
    eye = jnp.eye(x.shape[-1], dtype=x.dtype)

    def step(state):
        i, x, f, gradient, hessian, gauss_newton, damping, done = state
        # The first pass only evaluates at `x` (zero matrices give a zero step): so the
        # model is traced once, in this body, not once more for the initial state.
        fresh = i == 0
        scale = jnp.trace(gauss_newton, axis1=-2, axis2=-1) / x.shape[-1]
        shift = (damping * jnp.maximum(scale, tiny))[:, None, None] * eye
        newton, definite = _newton_step(*_reduce(gradient, hessian + shift, x, lower, upper))
        fallback, usable = _newton_step(*_reduce(gradient, gauss_newton + shift, x, lower, upper))
        trial = jnp.clip(x + jnp.where(definite[:, None], newton, fallback), lower, upper)
        f_t, *derivatives_t = _objective(model, trial, points)
        accept = ((definite | usable) & (f_t <= f) | fresh) & ~done
        small = jnp.all(jnp.abs(trial - x) <= tolerance, axis=-1) & ~fresh

        def pick(new, old):
            return jnp.where(accept.reshape(accept.shape + (1,) * (new.ndim - 1)), new, old)

        raised = jnp.maximum(10 * damping, _FIRST_DAMPING)
        damping = jnp.where(accept, damping / 10, jnp.where(done, damping, raised))
        damping = jnp.where(fresh, 0.0, damping)
        derivatives = (gradient, hessian, gauss_newton)
        kept = [pick(new, old) for new, old in zip(derivatives_t, derivatives, strict=True)]
        # A step too small to matter ends the search even when rejected: the damping
        # has grown until the step vanished, at a kink (a knot of a C0 curve) or at
        # rounding level.
        return (i + 1, pick(trial, x), pick(f_t, f), *kept, damping, done | small)

    def running(state):
        return (state[0] <= max_steps) & ~jnp.all(state[-1])

    n, d = x.shape
    zeros = jnp.zeros((n, d, d), x.dtype)
    state = (0, x, jnp.full(n, jnp.inf, x.dtype), jnp.zeros_like(x), zeros, zeros)
    state = (*state, jnp.zeros(n, x.dtype), done)
    _, x, f, *_, done = jax.lax.while_loop(running, step, state)
    return x, f, done


def _minimise(model, x, points, lower, upper, done):
    """Newton from every start `x` (except where `done`); returns `(x, f)`.

    A loop over all the points runs until the slowest has converged, and a few always
    take many more steps than the rest. So all points take `_BULK_STEPS` steps together;
    the stragglers then continue in groups of `1 / _STRAGGLERS` of the points, each
    group for up to `_MAX_STEPS` more.
    """
    x, f, done = _newton(model, x, points, lower, upper, done, _BULK_STEPS)
    size = max(1, x.shape[0] // _STRAGGLERS)

    def group(carry):
        x, f, done = carry
        index = jnp.nonzero(~done, size=size, fill_value=x.shape[0])[0]
        padding = index == x.shape[0]
        index = jnp.where(padding, 0, index)
        x_group, f_group, _ = _newton(
            model, x[index], points[index], lower, upper, padding, _MAX_STEPS
        )
        keep = jnp.where(padding, x.shape[0], index)  # out of range: dropped by the scatter
        x = x.at[keep].set(x_group, mode="drop")
        f = f.at[keep].set(f_group, mode="drop")
        return x, f, done.at[keep].set(True, mode="drop")

    x, f, _ = jax.lax.while_loop(lambda carry: ~jnp.all(carry[2]), group, (x, f, done))
    return x, f


def _invert(spline, model, starts, points):
    """Minimise on frozen values from each query's first start and from those of its
    other three starts that `_starts` marks as needed, keep the nearest result, then
    attach the derivatives of the optimum (see above).

    `model(spline, x)` gives the points, first and second derivatives at `x` of shape
    `(N, d)`; `starts` is `_starts`'s answer; `spline.domain` gives the bounds.
    """
    (starts, needed), (n, k, d) = starts, starts[0].shape
    frozen, frozen_points = jax.lax.stop_gradient((spline, jnp.repeat(points, k, axis=0)))
    lower, upper = _bounds(frozen)
    skip = jnp.concatenate([jnp.zeros_like(needed[:, :1]), ~needed], axis=1).reshape(n * k)
    x, f = _minimise(
        lambda x: model(frozen, x), starts.reshape(n * k, d), frozen_points, lower, upper, skip
    )
    best = jnp.argmin(f.reshape(n, k), axis=1)
    x = jax.lax.stop_gradient(x.reshape(n, k, d)[jnp.arange(n), best])
    return _attach_derivatives(spline, model, x, points, lower, upper)


def _attach_derivatives(spline, model, x, points, lower, upper):
    """A last Newton step `-H^{-1} g` on the live values: it polishes the converged `x`
    to rounding level, and its derivative is that of the optimum, `-H^{-1} dg/dθ`, by the
    implicit function theorem. A coordinate held at a bound follows the bound (a knot).
    Where the step is not small the optimum sits on a kink (a knot of a C0 curve): no
    step there, and no derivative."""
    tolerance = math.sqrt(jnp.finfo(x.dtype).eps) * (upper - lower)
    live_lower, live_upper = _bounds(spline)
    _, gradient, hessian, _ = _objective(lambda x: model(spline, x), x, points)
    move, _ = _newton_step(*_reduce(gradient, hessian, x, lower, upper))
    smooth = jnp.all(jnp.abs(jax.lax.stop_gradient(move)) <= tolerance, axis=-1, keepdims=True)
    at_lower, at_upper = _held(jax.lax.stop_gradient(gradient), x, lower, upper)
    x = x + jnp.where(smooth, move, 0.0)
    # `where`, not `clip`: the gradient must pass whole to a free coordinate or a bound.
    at_lower, at_upper = at_lower | (x < live_lower), at_upper | (x > live_upper)
    return jnp.where(at_lower, live_lower, jnp.where(at_upper, live_upper, x))


def _bounds(spline):
    """`(lower, upper)` of the domain, each of shape `(d,)`."""
    domain = spline.domain
    if not isinstance(domain[0], tuple):  # a curve: (u_min, u_max)
        domain = (domain,)
    return tuple(jnp.stack(ends) for ends in zip(*domain, strict=True))


def _curve_model(curve, x):
    ders = curve.derivatives(x[:, 0], 2)
    return ders[:, 0], ders[:, 1, :, None], ders[:, 2, :, None, None]


def _surface_model(surface, x):
    return surface._second_order(x[:, 0], x[:, 1])


def _sample_count(samples_per_span, default):
    if samples_per_span is None:
        return default
    return check_degree(samples_per_span, minimum=1, name="samples_per_span")


def curve_closest_point(
    curve, point: ArrayLike, samples_per_span: int | None = None
) -> Float[Array, "..."]:
    """Parameters of the points of `curve` nearest to `point` (see `NURBSCurve.closest_point`)."""
    points, batch = _query_points(point, curve.dim, curve.knots.dtype)
    samples = _sample_count(samples_per_span, 3 * (curve.degree + 1))
    return _curve_parameters(curve, points, samples).reshape(batch)


@eqx.filter_jit
def _curve_parameters(curve, points, samples):
    p = curve.degree
    u, steps, _ = _domain_samples(curve.knots[p:-p], samples)
    u, steps = u[:, None], steps[:, None]
    segments = _segments(lambda x: curve(x[:, 0]), u[:-1], u[1:], steps)
    return _invert(curve, _curve_model, _starts(segments, points), points)[:, 0]


def surface_closest_point(
    surface, point: ArrayLike, samples_per_span: int | None = None
) -> tuple[Float[Array, "..."], Float[Array, "..."]]:
    """Parameters of the points of `surface` nearest to `point` (see
    `AbstractSurface.closest_point`)."""
    points, batch = _query_points(point, surface.dim, jnp.result_type(surface.domain[0][0]))
    sampling = surface._sampling()
    samples = tuple(_sample_count(samples_per_span, default) for _, default in sampling)
    u, v = _surface_parameters(surface, points, tuple(breaks for breaks, _ in sampling), samples)
    return u.reshape(batch), v.reshape(batch)


@eqx.filter_jit
def _surface_parameters(surface, points, breaks, samples):
    us, u_steps, u_gaps = _domain_samples(breaks[0], samples[0])
    vs, v_steps, v_gaps = _domain_samples(breaks[1], samples[1])

    def pairs(x, y):
        return jnp.stack(jnp.broadcast_arrays(x[:, None], y[None, :]), axis=-1)

    grid = pairs(us, vs)
    # The grid lines along u and along v, one segment between neighbouring samples each;
    # a segment's cell spans its own step and the gap to the neighbouring lines.
    a_params = jnp.concatenate([grid[:-1].reshape(-1, 2), grid[:, :-1].reshape(-1, 2)])
    b_params = jnp.concatenate([grid[1:].reshape(-1, 2), grid[:, 1:].reshape(-1, 2)])
    extent = jnp.concatenate(
        [pairs(u_steps, v_gaps).reshape(-1, 2), pairs(u_gaps, v_steps).reshape(-1, 2)]
    )
    segments = _segments(lambda x: surface(x[:, 0], x[:, 1]), a_params, b_params, extent)
    x = _invert(surface, _surface_model, _starts(segments, points), points)
    return x[:, 0], x[:, 1]
