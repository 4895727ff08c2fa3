"""Arc length as the parameter: the inverse of `NURBSCurve.arc_length`, points at equal arc
length, and a reparametrisation of unit speed.

The length `s(u)` is tabulated once per curve on the sub-panels of the adaptive quadrature
that `arc_length` uses (the knot spans, each cut in four, bisected where the speed has a
sharp feature), so `s(u)` is known to rounding at every sub-panel end. A length is then
inverted inside its sub-panel by Newton's method on `s(u) - s`, the partial length coming
from one Gauss-Legendre rule, with bisection as the safeguard where the speed vanishes.
Inside a sub-panel the curve is one polynomial (homogeneous, if rational), so the speed is
evaluated from its Taylor coefficients at the sub-panel's start: no span search per point.
The result is differentiable: one last Newton step, taken outside the loop, carries the
implicit-function gradient `du/ds = 1 / |C'(u)|` and the gradient with respect to the
curve's control points, weights and knots.
"""

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._basis import taylor_coefficients
from ._misc import safe_divide, safe_norm
from ._quadrature import gauss_legendre, panel_integrals, refined_panels
from ._validate import concrete

_PIECES_PER_SPAN = 4
"""Each knot span starts as this many equal panels of the length table."""

_MAX_STEPS = 64
"""Safeguarded Newton steps at most (bisection alone halves the bracket 64 times)."""


def _speed(curve):
    def speed(u):
        return safe_norm(curve._derivatives(u, 1)[..., 1, :])

    return speed


def length_table(curve) -> tuple[Array, Array, Array]:
    """The sub-panels of the domain, in order, and the length up to each of their ends.

    **Arguments:**

    - `curve`: a `NURBSCurve`.

    **Returns:**

    `(a, b, lengths)`: sub-panel ends (shape `(m,)` each) and the cumulative lengths
    (shape `(m + 1,)`, starting at 0).
    """
    p = curve.degree
    breaks = curve.knots[p:-p]
    fractions = jnp.arange(_PIECES_PER_SPAN + 1, dtype=breaks.dtype) / _PIECES_PER_SPAN
    ends = breaks[:-1, None] + fractions * (breaks[1:] - breaks[:-1])[:, None]
    speed = _speed(curve)
    a, b = refined_panels(speed, ends[:, :-1].ravel(), ends[:, 1:].ravel())
    # Sorted along the domain: by the start, empty sub-panels (repeated knots) first.
    order = jnp.lexsort((jax.lax.stop_gradient(b), jax.lax.stop_gradient(a)))
    a, b = a[order], b[order]
    lengths = jnp.concatenate([jnp.zeros(1, a.dtype), jnp.cumsum(panel_integrals(speed, a, b))])
    return a, b, lengths


def _local_speed(curve, start):
    """The speed near each `start`, `speed(t)` at `start + t`, from the Taylor coefficients of
    the (homogeneous) curve at `start`; `t` has shape `start.shape + extra`."""
    p = curve.degree
    taylor = taylor_coefficients(curve.knots, p, curve.homogeneous_points(), start)

    def speed(t):
        coefficient = taylor.reshape(start.shape + (1,) * (t.ndim - start.ndim) + taylor.shape[-2:])
        value, slope = coefficient[..., p, :], p * coefficient[..., p, :]
        for k in range(p - 1, -1, -1):
            value = value * t[..., None] + coefficient[..., k, :]
            if k > 0:
                slope = slope * t[..., None] + k * coefficient[..., k, :]
        slope = jnp.broadcast_to(slope, value.shape)  # constant in t when p = 1
        if curve.rational:  # (A / w)' = (A' w - A w') / w^2
            point, weight = value[..., :-1], value[..., -1:]
            slope = (slope[..., :-1] * weight - point * slope[..., -1:]) / weight**2
        return safe_norm(slope)

    return speed


def check_lengths(s: Array, total: Array) -> None:
    """Concrete lengths outside `[0, total]` raise `ValueError` (rounding above `total` is
    forgiven); traced ones pass."""
    values, length = concrete(s), concrete(total)
    if values is None or length is None or values.size == 0:
        return
    if not np.all(np.isfinite(values)):
        raise ValueError("s must be finite")
    outside = (values < 0) | (values > length * (1 + 1e-12))
    if np.any(outside):
        where = tuple(int(i) for i in np.argwhere(outside)[0])
        raise ValueError(
            f"s must lie in [0, {length}] (0 to the curve's length), got {values[where]}"
            + (f" at index {where}" if where else "")
        )


