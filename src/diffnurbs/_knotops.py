"""Knot insertion and refinement, clamping, Bezier decomposition, degree elevation and
knot merging.

The functions work on homogeneous control points along axis 0, so the same code serves
curves and either direction of a surface. Insertion and refinement compute every new
control point at once as a blossom of the old curve (the Oslo algorithm; the points are
those of Boehm's NURBS Book A5.1, one knot at a time): the knot values may be traced, and
the array shapes depend only on how many knots are inserted. Clamping, decomposition and
elevation need concrete knots, whose multiplicities decide the shapes.
"""

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np

from ._banded import collocation_solve
from ._basis import basis_funs, combine_local, find_span
from ._misc import clamp_to_domain, safe_divide
from ._validate import check_degree, check_parameter, concrete


def insert(points, knots, degree, values):
    """Insert all the knots `values` at once (knot refinement, the Oslo algorithm).

    Every control point of the refined curve is a blossom of the old one: with the new
    knots `tau`, `Q_j = F(tau_{j+1}, ..., tau_{j+p})`, evaluated by de Boor's triangle in
    the old span `mu` with `t_mu <= tau_j < t_{mu+1}`, one blossom argument per level:
    `tau_{j+p}` first, where the denominators span `p` knot intervals, down to `tau_{j+1}`
    in the last level, which spans one (Lyche and Morken's `R_1(tau_{j+1}) ... R_p(tau_{j+p})`).
    The blossom is symmetric, but this order keeps each argument near the knots of its
    level; the reverse order loses about six digits next to short knot spans.
    The points are independent of each other, so the whole refinement is one vectorised
    pass of `O(p^2)` operations per new point (instead of NURBS Book A5.4's sequential
    sweep), and differentiable in the points, the old knots and the inserted values.

    **Arguments:**

    - `points`: homogeneous control points, shape `(n + 1, ...)`.
    - `knots`: knot vector of length `n + degree + 2`.
    - `degree`: the degree `p`.
    - `values`: the knots to insert (any order; may be traced), a sequence or 1-D array.

    **Returns:**

    `(points, knots)` with `len(values)` more control points and knots; the curve is
    unchanged.
    """
    values = jnp.ravel(jnp.asarray(values, dtype=knots.dtype))
    if values.size == 0:
        return points, knots
    return _refined(points, knots, degree, values)


# One compiled program per shape: run op by op, the triangle's few dozen small operations
# were each compiled anew for every control-point count (about 1 s per refinement level).
@functools.partial(jax.jit, static_argnums=2)
def _refined(points, knots, degree, values):
    new_knots = jnp.sort(jnp.concatenate([knots, values]))
    new_index = jnp.arange(points.shape[0] + values.size)
    span = find_span(knots, degree, new_knots[new_index])
    trailing = (1,) * (points.ndim - 1)
    column = [points[span - degree + k] for k in range(degree + 1)]
    for level in range(1, degree + 1):
        argument = new_knots[new_index + degree + 1 - level].reshape(-1, *trailing)
        next_column = []
        for m in range(degree + 1 - level):
            i = span - degree + level + m
            lower = knots[i].reshape(-1, *trailing)
            upper = knots[i + degree + 1 - level].reshape(-1, *trailing)
            alpha = safe_divide(argument - lower, upper - lower)
            next_column.append((1.0 - alpha) * column[m] + alpha * column[m + 1])
        column = next_column
    return column[0], new_knots


def bezier_breaks(knots, degree):
    """Knots to insert so that every interior knot has multiplicity `degree` (concrete knots)."""
    knots = np.asarray(knots)
    interior = knots[degree + 1 : -degree - 1]
    values, counts = np.unique(interior, return_counts=True)
    return np.repeat(values, degree - counts)


def check_insertion(knots, degree, u, times):
    """Checks for inserting one value `times` times; returns `times`."""
    times = check_degree(times, minimum=1, name="times")
    value = concrete(u)
    if value is not None and value.ndim != 0:
        raise ValueError(f"insert one knot value at a time, got shape {value.shape}")
    check_refinement(knots, degree, jnp.full(times, u))
    return times


def checked_insertion(points, knots, degree, u, times):
    """`insert` of the one value `u`, `times` times, after `check_insertion` (which skips
    a traced `u`)."""
    times = check_insertion(knots, degree, u, times)
    return insert(points, knots, degree, [jnp.asarray(u, knots.dtype)] * times)


def checked_refinement(points, knots, degree, values):
    """`insert` of every knot of `values` after `check_refinement` (which skips traced
    values)."""
    values = jnp.ravel(jnp.asarray(values, dtype=knots.dtype))
    check_refinement(knots, degree, values)
    return insert(points, knots, degree, values)


def check_refinement(knots, degree, values):
    """Concrete knots and values: every value in the domain, and no knot with multiplicity
    above `degree` after insertion (traced ones are not checked)."""
    knots, values = concrete(knots), concrete(values)
    if knots is None or values is None:
        return
    check_parameter(values, knots[degree], knots[-degree - 1], name="a knot to insert")
    unique, counts = np.unique(values, return_counts=True)
    for value, times in zip(unique, counts, strict=True):
        existing = int(np.sum(knots == value))
        if existing + times > degree:
            raise ValueError(
                f"knot {value} already has multiplicity {existing}; at most degree = {degree} "
                f"is allowed after insertion, so insert it at most "
                f"{max(degree - existing, 0)} times, not {times}"
            )


