"""Knot insertion (Boehm's algorithm, NURBS Book A5.1), refinement, Bezier decomposition,
degree elevation and knot merging.

The functions work on homogeneous control points along axis 0, so the same code serves
curves and either direction of a surface. A knot value may be traced: the span is found
with `find_span` and every new control point is a `where` over the old ones, so the array
shapes depend only on how many knots are inserted.
"""

import jax.numpy as jnp
import numpy as np

from ._basis import basis_matrix, find_span
from ._validate import check_degree, concrete


def _safe_ratio(num, den):
    zero = den == 0
    return jnp.where(zero, 0.0, num / jnp.where(zero, 1.0, den))


def insert_once(points, knots, degree, u):
    """Insert the knot `u` once.

    **Arguments:**

    - `points`: homogeneous control points, shape `(n + 1, ...)`.
    - `knots`: knot vector of length `n + degree + 2`.
    - `degree`: the degree `p`.
    - `u`: the new knot, inside the domain.

    **Returns:**

    `(points, knots)` with one more control point and one more knot; the curve is unchanged.
    """
    span = find_span(knots, degree, u)
    index = jnp.arange(points.shape[0] + 1)
    # alpha_i = (u - u_i) / (u_{i+p} - u_i) on span - p < i <= span; 1 before, 0 after.
    lower = knots[jnp.clip(index, 0, knots.shape[0] - 1)]
    upper = knots[jnp.clip(index + degree, 0, knots.shape[0] - 1)]
    alpha = jnp.where(
        index <= span - degree,
        1.0,
        jnp.where(index > span, 0.0, _safe_ratio(u - lower, upper - lower)),
    )
    alpha = alpha.reshape(alpha.shape + (1,) * (points.ndim - 1))
    current = jnp.concatenate([points, points[-1:]])  # P_i (P_{n+1} is never weighted in)
    previous = jnp.concatenate([points[:1], points])  # P_{i-1}
    new_points = alpha * current + (1.0 - alpha) * previous
    knot_index = jnp.arange(knots.shape[0] + 1)
    shifted = knots[jnp.clip(knot_index - 1, 0, knots.shape[0] - 1)]
    new_knots = jnp.where(
        knot_index <= span,
        knots[jnp.clip(knot_index, 0, knots.shape[0] - 1)],
        jnp.where(knot_index == span + 1, u, shifted),
    )
    return new_points, new_knots


def insert(points, knots, degree, values):
    """Insert the knots `values` one after another (a Python sequence or 1-D array)."""
    for u in values:
        points, knots = insert_once(points, knots, degree, u)
    return points, knots


def bezier_breaks(knots, degree):
    """Knots to insert so that every interior knot has multiplicity `degree` (concrete knots)."""
    knots = np.asarray(knots)
    interior = knots[degree + 1 : -degree - 1]
    values, counts = np.unique(interior, return_counts=True)
    return np.repeat(values, degree - counts)


def check_insertion(knots, degree, u, times):
    """Concrete `u` and knots: the knot may end with multiplicity at most `degree`."""
    times = check_degree(times, minimum=1, name="times")
    values, value = concrete(knots), concrete(u)
    if values is None or value is None:
        return times
    if value.ndim != 0:
        raise ValueError(f"insert one knot value at a time, got shape {value.shape}")
    lower, upper = values[degree], values[-degree - 1]
    if not lower <= value <= upper:
        raise ValueError(f"knot {value} must lie in the domain [{lower}, {upper}]")
    existing = int(np.sum(values == value))
    if existing + times > degree:
        raise ValueError(
            f"knot {value} already has multiplicity {existing}; at most degree = {degree} is "
            f"allowed after insertion, so insert it at most {max(degree - existing, 0)} times"
        )
    return times


def bezier_segments(points, knots, degree):
    """Split refined control points into Bezier pieces (clamped, concrete knots).

    **Returns:**

    List of `(degree + 1, ...)` arrays of control points, one per non-empty span.
    """
    values = np.asarray(knots)
    ends = (np.sum(values == values[degree]), np.sum(values == values[-degree - 1]))
    if ends != (degree + 1, degree + 1):
        raise ValueError(
            f"Bezier decomposition needs clamped end knots (multiplicity degree + 1 = "
            f"{degree + 1}), got multiplicities {ends}"
        )
    points, knots = insert(points, knots, degree, bezier_breaks(values, degree))
    count = (points.shape[0] - 1) // degree
    return [points[j * degree : j * degree + degree + 1] for j in range(count)]


def bezier_knots(a, b, degree, dtype):
    """Knot vector of a single Bezier piece on `[a, b]`."""
    return jnp.asarray([a] * (degree + 1) + [b] * (degree + 1), dtype=dtype)


def span_breaks(knots, degree):
    """The distinct knots of the domain: the ends of the Bezier pieces (concrete knots)."""
    return np.unique(np.asarray(knots)[degree : len(knots) - degree])


def greville(knots, degree):
    """Greville abscissae `(u_{i+1} + ... + u_{i+p}) / p`, one per control point."""
    n_control = knots.shape[0] - degree - 1
    return sum(knots[1 + j : 1 + j + n_control] for j in range(degree)) / degree


def _elevated_knot_indices(knots, times):
    """Indices into `knots` that repeat every distinct value `times` more times."""
    starts = np.flatnonzero(np.r_[True, knots[1:] != knots[:-1]])
    repeats = np.ones(len(knots), dtype=int)
    repeats[starts] += times
    return np.repeat(np.arange(len(knots)), repeats)


def elevate(points, knots, degree, times):
    """Raise the degree by `times` without changing the curve.

    The curve lies in the spline space of degree `p + times` whose knots are the old ones,
    each distinct value `times` more often (the continuity at a knot stays the same). Its
    control points there are found by collocation at the Greville abscissae of that space,
    which satisfy the Schoenberg-Whitney condition, so the system is square and regular.
    This replaces NURBS Book A5.9 (Bezier decomposition, elevation, knot removal) with one
    banded solve, and it is differentiable in the control points.

    **Arguments:**

    - `points`: homogeneous control points, shape `(n + 1, ...)`.
    - `knots`: concrete knot vector (the multiplicities decide the new one).
    - `degree`: the degree `p`.
    - `times`: how much to raise the degree, at least 1.

    **Returns:**

    `(points, knots)` of degree `p + times`.
    """
    values = concrete(knots)
    if values is None:
        raise ValueError(
            "degree elevation needs concrete knots: their multiplicities decide the new knot vector"
        )
    new_degree = degree + times
    new_knots = knots[_elevated_knot_indices(values, times)]
    sites = greville(new_knots, new_degree)
    flat = points.reshape(points.shape[0], -1)
    values_at_sites = basis_matrix(knots, degree, sites) @ flat
    new_points = jnp.linalg.solve(basis_matrix(new_knots, new_degree, sites), values_at_sites)
    return new_points.reshape((-1, *points.shape[1:])), new_knots


def missing_knots(knots, target):
    """The knots to insert into `knots` to reach the non-decreasing `target` (concrete)."""
    values, counts = np.unique(target, return_counts=True)
    have = np.array([np.sum(knots == value) for value in values])
    if np.any(have > counts):
        extra = values[have > counts]
        raise ValueError(f"knots {extra} are more frequent than in the target knot vector")
    return np.repeat(values, counts - have)


def merged_knots(*knot_vectors):
    """The smallest knot vector containing each of `knot_vectors` (concrete, same degree):
    every value with its largest multiplicity."""
    values = np.unique(np.concatenate(knot_vectors))
    counts = [max(np.sum(knots == value) for knots in knot_vectors) for value in values]
    return np.repeat(values, counts)
