"""Point inversion: the parameters of the point of a curve or surface nearest to a point.

Two stages, both vectorised over many query points (NURBS Book §6.1):

1. a start: the curve (surface) is sampled at a few parameters per knot span (per pair of
   spans), and every query starts from its nearest sample, which is close to the global
   minimum of the distance;
2. a projected Newton method on `f(x) = |S(x) - P|^2 / 2` with Levenberg damping: the exact
   Hessian `J^T J + sum_k r_k S_xx,k` from the analytic second derivatives, a coordinate at
   a bound of the domain held there while the gradient pushes it outwards (ends of a curve,
   edges and corners of a surface), a step accepted only if `f` does not grow.

A general solver (`optimistix.minimise`) would know neither the box of the domain nor the
analytic Hessian, and would stop each point only when all of them stop; this loop uses
both and freezes every query as soon as its own step is small.

The loop runs on values without gradients. One more Newton step from the converged
parameters, taken on the live curve, gives the derivatives of the optimum by the implicit
function theorem (`dx/dθ = -H^{-1} dg/dθ`, since `g = 0` there) and zero along a
coordinate held at a bound: `jax.grad` reaches the query points, control points, weights
and knots.
"""

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

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


def _span_samples(knots, degree, count):
    """`count` evenly spaced parameters in every knot span of the domain, and its end."""
    starts, ends = knots[degree : -degree - 1], knots[degree + 1 : -degree]
    fractions = jnp.arange(count, dtype=knots.dtype) / count
    inner = starts[:, None] + (ends - starts)[:, None] * fractions
    return jnp.concatenate([inner.ravel(), ends[-1:]])


class _Segments(NamedTuple):
    """A polyline through samples of a curve or surface: segment ends `a`, `b` (shape
    `(S, dim)`), their parameters (`(S, d)`), and how far the geometry bulges from each
    segment (twice the distance at the middle parameter, shape `(S,)`)."""

    a: Array
    b: Array
    a_params: Array
    b_params: Array
    bulge: Array


def _segments(evaluate, a_params, b_params):
    """`_Segments` between the parameters `a_params` and `b_params`, `evaluate(params)`
    giving the points of the geometry."""
    a, b = evaluate(a_params), evaluate(b_params)
    middle = evaluate((a_params + b_params) / 2)
    bulge = 2 * jnp.sqrt(jnp.sum((middle - (a + b) / 2) ** 2, axis=-1))
    return _Segments(a, b, a_params, b_params, bulge)


def _starts(segments, points):
    """Two start parameters per query point, from the polyline segments nearest to it,
    and whether the second one is needed.

    The foot of a query on its nearest segment, with linearly interpolated parameters,
    is the first start: within `O(h^2)` of the geometry's own foot when the query is
    near it. The second is the nearest segment more than two sample spacings away in
    parameter space: across the seam of a closed curve or surface it is the twin of the
    first (equally near, on the other side of the domain); where two branches are almost
    equally near it is the other branch. It is needed only if, bulges included, the
    geometry could come nearer there than at the first start; Newton then runs from both
    and the nearer result wins.

    Distances are compared as `|A + tD - P|^2 - |P|^2` (matrix products, in blocks so
    that `N x S` never sits in memory whole), after moving the origin to the middle of
    the samples to limit cancellation.

    **Returns:**

    `(starts, needed)` of shapes `(N, 2, d)` and `(N,)`.
    """
    origin = jnp.mean(segments.a, axis=0)
    a, points = segments.a - origin, points - origin
    d, d_params = segments.b - segments.a, segments.b_params - segments.a_params
    aa, ad, dd = jnp.sum(a * a, -1), jnp.sum(a * d, -1), jnp.sum(d * d, -1)
    reach = 2 * jnp.max(jnp.abs(d_params), axis=0)

    def foot(along, length2):
        degenerate = length2 == 0
        t = jnp.where(degenerate, 0.0, along / jnp.where(degenerate, 1.0, length2))
        return jnp.clip(t, 0.0, 1.0)

    def start(point, k):
        t = foot(jnp.dot(point - a[k], d[k]), dd[k])
        distance = jnp.sqrt(jnp.sum((a[k] + t * d[k] - point) ** 2))
        return segments.a_params[k] + t * d_params[k], distance

    def nearest(point):
        along = d @ point - ad
        t = foot(along, dd)
        score = aa - 2 * (a @ point) - 2 * t * along + t * t * dd
        first = jnp.argmin(score)
        feet = segments.a_params + t[:, None] * d_params
        away = jnp.any(jnp.abs(feet - feet[first]) > reach, axis=-1)
        second = jnp.argmin(jnp.where(away, score, jnp.inf))
        (x1, d1), (x2, d2) = start(point, first), start(point, second)
        needed = d2 - segments.bulge[second] <= d1 + segments.bulge[first]
        return jnp.stack([x1, x2]), needed

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


def _reduce(gradient, hessian, x, lower, upper):
    """The Newton system on the free coordinates: a coordinate at a bound whose gradient
    pushes it outwards is held (identity row, zero right-hand side)."""
    held = ((x <= lower) & (gradient > 0)) | ((x >= upper) & (gradient < 0))
    free = ~held
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