def increasing_root(residual, slope, guess, left, right, tolerance):
    """Roots of increasing functions, one per entry, each bracketed by `[left, right]`:
    Newton's method, with bisection where a step would leave the bracket (or the slope is
    zero). Converged entries stop moving. Not differentiable: callers take one more
    Newton step outside (the implicit-function gradient).

    **Arguments:**

    - `residual`, `slope`: the function and its derivative, elementwise on arrays.
    - `guess`, `left`, `right`: arrays of one shape, `left <= guess <= right`.
    - `tolerance`: done where `|residual| <= tolerance` or the bracket is at rounding width.

    **Returns:**

    The roots, shape of `guess`.
    """
    eps = jnp.finfo(guess.dtype).eps

    def open_(u, left, right, value):
        wide = right - left > 4 * eps * jnp.maximum(jnp.abs(u), 1.0)
        return (jnp.abs(value) > tolerance) & wide

    def unfinished(state):
        u, left, right, value, count = state
        return (count < _MAX_STEPS) & jnp.any(open_(u, left, right, value))

    def step(state):
        u, left, right, value, count = state
        active = open_(u, left, right, value)
        left, right = jnp.where(value <= 0, u, left), jnp.where(value > 0, u, right)
        newton = u - safe_divide(value, slope(u))
        bracketed = (newton >= left) & (newton <= right)
        u = jnp.where(active, jnp.where(bracketed, newton, 0.5 * (left + right)), u)
        return u, left, right, jnp.where(active, residual(u), value), count + 1

    return jax.lax.while_loop(unfinished, step, (guess, left, right, residual(guess), 0))[0]


def parameter_at_length(curve, s: Array, table) -> Array:
    """The parameters `u` with `arc_length(lower, u) = s`, for lengths `s` of any shape.

    **Arguments:**

    - `curve`: a `NURBSCurve`.
    - `s`: lengths from the start, in `[0, curve length]`.
    - `table`: `length_table(curve)`.

    **Returns:**

    Parameters of the shape of `s`. Where the curve stands still (zero speed over an
    interval), the first parameter of that interval.
    """
    a, b, lengths = table
    shape, eps = s.shape, jnp.finfo(s.dtype).eps
    s = jnp.clip(s.ravel(), 0.0, lengths[-1])
    # The first sub-panel whose end reaches `s`, forgiving rounding in the running sum: a
    # length where the curve pauses belongs to the panel before the pause.
    slack = 4 * eps * jax.lax.stop_gradient(lengths[-1])
    k = jnp.clip(jnp.searchsorted(lengths[1:], s - slack, side="left"), 0, a.shape[0] - 1)
    lo, hi, target = a[k], b[k], s - lengths[k]

    # The loop finds the root; it is not differentiated (the last step below is).
    fixed, lo0, hi0, target0 = jax.tree_util.tree_map(
        jax.lax.stop_gradient, (curve, lo, hi, target)
    )
    speed = _local_speed(fixed, lo0)
    tolerance = 8 * eps * jnp.maximum(jax.lax.stop_gradient(lengths[-1]), 1.0)

    def residual(u):
        return gauss_legendre(speed, jnp.zeros_like(u), u - lo0) - target0

    # From linear interpolation of the table.
    share = safe_divide(target0, jax.lax.stop_gradient(lengths[k + 1] - lengths[k]))
    guess = lo0 + (hi0 - lo0) * share
    u = increasing_root(residual, lambda u: speed(u - lo0), guess, lo0, hi0, tolerance)
    # One more Newton step, outside the loop: its derivative is the implicit-function one.
    speed = _local_speed(curve, lo)
    u = u - safe_divide(gauss_legendre(speed, jnp.zeros_like(u), u - lo) - target, speed(u - lo))
    lower, upper = curve.domain
    return jnp.where(u < lower, lower, jnp.where(u > upper, upper, u)).reshape(shape)


def _hermite_curve(curve, fractions: np.ndarray, table):
    """The cubic, C^1, piecewise Hermite interpolant in arc length of `curve` at the lengths
    `fractions * L`: its points and unit tangents there, as a curve of `curve`'s class on
    `[0, L]` (double interior knots). Differentiable with respect to `curve`."""
    total = table[2][-1]
    s = jnp.asarray(fractions, dtype=total.dtype) * total
    ders = _at_lengths(curve, s, table)
    points, tangents = ders[:, 0], ders[:, 1] / safe_norm(ders[:, 1])[:, None]
    h = jnp.diff(s)[:, None] / 3
    inner = jnp.stack([points[:-1] + h * tangents[:-1], points[1:] - h * tangents[1:]], axis=1)
    control = jnp.concatenate([points[:1], inner.reshape(-1, points.shape[1]), points[-1:]])
    knots = jnp.concatenate([jnp.repeat(s[:1], 4), jnp.repeat(s[1:-1], 2), jnp.repeat(s[-1:], 4)])
    return type(curve)(control, 3, knots)


