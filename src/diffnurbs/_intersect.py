"""Every intersection of two curves: subdivision to find them all, Newton to polish them,
and the implicit function theorem for their gradients.

Robust first: both curves are cut into Bezier pieces, and pairs of pieces whose bounding
boxes (which hold the pieces: the convex hull property, weights positive) do not overlap are
dropped; the larger piece of every other pair is halved (de Casteljau at 1/2) until both are
flat to `FLAT` of their size. Each flat pair gives the crossing of its two chords as a start,
Gauss-Newton on `C1(u) - C2(v)` polishes it on the Bezier pieces (in NumPy), and starts that
converge to one point are merged. Tangential contacts converge more slowly but are found the
same way (the distance goes to zero). Two flat pieces that lie on each other within `tol`
are an overlap: reported as an interval, not as points.

Exact last: the polished parameters go through one more Newton step in JAX, outside the
search, whose derivative is the implicit-function one: `jax.grad` reaches the control points,
weights and knots of both curves.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._curve import NURBSCurve
from ._knotops import bezier_pieces
from ._validate import concrete

FLAT = 1e-4
"""A piece is flat when its control points are within this fraction of its size of its chord."""

MAX_DEPTH = 60
NEWTON_STEPS = 60


def halve(h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """De Casteljau at 1/2 on homogeneous control points (the two halves)."""
    left, right, level = [h[0]], [h[-1]], h
    while len(level) > 1:
        level = 0.5 * (level[:-1] + level[1:])
        left.append(level[0])
        right.append(level[-1])
    return np.array(left), np.array(right[::-1])


def _points(h: np.ndarray, rational: bool) -> np.ndarray:
    return h[:, :-1] / h[:, -1:] if rational else h


def homogeneous_bezier(h: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Point and first derivative at `t` of the polynomial Bezier piece whose control points
    run along axis 0 of `h` (de Casteljau; trailing axes ride along, so a patch's net gives
    the row of points and of `u`-derivatives at `t`)."""
    n, levels = len(h) - 1, h
    for _ in range(n - 1):
        levels = (1 - t) * levels[:-1] + t * levels[1:]
    if n == 0:
        return levels[0], np.zeros_like(levels[0])
    return (1 - t) * levels[0] + t * levels[1], n * (levels[1] - levels[0])


def bezier_point(h: np.ndarray, t: float, rational: bool) -> tuple[np.ndarray, np.ndarray]:
    """Point and first derivative of a Bezier piece (homogeneous points `h`) at `t`."""
    point, slope = homogeneous_bezier(h, t)
    if not rational:
        return point, slope
    return point[:-1] / point[-1], (slope[:-1] * point[-1] - point[:-1] * slope[-1]) / point[
        -1
    ] ** 2


class Piece:
    """A Bezier piece of a curve: homogeneous control points on the parameters `[a, b]`."""

    def __init__(self, h, a, b, rational):
        self.h, self.a, self.b, self.rational = h, a, b, rational
        points = _points(h, rational)
        self.low, self.high = points.min(axis=0), points.max(axis=0)
        self.size = float(np.linalg.norm(self.high - self.low))
        chord = points[-1] - points[0]
        length = np.linalg.norm(chord)
        if length > 0:
            offsets = points - points[0]
            along = offsets @ chord / length**2
            deviation = np.linalg.norm(offsets - np.outer(along, chord), axis=1).max()
        else:
            deviation = np.linalg.norm(points - points[0], axis=1).max()
        self.deviation = float(deviation)
        self.ends = points[0], points[-1]

    def halves(self):
        left, right = halve(self.h)
        middle = 0.5 * (self.a + self.b)
        return Piece(left, self.a, middle, self.rational), Piece(
            right, middle, self.b, self.rational
        )


def pieces(curve) -> list[Piece]:
    knots = concrete(curve.knots)
    points = concrete(curve.homogeneous_points())
    if knots is None or points is None:
        raise ValueError(
            "the intersection search needs concrete curves; to differentiate, find the "
            "intersections first and pass them as `start=` inside the function"
        )
    return [
        Piece(np.asarray(h), float(k[0]), float(k[-1]), curve.rational)
        for h, k in bezier_pieces(points, knots, curve.degree)
    ]


