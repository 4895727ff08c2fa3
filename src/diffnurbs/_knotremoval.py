"""Knot removal (NURBS Book A5.8), the simplification of a curve by removing every knot it
can spare within a tolerance, and degree reduction.

Removing a knot is the inverse of inserting it: the control points next to the knot are
solved back from both sides, and the two solutions for the middle point (or the middle
point and the average of its neighbours) must agree for the curve to stay the same. Their
distance bounds how far the curve moves, so a tolerance turns "removable" into "removable
within `tol`". For a rational curve the test is made on the homogeneous points, with the
tolerance scaled by `w_min / (1 + max |P|)` (NURBS Book eq. 5.30), which bounds the
deviation of the projected curve by `tol`.

Degree reduction cuts the curve into its Bezier pieces, replaces each by the Bezier curve of
one degree less that keeps its end points and is nearest in least squares (exact when the
piece was degree-elevated), and then removes the knots the reduced curve can spare.

Everything works on homogeneous control points along axis 0, shape `(n + 1, ...)`, so the
same code serves curves and either direction of a surface (a "row" is then a whole row of
the net, and distances are the largest over its points). The arithmetic works on NumPy or
JAX rows alike: `remove` on JAX arrays is differentiable in the control points (the number
of removals is a discrete choice made on the values); `simplify` and `reduce` use NumPy,
since they try every knot many times.
"""

import numpy as np

from ._basis import bernstein
from ._knotops import bezier_segments, span_breaks
from ._validate import concrete


def knot_index(knots: np.ndarray, degree: int, u: float) -> tuple[int, int]:
    """`(r, s)`: the index of the last copy of the interior knot `u`, and its multiplicity.

    Raises `ValueError` when `u` is not a knot inside the domain.
    """
    lower, upper = knots[degree], knots[len(knots) - degree - 1]
    s = int(np.sum(knots == u))
    if s == 0:
        raise ValueError(f"u = {u} is not a knot of the curve; its knots are {np.unique(knots)}")
    if not lower < u < upper:
        raise ValueError(
            f"u = {u} is an end of the domain [{lower}, {upper}]: only interior knots can be "
            "removed"
        )
    return int(np.flatnonzero(knots == u)[-1]), s


def _distance(a, b) -> float:
    """The largest distance between corresponding points of two rows."""
    return float(np.max(np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1)))


def remove(rows: list, knots: np.ndarray, degree: int, u: float, times: int, tol: float):
    """Remove the knot `u` up to `times` times while the test distance stays within `tol`.

    **Arguments:**

    - `rows`: the homogeneous control points, a list of 1-D arrays (NumPy or JAX).
    - `knots`: the concrete knot vector.
    - `degree`: the degree `p`.
    - `u`, `times`: the knot and how often to try (at most its multiplicity).
    - `tol`: the bound on the test distance in homogeneous space (`inf`: remove `times`
      times whatever the change, which needs no concrete values).

    **Returns:**

    `(rows, knots, removed, error)`: the new rows and knots, how many copies went, and the
    largest test distance of the removals made (0 when none).
    """
    p, order = degree, degree + 1
    r, s = knot_index(knots, degree, u)
    times = min(times, s)
    rows = list(rows)
    n = len(rows) - 1
    first_out = (2 * r - s - p) // 2
    first, last = r - p, r - s
    removed, worst = 0, 0.0
    while removed < times:
        t = removed
        off = first - 1
        temp = {0: rows[off], last + 1 - off: rows[last + 1]}
        i, j, ii, jj = first, last, 1, last - off
        while j - i > t:
            alpha_i = (u - knots[i]) / (knots[i + order + t] - knots[i])
            alpha_j = (u - knots[j - t]) / (knots[j + order] - knots[j - t])
            temp[ii] = (rows[i] - (1 - alpha_i) * temp[ii - 1]) / alpha_i
            temp[jj] = (rows[j] - alpha_j * temp[jj + 1]) / (1 - alpha_j)
            i, ii, j, jj = i + 1, ii + 1, j - 1, jj - 1
        if np.isfinite(tol):
            if j - i < t:
                error = _distance(temp[ii - 1], temp[jj + 1])
            else:
                alpha_i = (u - knots[i]) / (knots[i + order + t] - knots[i])
                error = _distance(
                    rows[i], alpha_i * temp[ii + t + 1] + (1 - alpha_i) * temp[ii - 1]
                )
            if error > tol:
                break
            worst = max(worst, error)
        i, j = first, last
        while j - i > t:
            rows[i], rows[j] = temp[i - off], temp[j - off]
            i, j = i + 1, j - 1
        first, last, removed = first - 1, last + 1, removed + 1
    if removed == 0:
        return rows, knots, 0, 0.0
    knots = np.delete(knots, np.arange(r - removed + 1, r + 1))
    i = j = first_out
    for k in range(1, removed):
        if k % 2 == 1:
            i += 1
        else:
            j -= 1
    return rows[:j] + rows[i + 1 : n + 1], knots, removed, worst


def homogeneous_tolerance(points: np.ndarray, rational: bool, tol: float) -> float:
    """The test distance in homogeneous space that keeps the curve within `tol`
    (NURBS Book eq. 5.30 for rational curves)."""
    if not rational:
        return tol
    weights = points[..., -1]
    largest = np.max(np.linalg.norm(points[..., :-1] / weights[..., None], axis=-1))
    return tol * float(np.min(weights)) / (1 + largest)