_SAMPLES_PER_SEGMENT = 8
"""Where the unit-speed curve is compared with the curve, per segment."""

_MAX_SEGMENTS = 2**17


def _at_lengths(curve, s: Array, table) -> Array:
    """`(C, C')` at the lengths `s`, shape `(len(s), 2, dim)`, computed on `s` padded to a
    power of two and at least 1024 long: the rounds of `unit_speed_curve` and its result
    then compile one or two shapes (each shape costs a compilation of the root finder, far
    more than evaluating a thousand points)."""
    size = 1 << max(int(len(s) - 1).bit_length(), 10)
    padded = jnp.concatenate([s, jnp.zeros(size - len(s), s.dtype)])
    return curve._derivatives(curve._parameter_at_length(padded, table), 1)[: len(s)]


def _padded(curve, s: np.ndarray, table) -> tuple[np.ndarray, np.ndarray]:
    """Points and first derivatives of `curve` at the lengths `s`, in NumPy."""
    ders = np.asarray(_at_lengths(curve, jnp.asarray(s), table))
    return ders[:, 0], ders[:, 1]


def _hermite(points, tangents, s, at):
    """Points and derivatives at `at` (shape `(segments, k)`) of the cubic Hermite curve in
    `s` through `points` with derivatives `tangents` at the lengths `s`."""
    h = np.diff(s)[:, None]
    t = (at - s[:-1, None]) / h
    basis = [2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t, -2 * t**3 + 3 * t**2, t**3 - t**2]
    slopes = [6 * t**2 - 6 * t, 3 * t**2 - 4 * t + 1, -6 * t**2 + 6 * t, 3 * t**2 - 2 * t]
    terms = [points[:-1, None], h[..., None] * tangents[:-1, None], points[1:, None]]
    terms.append(h[..., None] * tangents[1:, None])
    value = sum(b[..., None] * term for b, term in zip(basis, terms, strict=True))
    slope = sum(d[..., None] * term for d, term in zip(slopes, terms, strict=True))
    return value, slope / h[..., None]


def unit_speed_curve(curve, tol: float, table):
    """A cubic curve `R(s)`, `s` in `[0, L]`, with `| |R'(s)| - 1 | <= tol` and
    `|R(s) - C(u(s))| <= tol L`, `u(s)` the parameter at length `s`.

    Segments of a C^1 cubic Hermite interpolant at equal lengths are halved where either
    error exceeds `tol / 2` at `_SAMPLES_PER_SEGMENT` points of the segment (the rounds
    work in NumPy; the result is built once, differentiably, by `_hermite_curve`).
    """
    total = float(table[2][-1])
    if not total > 0:
        raise ValueError("the curve has length 0: no arc-length parametrisation exists")
    spans = curve.knots.shape[0] - 2 * curve.degree - 1
    fractions = np.linspace(0.0, 1.0, max(2, spans + 1))
    inside = (np.arange(_SAMPLES_PER_SEGMENT) + 0.5) / _SAMPLES_PER_SEGMENT
    while True:
        s = fractions * total
        at = s[:-1, None] + np.diff(s)[:, None] * inside
        points, ders = _padded(curve, np.concatenate([s, at.ravel()]), table)
        speed = np.linalg.norm(ders[: len(s)], axis=-1, keepdims=True)
        value, slope = _hermite(points[: len(s)], ders[: len(s)] / speed, s, at)
        exact = points[len(s) :].reshape(value.shape)
        speed_error = np.abs(np.linalg.norm(slope, axis=-1) - 1)
        place_error = np.linalg.norm(value - exact, axis=-1) / total
        error = np.maximum(speed_error, place_error).max(axis=1)
        # Half the bound at the samples, so that it holds between them too.
        bad = error > tol / 2
        if not bad.any():
            return _hermite_curve(curve, fractions, table)
        if len(fractions) + bad.sum() > _MAX_SEGMENTS:
            worst = int(np.argmax(error))
            where = float(curve._parameter_at_length(jnp.asarray(s[worst : worst + 1]), table)[0])
            raise ValueError(
                f"no unit-speed cubic within tol = {tol} with {_MAX_SEGMENTS} segments: the "
                f"worst error, {error[worst]:.2e}, is near u = {where:.6g} (a point of zero "
                "speed, where the direction turns back, has no unit-speed parametrisation); "
                "expected a larger tol, or the curve split at that point"
            )
        middles = 0.5 * (fractions[:-1] + fractions[1:])[bad]
        fractions = np.sort(np.concatenate([fractions, middles]))