def _chord_crossing(p: Piece, q: Piece) -> tuple[float, float]:
    """Parameters in `[0, 1]` of the nearest points of the two pieces' chords."""
    (p0, p1), (q0, q1) = p.ends, q.ends
    matrix = np.stack([p1 - p0, q0 - q1], axis=1)
    s, t = np.linalg.lstsq(matrix, q0 - p0, rcond=None)[0]
    return float(np.clip(s, 0, 1)), float(np.clip(t, 0, 1))


def _distance_to(point: np.ndarray, q: Piece) -> float:
    """Distance from a point to a Bezier piece (Gauss-Newton projection from the chord)."""
    a, b = q.ends
    d = b - a
    t = float(np.clip((point - a) @ d / max(d @ d, 1e-300), 0, 1))
    for _ in range(NEWTON_STEPS):
        x, dx = bezier_point(q.h, t, q.rational)
        t_new = float(np.clip(t + (point - x) @ dx / max(dx @ dx, 1e-300), 0, 1))
        if abs(t_new - t) < 1e-16:
            break
        t = t_new
    return float(np.linalg.norm(point - bezier_point(q.h, t, q.rational)[0]))


def _overlap(p: Piece, q: Piece, tol: float) -> bool:
    """Whether two flat pieces run on each other: the middle of one lies on the other
    within `tol`, and so does an end of one of them (a crossing puts neither there, as the
    pieces are flat)."""
    if min(p.size, q.size) <= 4 * tol:
        return False
    middles = [
        (bezier_point(p.h, 0.5, p.rational)[0], q),
        (bezier_point(q.h, 0.5, q.rational)[0], p),
    ]
    if all(_distance_to(x, other) > tol for x, other in middles):
        return False
    ends = [(x, q) for x in p.ends] + [(x, p) for x in q.ends]
    return any(_distance_to(x, other) <= tol for x, other in ends)


def _polish(p: Piece, q: Piece, s: float, t: float) -> tuple[float, float, float]:
    """Gauss-Newton on the two Bezier pieces from `(s, t)`; returns `(s, t, distance)`."""
    for _ in range(NEWTON_STEPS):
        (x, dx), (y, dy) = bezier_point(p.h, s, p.rational), bezier_point(q.h, t, q.rational)
        step = np.linalg.lstsq(np.stack([dx, -dy], axis=1), y - x, rcond=None)[0]
        s_new, t_new = float(np.clip(s + step[0], 0, 1)), float(np.clip(t + step[1], 0, 1))
        if abs(s_new - s) + abs(t_new - t) < 1e-16:
            break
        s, t = s_new, t_new
    gap = bezier_point(p.h, s, p.rational)[0] - bezier_point(q.h, t, q.rational)[0]
    return s, t, float(np.linalg.norm(gap))


def search(c1, c2, tol: float):
    """`(u1, u2, overlaps)`: the intersection parameters (NumPy, sorted by `u1`) and the
    overlapping intervals `[((u_start, u_end), (v_start, v_end)), ...]`."""
    tops1, tops2 = pieces(c1), pieces(c2)
    found, overlaps = [], []
    stack = [(p, q, i, j, 0) for i, p in enumerate(tops1) for j, q in enumerate(tops2)]
    while stack:
        p, q, i, j, depth = stack.pop()
        if np.any(p.low > q.high + tol) or np.any(q.low > p.high + tol):
            continue
        flat = p.deviation <= FLAT * max(p.size, tol) and q.deviation <= FLAT * max(q.size, tol)
        if flat or depth >= MAX_DEPTH:
            if _overlap(p, q, tol):
                overlaps.append(((p.a, p.b), (q.a, q.b)))
                continue
            s, t = _chord_crossing(p, q)
            top_p, top_q = tops1[i], tops2[j]
            s = (p.a + s * (p.b - p.a) - top_p.a) / (top_p.b - top_p.a)
            t = (q.a + t * (q.b - q.a) - top_q.a) / (top_q.b - top_q.a)
            s, t, gap = _polish(top_p, top_q, s, t)
            if gap <= tol:
                found.append((top_p.a + s * (top_p.b - top_p.a), top_q.a + t * (top_q.b - top_q.a)))
            continue
        if p.size >= q.size:
            stack += [(half, q, i, j, depth + 1) for half in p.halves()]
        else:
            stack += [(p, half, i, j, depth + 1) for half in q.halves()]
    return _merged(found, overlaps, c1, c2, tol)


