"""Adaptive B-spline approximation of a function to a tolerance (seed 003, §5).

The seed's method: put knots where the function changes character — its extrema and
inflection points, found here from `jax.grad` and root finding — start with degree 1
(the function may be piecewise linear), raise the degree, then refine the knots until an
error bound holds. Each fit is a least-squares solve with the machinery of `approximate`.
"""

import functools
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._basis import basis_funs, combine_local
from ._curve import NURBSCurve
from ._interpolate import check_solved, least_squares
from ._validate import check_degree

# Least-squares samples and error checks per knot span, per unit of order p + 1: the check
# grid is dense enough that the error between its points is a few per cent above its maximum
# at worst (a span's error curve has at most a few oscillations).
_SAMPLES_PER_ORDER = 4
_CHECKS_PER_SPAN = 64
_SCAN_POINTS = 4097  # grid on which sign changes of f' and f'' are sought
_BISECTIONS = 64  # halvings of each bracket: below the spacing of floats in any dtype
_MIN_CAPACITY = 64  # spans the padded problem has at least (see `_fit`)
_KINK_FACTOR = 10  # a step of f' this many times what f'' predicts is a kink


class FunctionFitReport(eqx.Module):
    """What `fit_function` did.

    - `max_error`: largest `|spline(t) - f(t)|` on the check grid (`<= tol`).
    - `knots`: the knot vector of the result.
    - `features`: the extrema and inflection points found (interior knots to start from).
    - `kinks`: the jumps of `f'` found (knots of multiplicity `degree`).
    - `degree`, `n_control`: of the result.
    - `steps`: least-squares fits made, over all degrees.
    """

    max_error: float
    knots: Float[Array, " n_control+p+1"]
    features: Float[Array, " k"]
    kinks: Float[Array, " j"]
    degree: int = eqx.field(static=True)
    n_control: int = eqx.field(static=True)
    steps: int = eqx.field(static=True)


def _check_inputs(f, a, b, tol, max_degree):
    if not callable(f):
        raise ValueError(f"f must be a callable t -> f(t), got {f!r}")
    for name, value in (("a", a), ("b", b), ("tol", tol)):
        if np.ndim(value) != 0 or not np.isfinite(value):
            raise ValueError(f"{name} must be a finite number, got {value!r}")
    if not a < b:
        raise ValueError(f"the domain [a, b] must have a < b, got a = {a}, b = {b}")
    if not tol > 0:
        raise ValueError(f"tol must be > 0, got {tol}")
    return check_degree(max_degree, name="max_degree")


def _values(f: Callable, t: Array, what: str = "f") -> Array:
    """`f` at every `t`, as one compiled vectorised call; NaN or inf raise `ValueError`."""
    values = _vmapped(f, t)
    if values.shape != t.shape:
        raise ValueError(
            f"{what} must map a scalar to a scalar, got shape {values.shape[1:]} per point"
        )
    _check_finite_values(values, t, what)
    return values


@functools.partial(jax.jit, static_argnums=0)
def _vmapped(f, t):
    return jax.vmap(f)(t)


def _check_finite_values(values, t, what="f"):
    bad = ~np.isfinite(np.asarray(values))
    if np.any(bad):
        raise ValueError(f"{what} is not finite at t = {float(t[np.argmax(bad)])}")


def _bisect(g, lower, upper, level, sign_lower):
    """Where `g` crosses `level` in each bracket `[lower, upper]`, given the sign of
    `g - level` at `lower` (brackets without a crossing end at `upper`)."""

    def halve(_, bracket):
        lower, upper = bracket
        middle = (lower + upper) / 2
        same = jnp.sign(jax.vmap(g)(middle) - level) == sign_lower
        return jnp.where(same, middle, lower), jnp.where(same, upper, middle)

    lower, upper = jax.lax.fori_loop(0, _BISECTIONS, halve, (lower, upper))
    return (lower + upper) / 2


@functools.partial(jax.jit, static_argnums=0)
def _scan(f, grid):
    """`f'` and `f''` on the grid, and in every cell the crossing of `f'` and of `f''`
    through zero and of `f'` through the middle of its values at the cell ends."""
    first = jax.grad(f)
    second = jax.grad(first)
    d1, d2 = jax.vmap(first)(grid), jax.vmap(second)(grid)
    lower, upper = grid[:-1], grid[1:]
    middle = (d1[:-1] + d1[1:]) / 2
    roots1 = _bisect(first, lower, upper, 0.0, jnp.sign(d1[:-1]))
    roots2 = _bisect(second, lower, upper, 0.0, jnp.sign(d2[:-1]))
    kinks = _bisect(first, lower, upper, middle, jnp.sign(d1[:-1] - middle))
    return d1, d2, roots1, roots2, kinks


