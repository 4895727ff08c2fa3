"""Knot removal (NURBS Book A5.8) and the simplification of a curve by removing every knot
it can spare within a tolerance.

Removing a knot is the inverse of inserting it: the control points next to the knot are
solved back from both sides, and the two solutions for the middle point (or the middle
point and the average of its neighbours) must agree for the curve to stay the same. Their
distance bounds how far the curve moves, so a tolerance turns "removable" into "removable
within `tol`". For a rational curve the test is made on the homogeneous points, with the
tolerance scaled by `w_min / (1 + max |P|)` (NURBS Book eq. 5.30), which bounds the
deviation of the projected curve by `tol`.

The arithmetic works on NumPy or JAX rows alike: `remove` on JAX arrays is differentiable in
the control points (the number of removals is a discrete choice made on the values);
`simplify` uses NumPy, since it tries every knot of a curve many times.
"""

import numpy as np

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
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)))


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
    weights = points[:, -1]
    largest = np.max(np.linalg.norm(points[:, :-1] / weights[:, None], axis=1))
    return tol * float(np.min(weights)) / (1 + largest)


def simplify(points: np.ndarray, knots: np.ndarray, degree: int, rational: bool, tol: float):
    """Remove every knot that can go while the curve stays within `tol` of the original.

    Each removal moves the curve by at most its bound, only over the spans its changed
    basis functions cover; those bounds are summed per span of the original knots
    (NURBS Book A9.8's error bookkeeping), and a removal is made only where the sum stays
    within `tol`. Interior knots are tried in turn, each as often as its multiplicity,
    until a sweep removes nothing.

    **Returns:**

    `(points, knots)` as NumPy arrays.
    """
    breaks = np.unique(knots[degree : len(knots) - degree])
    spent = np.zeros(len(breaks) - 1)  # deviation bound so far, per original span
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


def check_tolerance(tol) -> float:
    value = concrete(tol)
    if value is None or np.ndim(value) != 0 or not value > 0:
        raise ValueError(f"tol must be a positive number, got {tol!r}")
    return float(value)