def _contacts(overlaps, c1, c2, tops1, tops2, tol):
    """Split joined overlap intervals into true overlaps and tangential contacts.

    Near a tangential contact the curves stay within `tol` of each other over a short
    stretch (about `sqrt(tol / curvature)`), so its flat pieces pass the overlap test too.
    On a true overlap the curves coincide: a quarter of the way in from either end their
    distance is rounding. At a contact it grows with the square of the distance from the
    contact and is about `tol / 4` there. Each contact becomes one point, polished by
    Gauss-Newton from the middle of its stretch (linear convergence at a double root).
    """
    if not overlaps:
        return [], []

    def gap(u):  # distance from C1(u) to C2, on the Bezier pieces (NumPy: nothing compiles)
        return min(_distance_to(_point_at(tops1, u), q) for q in tops2)

    true, contacts = [], []
    for interval in overlaps:
        (a, b), (c, d) = interval
        if max(gap(a + (b - a) / 4), gap(b - (b - a) / 4)) <= tol / 100:
            true.append(interval)
        elif (point := _contact(c1, c2, (a + b) / 2, (c + d) / 2, tol)) is not None:
            contacts.append(point)
    return true, contacts


def _point_at(tops, u):
    """The point at `u` of the curve cut into the Bezier pieces `tops` (NumPy)."""
    p = next(q for q in tops if q.a <= u <= q.b)
    return bezier_point(p.h, (u - p.a) / (p.b - p.a), p.rational)[0]


def _contact(c1, c2, u, v, tol):
    """`(u1, u2)` of the contact Gauss-Newton reaches from `(u, v)` on the whole curves, or
    None when the curves are farther apart than `tol` there."""
    start = jnp.asarray([u]), jnp.asarray([v])
    u, v = newton_to_rounding(lambda u, v: polish(c1, c2, u, v), start, (c1.domain, c2.domain))
    if np.linalg.norm(np.asarray(c1(u)) - np.asarray(c2(v))) <= tol:
        return float(u[0]), float(v[0])
    return None


def _merged(found, overlaps, c1, c2, tol):
    """Starts that reached one point counted once; points inside an overlap dropped; the
    overlap intervals joined where they touch; tangential contacts taken out of them."""
    tops1, tops2 = pieces(c1), pieces(c2)
    overlaps, contacts = _contacts(_join(sorted(overlaps)), c1, c2, tops1, tops2, tol)
    found = found + contacts
    points, result = [], []
    for u, v in sorted(found):
        # A point at (or just beyond) the end of an overlap is where the curves start to run
        # together: it extends the overlap (whose end pieces were not flat enough to count).
        near = [
            k
            for k, ((a, b), _) in enumerate(overlaps)
            if a - 0.01 * (b - a) <= u <= b + 0.01 * (b - a)
        ]
        if near:
            (a, b), (c, d) = overlaps[near[0]]
            overlaps[near[0]] = ((min(a, u), max(b, u)), (min(c, v), max(d, v)))
            continue
        x = np.asarray(c1(u))
        if any(np.linalg.norm(x - y) <= max(tol, 1e-9) for y in points):
            continue
        points.append(x)
        result.append((u, v))
    return (*_contacts_merged(result, c1, c2, tops1, tops2, tol), overlaps)


def _contacts_merged(found, c1, c2, tops1, tops2, tol):
    """`(u1, u2)`: the points `found` (sorted along `c1`), each run of them between which
    the curves stay within `tol` of each other replaced by its one contact point. Starts
    near a tangential contact converge only linearly, so in general (not axis-aligned data)
    they stop at many points about `sqrt(tol)` apart along it."""
    runs = []
    for u, v in found:
        if runs:
            (a, c) = runs[-1][-1]
            middle = _point_at(tops1, (a + u) / 2) - _point_at(tops2, (c + v) / 2)
            if np.linalg.norm(middle) <= tol:
                runs[-1].append((u, v))
                continue
        runs.append([(u, v)])
    result = []
    for run in runs:
        if len(run) == 1:
            result += run
            continue
        (a, c), (b, d) = run[0], run[-1]
        point = _contact(c1, c2, (a + b) / 2, (c + d) / 2, tol)
        result += run if point is None else [point]
    u1 = np.array([u for u, _ in result])
    u2 = np.array([v for _, v in result])
    return u1, u2