def _clamp(x, lower, upper):
    # `where`, not `clip`: a coordinate at a bound must keep no gradient, a free one all of it.
    return jnp.where(x < lower, lower, jnp.where(x > upper, upper, x))


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
        scale = jnp.trace(gauss_newton, axis1=-2, axis2=-1) / x.shape[-1]
        shift = (damping * jnp.maximum(scale, tiny))[:, None, None] * eye
        newton, definite = _newton_step(*_reduce(gradient, hessian + shift, x, lower, upper))
        fallback, usable = _newton_step(*_reduce(gradient, gauss_newton + shift, x, lower, upper))
        trial = jnp.clip(x + jnp.where(definite[:, None], newton, fallback), lower, upper)
        f_t, *derivatives_t = _objective(model, trial, points)
        accept = (definite | usable) & (f_t <= f) & ~done
        small = jnp.all(jnp.abs(trial - x) <= tolerance, axis=-1)

        def pick(new, old):
            return jnp.where(accept.reshape(accept.shape + (1,) * (new.ndim - 1)), new, old)

        raised = jnp.maximum(10 * damping, _FIRST_DAMPING)
        damping = jnp.where(accept, damping / 10, jnp.where(done, damping, raised))
        derivatives = (gradient, hessian, gauss_newton)
        kept = [pick(new, old) for new, old in zip(derivatives_t, derivatives, strict=True)]
        return (i + 1, pick(trial, x), pick(f_t, f), *kept, damping, done | (accept & small))

    def running(state):
        return (state[0] < max_steps) & ~jnp.all(state[-1])

    damping = jnp.zeros(x.shape[:1], x.dtype)
    state = (0, x, *_objective(model, x, points), damping, done)
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
    """Minimise from both starts on frozen values, keep the nearer result, then take one
    Newton step on the live values (see above).

    `model(spline, x)` gives the points, first and second derivatives at `x` of shape
    `(N, d)`; `starts` is `_starts`'s answer; `spline.domain` gives the bounds.
    """
    (starts, needed), (n, k, d) = starts, starts[0].shape
    frozen, frozen_points = jax.lax.stop_gradient((spline, jnp.repeat(points, k, axis=0)))
    lower, upper = _bounds(frozen)
    skip = jnp.stack([jnp.zeros_like(needed), ~needed], axis=1).reshape(n * k)
    x, f = _minimise(
        lambda x: model(frozen, x), starts.reshape(n * k, d), frozen_points, lower, upper, skip
    )
    best = jnp.argmin(f.reshape(n, k), axis=1)
    x = jax.lax.stop_gradient(x.reshape(n, k, d)[jnp.arange(n), best])
    lower, upper = _bounds(spline)
    _, gradient, hessian, _ = _objective(lambda x: model(spline, x), x, points)
    move, _ = _newton_step(*_reduce(gradient, hessian, x, lower, upper))
    return _clamp(x + move, lower, upper)


def _bounds(spline):
    """`(lower, upper)` of the domain, each of shape `(d,)`."""
    domain = spline.domain
    if not isinstance(domain[0], tuple):  # a curve: (u_min, u_max)
        domain = (domain,)
    return tuple(jnp.stack(ends) for ends in zip(*domain, strict=True))


def _curve_model(curve, x):
    ders = curve._derivatives(x[:, 0], 2)
    return ders[:, 0], ders[:, 1, :, None], ders[:, 2, :, None, None]


def _surface_model(surface, x):
    ders = surface._derivatives(x[:, 0], x[:, 1], 2)
    jac = jnp.stack([ders[:, 1, 0], ders[:, 0, 1]], axis=-1)
    mixed = ders[:, 1, 1]
    hess = jnp.stack(
        [jnp.stack([ders[:, 2, 0], mixed], axis=-1), jnp.stack([mixed, ders[:, 0, 2]], axis=-1)],
        axis=-2,
    )
    return ders[:, 0, 0], jac, hess


def _sample_count(samples_per_span, default):
    if samples_per_span is None:
        return default
    return check_degree(samples_per_span, minimum=1, name="samples_per_span")


def curve_closest_point(
    curve, point: ArrayLike, samples_per_span: int | None = None
) -> Float[Array, "..."]:
    """Parameters of the points of `curve` nearest to `point` (see `NURBSCurve.closest_point`)."""
    points, batch = _query_points(point, curve.dim, curve.knots.dtype)
    samples = _sample_count(samples_per_span, 2 * (curve.degree + 1))
    return _curve_parameters(curve, points, samples).reshape(batch)


@eqx.filter_jit
def _curve_parameters(curve, points, samples):
    u = _span_samples(curve.knots, curve.degree, samples)[:, None]
    segments = _segments(lambda x: curve._points(x[:, 0]), u[:-1], u[1:])
    return _invert(curve, _curve_model, _starts(segments, points), points)[:, 0]


def surface_closest_point(
    surface, point: ArrayLike, samples_per_span: int | None = None
) -> tuple[Float[Array, "..."], Float[Array, "..."]]:
    """Parameters of the points of `surface` nearest to `point` (see
    `NURBSSurface.closest_point`)."""
    points, batch = _query_points(point, surface.dim, surface.knots_u.dtype)
    samples = tuple(_sample_count(samples_per_span, p + 2) for p in surface.degree)
    u, v = _surface_parameters(surface, points, samples)
    return u.reshape(batch), v.reshape(batch)


@eqx.filter_jit
def _surface_parameters(surface, points, samples):
    p, q = surface.degree
    us = _span_samples(surface.knots_u, p, samples[0])
    vs = _span_samples(surface.knots_v, q, samples[1])
    grid = jnp.stack(jnp.broadcast_arrays(us[:, None], vs[None, :]), axis=-1)
    # The grid lines along u and along v, one segment between neighbouring samples each.
    a_params = jnp.concatenate([grid[:-1].reshape(-1, 2), grid[:, :-1].reshape(-1, 2)])
    b_params = jnp.concatenate([grid[1:].reshape(-1, 2), grid[:, 1:].reshape(-1, 2)])
    segments = _segments(lambda x: surface._points(x[:, 0], x[:, 1]), a_params, b_params)
    x = _invert(surface, _surface_model, _starts(segments, points), points)
    return x[:, 0], x[:, 1]