def critical_points(f: Callable, a: float, b: float) -> tuple[np.ndarray, np.ndarray]:
    """`(features, kinks)` of `f` on `(a, b)`, each sorted.

    Features are the extrema (`f' = 0`) and inflection points (`f'' = 0`): sign changes on a
    uniform grid, refined by bisection. Sign changes between values that are all tiny next
    to the largest one are rounding noise (`f''` where `f` is linear) and are skipped.
    Kinks are jumps of `f'` (as `|x|` has at 0): a step of `f'` between grid neighbours far
    larger than `f''` there predicts, located by bisection on `f'` against the middle of the
    jump. A kink where `f'` changes sign is both.
    """
    grid = jnp.linspace(a, b, _SCAN_POINTS, dtype=jnp.result_type(float))
    d1, d2, roots1, roots2, kinks = (np.asarray(x) for x in _scan(f, grid))
    _check_finite_values(d1, grid, "f'")
    _check_finite_values(d2, grid, "f''")
    features = []
    for values, roots in ((d1, roots1), (d2, roots2)):
        noise = 1e-6 * np.abs(values).max()
        big = np.maximum(np.abs(values[:-1]), np.abs(values[1:])) > noise
        features.append(roots[(values[:-1] * values[1:] < 0) & big])
        # A sign change through a grid point where the value is exactly zero (f'' of sin 3t
        # at t = 0 on a grid that holds 0) has no cell whose ends differ in sign.
        around = values[:-2] * values[2:] < 0
        big = np.maximum(np.abs(values[:-2]), np.abs(values[2:])) > noise
        features.append(np.asarray(grid)[1:-1][(values[1:-1] == 0) & around & big])
    step = (b - a) / (_SCAN_POINTS - 1)
    jump = np.abs(np.diff(d1))
    predicted = step * np.maximum(np.abs(d2[:-1]), np.abs(d2[1:]))
    jumps = (jump > _KINK_FACTOR * predicted) & (jump > 1e-6 * np.abs(d1).max())
    return _distinct(np.concatenate(features), a, b), _distinct(kinks[jumps], a, b)


def _distinct(points: np.ndarray, a: float, b: float) -> np.ndarray:
    """Sorted, with points closer than a millionth of a scan step merged (a root of both `f'`
    and `f''`), and points that close to an end dropped (the end is a knot anyway)."""
    points = np.unique(points)
    close = (b - a) / _SCAN_POINTS * 1e-6
    keep = (np.diff(points, prepend=a) > close) & (b - points > close)
    return points[keep]


def _knot_vector(breaks: np.ndarray, degree: int, kinks: np.ndarray) -> np.ndarray:
    """Clamped knots with single interior knots at `breaks`, `degree`-fold ones at kinks."""
    times = np.where(np.isin(breaks, kinks), degree, 1)
    times[[0, -1]] = degree + 1
    return np.repeat(breaks, times)


def _span_points(breaks: np.ndarray, per_span: int, offset: float) -> np.ndarray:
    """`per_span` points in every span at fractions `(j + offset) / per_span`."""
    fractions = (np.arange(per_span) + offset) / per_span
    left, width = breaks[:-1, None], np.diff(breaks)[:, None]
    return (left + fractions * width).ravel()


@functools.partial(jax.jit, static_argnums=(0, 6))
def _fit_and_check(f, knots, samples, sample_real, checks, check_real, degree):
    """Least-squares fit of `f` at the real samples (zero at the others), and `(spline, f)`
    at the check points (`f` evaluated only at real points)."""
    a = samples[-1]  # a real point (b) stands in for the others
    f_samples = jnp.where(sample_real, jax.vmap(f)(jnp.where(sample_real, samples, a)), 0.0)
    control = least_squares(samples, f_samples[:, None], knots, degree, None, False)
    span, funs = basis_funs(knots, degree, checks)
    spline = combine_local(funs, control, span, degree)[:, 0]
    f_checks = jnp.where(check_real, jax.vmap(f)(jnp.where(check_real, checks, a)), 0.0)
    return control, spline, f_checks


def _fit(f, breaks, degree, kinks, dtype):
    """Least-squares spline of `degree` on `breaks` (see `_knot_vector`) and the largest error
    in each span on the check grid.

    To compile once per power of two of spans (from 64) rather than for every count, the
    problem is padded with a dummy spline left of `a` that fits zeros: a knot of
    multiplicity `p + 1` at `a` decouples it, so the real part is the same fit.
    """
    spans = len(breaks) - 1
    dummy = max(_MIN_CAPACITY, 1 << spans.bit_length()) - spans
    a = breaks[0]
    lead = a - (breaks[-1] - a) / spans * np.arange(dummy, 0, -1)
    real_knots = _knot_vector(breaks, degree, kinks)
    # the dummy's clamped end at a is the real one's clamped start: a appears p + 1 times
    knots = np.concatenate(
        [_knot_vector(np.append(lead, a), degree, ())[: -degree - 1], real_knots]
    )
    every = np.concatenate([lead, breaks])
    samples = np.concatenate(
        [_span_points(every, _SAMPLES_PER_ORDER * (degree + 1), 0.5), [breaks[0], breaks[-1]]]
    )
    checks = np.append(_span_points(every, _CHECKS_PER_SPAN, 0.0), breaks[-1])
    control, spline, f_checks = _fit_and_check(
        f,
        jnp.asarray(knots, dtype=dtype),
        jnp.asarray(samples, dtype=dtype),
        jnp.asarray(samples >= a),
        jnp.asarray(checks, dtype=dtype),
        jnp.asarray(checks >= a),
        degree,
    )
    real = np.asarray(checks) >= a
    _check_finite_values(np.asarray(f_checks)[real], checks[real])
    control = check_solved(control)
    errors = np.abs(np.asarray(spline - f_checks))
    span_errors = errors[:-1].reshape(-1, _CHECKS_PER_SPAN).max(axis=1)[dummy:]
    span_errors[-1] = max(span_errors[-1], errors[-1])
    n_control = len(real_knots) - degree - 1
    return jnp.asarray(real_knots, dtype=dtype), control[-n_control:], span_errors