def _join(intervals):
    joined = []
    for (a, b), (c, d) in intervals:
        if joined and a <= joined[-1][0][1] + 1e-12:
            (a0, _), (c0, d0) = joined[-1]
            joined[-1] = ((a0, b), (min(c0, c), max(d0, d)))
        else:
            joined.append(((a, b), (c, d)))
    return joined


def newton_to_rounding(step, params, domains):
    """Apply `step` (a Newton step on arrays of parameters) from `params`, clipping each
    array into its `(low, high)` of `domains`, until no parameter moves by more than rounding
    (16 ulps of its domain's length), at most `NEWTON_STEPS` times. A crossing converges in
    a few steps; a tangential contact only linearly, halving its error per step."""
    for _ in range(NEWTON_STEPS):
        moved = tuple(
            jnp.clip(x, low, high) for x, (low, high) in zip(step(*params), domains, strict=True)
        )
        change = max(
            float(jnp.max(jnp.abs(new - old), initial=0.0)) / float(high - low)
            for new, old, (low, high) in zip(moved, params, domains, strict=True)
        )
        params = moved
        if change <= 16 * np.finfo(float).eps:
            break
    return params


def polish(c1, c2, u1, u2):
    """One Newton step at the intersections `(u1, u2)`, whose derivative is the implicit-
    function one (the values move only by rounding at a true intersection)."""
    # The parameter checks of `derivatives` stay eager; the step is one compiled program.
    return _newton_step(c1, c2, c1._parameters(u1), c2._parameters(u2))


@eqx.filter_jit
def _newton_step(c1, c2, u1, u2):
    fixed = jax.lax.stop_gradient((u1, u2))
    d1, d2 = c1._derivatives(fixed[0], 1), c2._derivatives(fixed[1], 1)
    gap = d1[:, 0] - d2[:, 0]
    jacobian = jnp.stack([d1[:, 1], -d2[:, 1]], axis=-1)  # (count, dim, 2)
    step = jnp.linalg.pinv(jacobian) @ gap[..., None]
    return fixed[0] - step[:, 0, 0], fixed[1] - step[:, 1, 0]


def curve_intersections(c1, c2, tol: float | None = None, *, start=None, full_output=False):
    """Every intersection of two curves (2D or 3D), tangential contacts included.

    **Arguments:**

    - `c1`, `c2`: `NURBSCurve`s of one dimension.
    - `tol`: how close two points must be to count as an intersection; None:
      `1e-9 (1 + size)`, the size the larger diagonal of the curves' bounding boxes.
    - `start`: `(u1, u2)` found before: the search is skipped and only the last Newton step
      is taken, so the call can sit inside a function that `jax.grad` differentiates
      (the search needs concrete curves).
    - `full_output`: also return the overlaps.

    **Returns:**

    `(u1, u2)`: arrays of the parameters on `c1` and `c2`, sorted along `c1`; with
    `full_output`, `(u1, u2, overlaps)`, `overlaps` a list of
    `((u1_start, u1_end), (u2_start, u2_end))` where the curves run on each other (no
    points are reported inside them). No intersection: empty arrays.
    """
    for name, curve in (("c1", c1), ("c2", c2)):
        if not isinstance(curve, NURBSCurve):
            raise ValueError(f"{name} must be a NURBSCurve, got {type(curve).__name__}")
    if c1.dim != c2.dim:
        raise ValueError(f"the curves must have one dimension, got {c1.dim} and {c2.dim}")
    overlaps = []
    if start is None:
        if tol is None:
            sizes = [p.size for c in (c1, c2) for p in pieces(c)]
            tol = 1e-9 * (1 + max(sizes))
        elif not np.isfinite(tol) or tol <= 0:
            raise ValueError(f"tol must be a positive number, got {tol!r}")
        u1, u2, overlaps = search(c1, c2, float(tol))
    else:
        u1, u2 = start
    u1 = jnp.asarray(u1, dtype=c1.knots.dtype).reshape(-1)
    u2 = jnp.asarray(u2, dtype=c2.knots.dtype).reshape(-1)
    if u1.shape != u2.shape:
        raise ValueError(f"start must be two arrays of one length, got {u1.shape}, {u2.shape}")
    if u1.size:
        u1, u2 = polish(c1, c2, u1, u2)
    return (u1, u2, overlaps) if full_output else (u1, u2)