def bezier_segments(points, knots, degree):
    """The Bezier pieces of the curve (clamped, concrete knots): every interior knot is
    inserted up to multiplicity `degree`, and the control points are cut into runs of
    `degree + 1` that share their end points.

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


def bezier_pieces(points, knots, degree):
    """`(points, knots)` of every Bezier piece (`bezier_segments`), each with the knot
    vector of its own span."""
    breaks = span_breaks(knots, degree)
    pieces = bezier_segments(points, knots, degree)
    return [
        (piece, bezier_knots(a, b, degree, knots.dtype))
        for piece, a, b in zip(pieces, breaks[:-1], breaks[1:], strict=True)
    ]


def greville(knots, degree):
    """Greville abscissae `(u_{i+1} + ... + u_{i+p}) / p`, one per control point."""
    n_control = knots.shape[0] - degree - 1
    return sum(knots[1 + j : 1 + j + n_control] for j in range(degree)) / degree


def concrete_knots(knots, operation):
    values = concrete(knots)
    if values is None:
        raise ValueError(
            f"{operation} needs concrete knots: their multiplicities decide the new knot vector"
        )
    return values


def clamp(points, knots, degree):
    """The same curve on its domain `[a, b] = [knots[p], knots[n + 1]]` with clamped knots:
    `a` and `b` each `p + 1` times, and no knots beyond them (concrete knots).

    Each end is inserted until it has multiplicity `p` (`insert`, which leaves the curve
    unchanged). Then the basis functions that vanish on the domain are dropped with their
    control points, and the one knot left beyond each end is set to the end: no basis
    function evaluated on the domain reads it. Clamped knots come back as they are.

    **Returns:**

    `(points, knots)`, fewer of each when the knots extended beyond the domain.
    """
    values = concrete_knots(knots, "clamping")
    a, b = values[degree], values[-degree - 1]
    missing = [max(degree - int(np.sum(values == end)), 0) for end in (a, b)]
    points, knots = insert(points, knots, degree, np.repeat([a, b], missing))
    values = np.asarray(knots)
    # Span [a, ...) is the one after the last a; it reads control points from `first` on and
    # knots from `first + 1` on. The span (..., b] reads up to the knot before `stop + p`.
    first = int(np.searchsorted(values, a, side="right")) - 1 - degree
    stop = int(np.searchsorted(values, b, side="left"))
    index = np.arange(first, stop + degree + 1)
    index[0], index[-1] = first + 1, stop + degree - 1
    return points[first:stop], knots[index]


def _elevated_knot_indices(knots, times):
    """Indices into `knots` that repeat every distinct value `times` more times."""
    starts = np.flatnonzero(np.r_[True, knots[1:] != knots[:-1]])
    repeats = np.ones(len(knots), dtype=int)
    repeats[starts] += times
    return np.repeat(np.arange(len(knots)), repeats)


def elevate(points, knots, degree, times):
    """Raise the degree by `times` without changing the curve on its domain.

    The knots are clamped first (`clamp`): beyond the domain, basis functions of the
    elevated space would vanish at every collocation site and make the system singular.
    A knot of multiplicity `p + 1` inside the domain splits the curve into pieces that
    share no control point; each is elevated on its own. On a piece, the curve lies in the
    spline space of degree `q = p + times` whose knots are the old ones, each distinct
    value `times` more often (the continuity at every knot stays the same). Its control
    points there are found by collocation at the Greville abscissae of that space, which
    satisfy the Schoenberg-Whitney condition: the system is square, regular, banded (row
    `k` involves control points `k - q .. k + q`) and totally positive, and
    `collocation_solve` solves it in O(n) without pivoting. This replaces NURBS Book A5.9
    (Bezier decomposition, elevation, knot removal), and it is differentiable in the
    control points.

    **Arguments:**

    - `points`: homogeneous control points, shape `(n + 1, ...)`.
    - `knots`: concrete knot vector (the multiplicities decide the new one).
    - `degree`: the degree `p`.
    - `times`: how much to raise the degree, at least 1.

    **Returns:**

    `(points, knots)` of degree `p + times`, with clamped knots.
    """
    concrete_knots(knots, "degree elevation")
    points, knots = clamp(points, knots, degree)
    values = np.asarray(knots)
    # The first knot of every run of p + 1 equal ones inside the domain starts a piece.
    starts = np.flatnonzero(values[degree + 1 : -degree - 1] == values[2 * degree + 1 : -1])
    cuts = [0, *(starts + degree + 1), points.shape[0]]
    pieces = [
        _elevate_piece(points[i:j], knots[i : j + degree + 1], degree, times)
        for i, j in itertools.pairwise(cuts)
    ]
    new_points = jnp.concatenate([piece for piece, _ in pieces])
    new_knots = jnp.concatenate(
        [pieces[0][1], *(piece_knots[degree + times + 1 :] for _, piece_knots in pieces[1:])]
    )
    return new_points, new_knots


def _elevate_piece(points, knots, degree, times):
    """`elevate` on clamped knots whose interior knots repeat at most `p` times."""
    new_knots = knots[_elevated_knot_indices(np.asarray(knots), times)]
    return _elevated_points(points, knots, new_knots, degree, degree + times), new_knots


# One compiled program per shape, as for `_refined`.
@functools.partial(jax.jit, static_argnums=(3, 4))
def _elevated_points(points, knots, new_knots, degree, new_degree):
    # Rounding can put the mean of equal end knots a hair outside the domain.
    sites = clamp_to_domain(greville(new_knots, new_degree), knots[0], knots[-1])
    flat = points.reshape(points.shape[0], -1)
    span, funs = basis_funs(knots, degree, sites)
    rhs = combine_local(funs, flat, span, degree)
    orders = np.zeros(sites.shape[0], dtype=int)
    new_points = collocation_solve(sites, orders, new_knots, new_degree, rhs)
    return new_points.reshape((-1, *points.shape[1:]))


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