def _bisected(breaks: np.ndarray, span_errors: np.ndarray, tol: float) -> np.ndarray:
    """`breaks` with the midpoint of every span whose error exceeds `tol` added."""
    over = span_errors > tol
    return np.sort(np.concatenate([breaks, (breaks[:-1][over] + breaks[1:][over]) / 2]))


def fit_function(
    f: Callable,
    a: float,
    b: float,
    tol: float,
    max_degree: int = 3,
    full_output: bool = False,
    *,
    max_steps: int = 100,
) -> NURBSCurve | tuple[NURBSCurve, FunctionFitReport]:
    """A scalar B-spline `s` on `[a, b]` with `|s(t) - f(t)| <= tol`, with few control points
    (seed 003, §5).

    1. Knots at the extrema and inflection points of `f` (sign changes of `jax.grad(f)`
       and of its derivative on a grid, refined by bisection), and `degree`-fold knots at
       kinks, where `f'` jumps (see `critical_points`).
    2. Least-squares fits with these knots at degree 1, 2, ..., `max_degree`: the first
       that meets the tolerance is returned (a piecewise linear `f` stays linear).
    3. Otherwise, at `max_degree`, every span whose error exceeds `tol` is bisected and
       the fit repeated, until the largest error on the check grid (64 points per span,
       where the error, a low-degree wave per span, cannot hide a larger peak) is `<= tol`.

    **Arguments:**

    - `f`: a JAX-traceable scalar function of a scalar; differentiated twice by `jax.grad`.
    - `a`, `b`: the domain, `a < b` (concrete numbers).
    - `tol`: the error bound, `> 0`. The floating type bounds what is reachable: with
      float32 (JAX's default) tolerances below about `1e-6 * max|f|` fail; enable x64.
    - `max_degree`: the highest degree tried.
    - `full_output`: also return a `FunctionFitReport`.
    - `max_steps`: least-squares fits before giving up.

    **Returns:**

    A `NURBSCurve` with `control_points` of shape `(n, 1)` on the domain `[a, b]`, so that
    `curve(t)[..., 0]` approximates `f(t)`; with `full_output`, `(curve, report)`.

    Raises `ValueError` for bad input and `RuntimeError` when the tolerance is not reached
    (e.g. `f` jumps, or the tolerance is below the rounding of the floating type).
    """
    max_degree = _check_inputs(f, a, b, tol, max_degree)
    dtype = jnp.result_type(float)
    a, b, tol = float(a), float(b), float(tol)
    _values(f, jnp.asarray([a, b], dtype=dtype))
    features, kinks = critical_points(f, a, b)
    breaks = np.concatenate([[a], _distinct(np.concatenate([features, kinks]), a, b), [b]])
    kinks = breaks[np.isin(breaks, kinks)]  # a feature merged with a kink is the kink
    steps = 0
    for degree in range(1, max_degree + 1):
        knots, control, span_errors = _fit(f, breaks, degree, kinks, dtype)
        steps += 1
        if span_errors.max() <= tol:
            break
    smallest = 64 * np.finfo(dtype).eps * max(abs(a), abs(b), b - a)
    while span_errors.max() > tol:
        worst = int(np.argmax(span_errors))
        if steps >= max_steps or breaks[worst + 1] - breaks[worst] < smallest:
            raise RuntimeError(
                f"fit_function did not reach tol = {tol:g}: the error is "
                f"{span_errors.max():.3g} near t = {breaks[worst]:.17g} after {steps} "
                "fits (is f discontinuous there, or the tolerance below float rounding?)"
            )
        breaks = _bisected(breaks, span_errors, tol)
        knots, control, span_errors = _fit(f, breaks, degree, kinks, dtype)
        steps += 1
    curve = NURBSCurve(control, degree, knots)
    if not full_output:
        return curve
    report = FunctionFitReport(
        max_error=float(span_errors.max()),
        knots=knots,
        features=jnp.asarray(features, dtype=dtype),
        kinks=jnp.asarray(kinks, dtype=dtype),
        degree=degree,
        n_control=int(control.shape[0]),
        steps=steps,
    )
    return curve, report