def simplify(
    points: np.ndarray,
    knots: np.ndarray,
    degree: int,
    rational: bool,
    tol: float,
    spent: float = 0.0,
):
    """Remove every knot that can go while the curve stays within `tol` of the original.

    Each removal moves the curve by at most its bound, only over the spans its changed
    basis functions cover; those bounds are summed per span of the original knots
    (NURBS Book A9.8's error bookkeeping), and a removal is made only where the sum stays
    within `tol`. Interior knots are tried in turn, each as often as its multiplicity,
    until a sweep removes nothing.

    **Arguments:**

    - `points`, `knots`, `degree`: the homogeneous control points, knots and degree.
    - `rational`: whether the last coordinate of `points` is a weight.
    - `tol`: how far the curve may move.
    - `spent`: how far it has already moved (degree reduction), everywhere.

    **Returns:**

    `(points, knots)` as NumPy arrays.
    """
    breaks = np.unique(knots[degree : len(knots) - degree])
    spent = np.full(len(breaks) - 1, spent)  # deviation bound so far, per original span
    rows = list(points)
    changed = True
    while changed:
        changed = False
        for u in np.unique(knots[degree + 1 : len(knots) - degree - 1]):
            r, s = knot_index(knots, degree, u)
            # Removing `times` copies changes the control points r - p - times + 1 ...
            # r - s + times - 1, whose basis functions cover the parameters between the
            # knots below.
            scale = homogeneous_tolerance(np.stack(rows), rational, 1.0)
            for times in range(s, 0, -1):
                lo = knots[max(r - degree - times + 1, 0)]
                hi = knots[min(r - s + times + degree, len(knots) - 1)]
                affected = (breaks[:-1] < hi) & (breaks[1:] > lo)
                budget = tol - spent[affected].max(initial=0.0)
                if budget <= 0:
                    continue
                new_rows, new_knots, removed, error = remove(
                    rows, knots, degree, u, times, budget * scale
                )
                if removed == times:
                    rows, knots = new_rows, new_knots
                    spent[affected] += error / scale
                    changed = True
                    break
    return np.stack(rows), knots


_SAMPLES = 8
"""Least-squares and error samples per degree of a Bezier piece."""


def _project(points: np.ndarray, rational: bool) -> np.ndarray:
    return points[..., :-1] / points[..., -1:] if rational else points


def reduce(points: np.ndarray, knots: np.ndarray, degree: int, rational: bool, tol: float):
    """The curve of degree `degree - 1` within `tol` of this one (concrete NumPy arrays).

    Each Bezier piece is replaced by the piece of one degree less with the same end points
    that is nearest at `_SAMPLES * degree` Chebyshev points (least squares); its error is
    measured at twice as many points, in space (after the division by the weight). The
    pieces join at knots of multiplicity `degree - 1`, and `simplify` then removes the knots
    the rest of the tolerance allows.

    **Returns:**

    `(points, knots, error)`: the reduced curve and the largest measured error of the pieces.
    Raises `ValueError` when a piece is farther than `tol` from every curve of lower degree.
    """
    p, q = degree, degree - 1
    pieces = [np.asarray(piece) for piece in bezier_segments(points, knots, degree)]
    breaks = span_breaks(knots, degree)
    count = _SAMPLES * p
    fit_at = 0.5 - 0.5 * np.cos(np.pi * (np.arange(count) + 0.5) / count)
    check_at = np.linspace(0.0, 1.0, 2 * count + 1)
    fit_high, fit_low = np.asarray(bernstein(p, fit_at)), np.asarray(bernstein(q, fit_at))
    check_high, check_low = np.asarray(bernstein(p, check_at)), np.asarray(bernstein(q, check_at))
    inner = np.linalg.pinv(fit_low[:, 1:-1]) if q > 1 else None
    reduced, error = [], 0.0
    for k, piece in enumerate(pieces):
        flat = piece.reshape(p + 1, -1)
        ends = np.outer(fit_low[:, 0], flat[0]) + np.outer(fit_low[:, -1], flat[-1])
        middle = inner @ (fit_high @ flat - ends) if q > 1 else np.zeros((0, flat.shape[1]))
        low = np.concatenate([flat[:1], middle, flat[-1:]]).reshape((q + 1, *piece.shape[1:]))
        gap = _project(np.tensordot(check_low, low, 1), rational) - _project(
            np.tensordot(check_high, piece, 1), rational
        )
        piece_error = float(np.max(np.linalg.norm(gap, axis=-1)))
        if piece_error > tol:
            raise ValueError(
                f"no curve of degree {q} is within tol = {tol} of this one: on the knot span "
                f"[{breaks[k]}, {breaks[k + 1]}] the nearest is {piece_error:.3g} away; "
                "expected a larger tol (or more knots, `refine`, before reducing)"
            )
        error = max(error, piece_error)
        reduced.append(low if k == 0 else low[1:])
    points = np.concatenate(reduced)
    knots = np.concatenate([[breaks[0]] * p, np.repeat(breaks[1:-1], q), [breaks[-1]] * p])
    return points, knots.astype(points.dtype), error


def check_tolerance(tol) -> float:
    value = concrete(tol)
    if value is None or np.ndim(value) != 0 or not value > 0:
        raise ValueError(f"tol must be a positive number, got {tol!r}")
    return float(value)
