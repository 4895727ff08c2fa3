"""Intersections with surfaces: of a curve and a surface (points), of two surfaces
(branches of curves), found by subdivision, traced by marching, exact by Newton.

Curve and surface: as `curve_intersections`. The curve is cut into Bezier pieces and the
surface into Bezier patches; pairs whose bounding boxes (convex hull property, weights
positive) do not overlap are dropped, and the larger of every other pair is halved (de
Casteljau at 1/2; a patch across its longer direction) until both are flat. Each flat pair
gives a start, the crossing of the chord with the two triangles of the patch's corners;
Gauss-Newton on `C(u) - S(s, t)` polishes it on the Bezier piece and patch (in NumPy), and
starts that reach one point are merged. A curve piece whose nine sample points all lie on
the surface within `tol` is an overlap, reported as an interval of the curve and not
subdivided further. One last Newton step in JAX carries the gradients (implicit function
theorem) to control points, weights and knots of both.

Two surfaces: start points come from (a) each boundary curve of one surface intersected
with the other (the curve-surface search) and (b) flat sub-patch pairs with overlapping
boxes (for loops that touch no boundary), each refined by Gauss-Newton from the patch
centres: its first step is the crossing of the two tangent planes. A pair whose crossing
lies within the pair's size of a traced branch is taken to be on it (a separate loop that
close to another branch is missed). From a start the branch
is marched both ways: the tangent is `n1 x n2`, the step follows the curvature so that a
cubic through the points stays within `tol`, and each predicted point is corrected by
Newton onto both surfaces in the plane through it perpendicular to the tangent (4
unknowns, 4 equations). A march stops on a domain boundary (the last point corrected onto
it), where it returns to its start (closed loop, closed exactly), or where the surfaces
become tangent (`|n1 x n2|` below `_SINGULAR`): there the singular point is located by
Gauss-Newton on `S1 = S2` with the normals parallel and the branch ends at it. Starts lying
on a traced branch are dropped. The points and their parameters are interpolated by cubics
on one parametrization, and points are added where a midpoint of the space curve is off
either surface (evaluated on the parameter curves) by more than `tol`. The settled points
then take one Newton step in JAX (`_polish_branch`, on the same 4 x 4 system with the
plane held fixed) whose derivative is the implicit-function one, and the curves
interpolate them: gradients reach control points, weights and knots of both surfaces.
"""

import bisect
import typing

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy.interpolate import BSpline, make_interp_spline

from ._curve import NURBSCurve
from ._interpolate import interpolate
from ._intersect import (
    FLAT,
    MAX_DEPTH,
    NEWTON_STEPS,
    bezier_point,
    halve,
    homogeneous_bezier,
    newton_to_rounding,
    pieces,
)
from ._knotops import bezier_pieces, span_breaks
from ._surface import NURBSSurface
from ._validate import concrete

_START_FLAT = 2e-2
"""Sub-patch pairs are flat enough to give a start of a surface-surface branch at this
fraction of their size (Newton does the rest; only the starts come from them)."""

_SINGULAR = 1e-2
"""Below this sine of the angle between the normals the surfaces count as tangent."""

_MAX_TURN = 0.15
"""Largest turn of the tangent (radians) over one marching step."""

_MAX_POINTS = 5000
_REFINEMENTS = 8
_BUCKET = 32


def _patch_point(h, s, t, rational):
    """`(S, S_s, S_t)` of a Bezier patch with homogeneous net `h` `(n + 1, m + 1, dim + 1)`
    (or the plain net when not rational) at local parameters `(s, t)` in `[0, 1]`; a stack
    of patches `(n + 1, m + 1, ..., dim + 1)` gives a stack of results."""
    row, row_s = homogeneous_bezier(h, s)
    point, d_t = homogeneous_bezier(row, t)
    d_s, _ = homogeneous_bezier(row_s, t)
    if not rational:
        return point, d_s, d_t
    w = point[..., -1:]
    x = point[..., :-1] / w
    return x, (d_s[..., :-1] - x * d_s[..., -1:]) / w, (d_t[..., :-1] - x * d_t[..., -1:]) / w


class _Patch:
    """A Bezier patch of a surface: homogeneous net `h` on the parameters `u x v`."""

    def __init__(self, h, u, v, rational):
        self.h, self.u, self.v, self.rational = h, u, v, rational
        points = h[..., :-1] / h[..., -1:] if rational else h
        self.corners = points[0, 0], points[-1, 0], points[-1, -1], points[0, -1]
        # Flat: every control point near the bilinear patch of the corners (at its Greville
        # site); then the patch is within that distance of the two corner triangles.
        low, high, size, deviation, along_u = _shapes(h[None], rational)
        self.low, self.high, self.size = low[0], high[0], float(size[0])
        self.deviation, self.along_u = float(deviation[0]), bool(along_u[0])

    def halves(self):
        """The two halves across the longer direction."""
        if self.along_u:
            (a, b), middle = self.u, 0.5 * sum(self.u)
            left, right = halve(self.h)
            return (
                _Patch(left, (a, middle), self.v, self.rational),
                _Patch(right, (middle, b), self.v, self.rational),
            )
        (a, b), middle = self.v, 0.5 * sum(self.v)
        left, right = (np.swapaxes(x, 0, 1) for x in halve(np.swapaxes(self.h, 0, 1)))
        return (
            _Patch(left, self.u, (a, middle), self.rational),
            _Patch(right, self.u, (middle, b), self.rational),
        )

    def local(self, u, v):
        """Local `[0, 1]` parameters of the surface parameters `(u, v)`."""
        return (u - self.u[0]) / (self.u[1] - self.u[0]), (v - self.v[0]) / (self.v[1] - self.v[0])

    def evaluate(self, s, t):
        """`(S, S_u, S_v)` at local parameters, derivatives in the surface's parameters."""
        x, x_s, x_t = _patch_point(self.h, s, t, self.rational)
        return x, x_s / (self.u[1] - self.u[0]), x_t / (self.v[1] - self.v[0])


class _Net:
    """A surface as its grid of Bezier patches, evaluated in NumPy (marching and search)."""

    def __init__(self, surface):
        knots_u, knots_v = (concrete(k) for k in surface.knots)
        points = concrete(surface.homogeneous_points())
        if knots_u is None or knots_v is None or points is None:
            raise ValueError(
                "the intersection search needs concrete surfaces (under jit, say); find the "
                "intersections first and pass them as `start=` inside the function"
            )
        p, q = surface.degree
        self.breaks_u, self.breaks_v = span_breaks(knots_u, p), span_breaks(knots_v, q)
        self.patches = []
        for strip, ku in bezier_pieces(jnp.asarray(points), jnp.asarray(knots_u), p):
            row = []
            for piece, kv in bezier_pieces(jnp.swapaxes(strip, 0, 1), jnp.asarray(knots_v), q):
                u, v = (float(ku[0]), float(ku[-1])), (float(kv[0]), float(kv[-1]))
                h = np.swapaxes(np.asarray(piece), 0, 1)
                row.append(_Patch(h, u, v, surface.rational))
            self.patches.append(row)
        # The interior breaks, as lists for `bisect` (a scalar search, called per point).
        self.inner_u, self.inner_v = list(self.breaks_u[1:-1]), list(self.breaks_v[1:-1])
        self.lower = np.array([self.breaks_u[0], self.breaks_v[0]])
        self.upper = np.array([self.breaks_u[-1], self.breaks_v[-1]])

    def __call__(self, u, v):
        """`(S, J)`: the point and the Jacobian `(3, 2)` at `(u, v)` (extrapolated outside)."""
        i = min(max(bisect.bisect_right(self.inner_u, u), 0), len(self.inner_u))
        j = min(max(bisect.bisect_right(self.inner_v, v), 0), len(self.inner_v))
        patch = self.patches[i][j]
        x, x_u, x_v = patch.evaluate(*patch.local(u, v))
        return x, np.stack([x_u, x_v], axis=1)

    def flat_patches(self):
        return [patch for row in self.patches for patch in row]


def _check_curve(curve, name="curve"):
    if not isinstance(curve, NURBSCurve):
        raise ValueError(f"{name} must be a NURBSCurve, got {type(curve).__name__}")
    if curve.dim != 3:
        raise ValueError(f"{name} must be a curve in 3D (dim 3), got dim {curve.dim}")


def _check_surface(surface, name="surface"):
    if not isinstance(surface, NURBSSurface):
        raise ValueError(f"{name} must be a NURBSSurface, got {type(surface).__name__}")
    if surface.dim != 3:
        raise ValueError(f"{name} must be a surface in 3D (dim 3), got dim {surface.dim}")


def _check_tol(tol):
    if not np.isfinite(tol) or tol <= 0:
        raise ValueError(f"tol must be a positive number, got {tol!r}")
    return float(tol)


# Curve and surface.


def _segment_start(piece, patch):
    """Local `(a, s, t)` where the chord of the piece crosses one of the two triangles of
    the patch's corners (the one it misses least when it misses both)."""
    p0, p1 = piece.ends
    c00, c10, c11, c01 = patch.corners
    best = None
    for corners, to_st in (
        ((c00, c10, c11), lambda b, c: (b + c, c)),
        ((c00, c11, c01), lambda b, c: (b, b + c)),
    ):
        a0, b0, c0 = corners
        matrix = np.stack([p1 - p0, a0 - b0, a0 - c0], axis=1)
        a, b, c = np.linalg.lstsq(matrix, a0 - p0, rcond=None)[0]
        miss = max(0, -a) + max(0, a - 1) + max(0, -b) + max(0, -c) + max(0, b + c - 1)
        if best is None or miss < best[0]:
            best = (miss, a, *to_st(b, c))
    return tuple(float(np.clip(x, 0, 1)) for x in best[1:])


def _polish_point(piece, patch, a, s, t):
    """Gauss-Newton on `C(a) - S(s, t)` (local parameters); returns `(a, s, t, gap, point)`."""
    x = np.array([a, s, t])
    for _ in range(NEWTON_STEPS):
        c, dc = bezier_point(piece.h, x[0], piece.rational)
        y, y_s, y_t = _patch_point(patch.h, x[1], x[2], patch.rational)
        step = np.linalg.lstsq(np.stack([dc, -y_s, -y_t], axis=1), y - c, rcond=None)[0]
        new = np.clip(x + step, 0, 1)
        if np.abs(new - x).sum() < 1e-16:
            break
        x = new
    c = bezier_point(piece.h, x[0], piece.rational)[0]
    y = _patch_point(patch.h, x[1], x[2], patch.rational)[0]
    return (*x, float(np.linalg.norm(c - y)), c)


def _distance_to_patch(point, patch):
    """Distance from a point to a Bezier patch (Gauss-Newton from the nearest of 3 x 3 samples)."""
    grid = np.linspace(0, 1, 3)
    samples = [(s, t) for s in grid for t in grid]
    s, t = min(
        samples,
        key=lambda st: np.linalg.norm(_patch_point(patch.h, *st, patch.rational)[0] - point),
    )
    x = np.array([s, t])
    # Few steps: only whether the distance is below `tol` matters, and from the nearest
    # sample a point that close converges in a handful.
    for _ in range(12):
        y, y_s, y_t = _patch_point(patch.h, x[0], x[1], patch.rational)
        step = np.linalg.lstsq(np.stack([y_s, y_t], axis=1), point - y, rcond=None)[0]
        new = np.clip(x + step, 0, 1)
        if np.abs(new - x).sum() < 1e-14:
            break
        x = new
    return float(np.linalg.norm(point - _patch_point(patch.h, *x, patch.rational)[0]))


def _lies_on(piece, patches, tol, radius):
    """Whether a curve piece lies on the surface: nine points spread along it are within
    `tol` of it (a curve meeting the surface in isolated points has fewer there: the
    pieces have low degree). Pieces within the merging `radius` are not asked: near a
    tangential contact a piece that short lies within `tol` of the surface."""
    if piece.size <= radius:
        return False
    for a in (0.5, 0.0, 1.0, 0.25, 0.75, 0.125, 0.375, 0.625, 0.875):
        x = bezier_point(piece.h, a, piece.rational)[0]
        near = [q for q in patches if np.all(x >= q.low - tol) and np.all(x <= q.high + tol)]
        if min((_distance_to_patch(x, q) for q in near), default=np.inf) > tol:
            return False
    return True


def _curve_surface_search(curve, surface, tol):
    """`(u, s, t, overlaps)` in NumPy, sorted along the curve."""
    tops_c, tops_s = pieces(curve), _Net(surface).flat_patches()
    found, overlaps = [], []
    found_at = ()  # the points of `found`, as one array
    stack = [(p, q, i, j, 0) for i, p in enumerate(tops_c) for j, q in enumerate(tops_s)]
    on_surface = {}  # piece -> whether it lies on the surface (asked once per piece)
    radius = _merge_radius(tol, _model_size(curve, surface))
    while stack:
        p, q, i, j, depth = stack.pop()
        if np.any(p.low > q.high + tol) or np.any(q.low > p.high + tol):
            continue
        # A piece inside the merging radius of a point found already can only find that
        # point again (near a tangential contact at a pole of a sphere, where the patches
        # degenerate, thousands of sliver pairs would otherwise each be polished).
        if len(found_at):
            farthest = np.maximum(abs(p.low - found_at), abs(p.high - found_at))
            if np.any(np.linalg.norm(farthest, axis=1) <= radius):
                continue
        if p not in on_surface:
            on_surface[p] = _lies_on(p, tops_s, tol, radius)
            if on_surface[p]:
                overlaps.append((p.a, p.b))
        if on_surface[p]:
            continue
        flat = p.deviation <= FLAT * max(p.size, tol) and q.deviation <= FLAT * max(q.size, tol)
        if flat or depth >= MAX_DEPTH:
            a, s, t = _segment_start(p, q)
            top_p, top_q = tops_c[i], tops_s[j]
            a = (p.a + a * (p.b - p.a) - top_p.a) / (top_p.b - top_p.a)
            s, t = top_q.local(q.u[0] + s * (q.u[1] - q.u[0]), q.v[0] + t * (q.v[1] - q.v[0]))
            a, s, t, gap, point = _polish_point(top_p, top_q, a, s, t)
            if gap <= tol:
                u = top_p.a + a * (top_p.b - top_p.a)
                s = top_q.u[0] + s * (top_q.u[1] - top_q.u[0])
                t = top_q.v[0] + t * (top_q.v[1] - top_q.v[0])
                found.append((u, s, t, gap, point))
                found_at = np.array([x for *_, x in found])
            continue
        if p.size >= q.size:
            stack += [(half, q, i, j, depth + 1) for half in p.halves()]
        else:
            stack += [(p, half, i, j, depth + 1) for half in q.halves()]
    return _merge_points(found, _join_intervals(overlaps), radius)


def _join_intervals(intervals):
    joined = []
    for a, b in sorted(intervals):
        if joined and a <= joined[-1][1] + 1e-12:
            joined[-1] = (joined[-1][0], max(joined[-1][1], b))
        else:
            joined.append((a, b))
    return joined


def _merge_radius(tol, size):
    """At a tangential contact the gap grows only with the square of the distance, so
    starts stop anywhere within `sqrt(tol size)` of it (on the edge of a neighbouring
    patch, say): points closer than that are one."""
    return float(np.sqrt(tol * (1 + size)))


def _merge_points(found, overlaps, radius):
    """Starts that reached one point (within `radius`) counted once, the closest kept;
    points at or inside an overlap dropped."""
    kept = []
    for u, s, t, gap, point in sorted(found, key=lambda f: f[3]):
        if any(a - 0.01 * (b - a) <= u <= b + 0.01 * (b - a) for a, b in overlaps):
            continue
        if any(np.linalg.norm(point - other[4]) <= radius for other in kept):
            continue
        kept.append((u, s, t, gap, point))
    kept.sort(key=lambda f: f[0])
    u, s, t = (np.array([k[i] for k in kept]) for i in range(3))
    return u, s, t, overlaps


def _polish_curve_surface(curve, surface, u, s, t):
    """One Newton step at the intersections, whose derivative is the implicit-function one."""
    u, s, t = jax.lax.stop_gradient((u, s, t))
    dc = curve.derivatives(u, 1)
    ds = surface.derivatives(s, t, 1)
    gap = dc[:, 0] - ds[:, 0, 0]
    jacobian = jnp.stack([dc[:, 1], -ds[:, 1, 0], -ds[:, 0, 1]], axis=-1)  # (count, 3, 3)
    step = (jnp.linalg.pinv(jacobian) @ gap[..., None])[..., 0]
    return u - step[:, 0], s - step[:, 1], t - step[:, 2]


def _refined(curve, surface, u, s, t):
    """Gauss-Newton on the whole curve and surface from the search's points: a point the
    search polished on one Bezier patch stops on the patch's edge when the contact lies in
    the next patch, and a tangential contact converges only linearly."""
    if not len(u):
        return u, s, t
    u, s, t = newton_to_rounding(
        lambda *x: _polish_curve_surface(curve, surface, *x),
        tuple(jnp.asarray(x) for x in (u, s, t)),
        (curve.domain, *surface.domain),
    )
    return np.asarray(u), np.asarray(s), np.asarray(t)


def _model_size(*objects):
    points = [np.asarray(concrete(o.control_points)).reshape(-1, 3) for o in objects]
    points = np.concatenate(points)
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def curve_surface_intersections(
    curve, surface, tol: float | None = None, *, start=None, full_output=False
):
    """Every intersection of a curve and a surface in 3D, tangential contacts included.

    A ray or a segment is a `NURBSCurve` of degree 1.

    **Arguments:**

    - `curve`: a `NURBSCurve` in 3D.
    - `surface`: a `NURBSSurface` in 3D.
    - `tol`: how close the curve and the surface must come to count as an intersection;
      None: `1e-9 (1 + size)`, the size the diagonal of the box of both control nets.
      Intersections closer than `sqrt(tol (1 + size))` to each other count once (the
      starts of a tangential contact spread that far; Gauss-Newton on the whole curve and
      surface then brings it to about the square root of the rounding).
    - `start`: `(u, s, t)` found before: the search is skipped and only the last Newton step
      is taken, so the call can sit inside a function that `jax.grad` differentiates
      (the search needs concrete inputs).
    - `full_output`: also return the overlaps.

    **Returns:**

    `(u, s, t)`: arrays of the curve parameters and the surface parameters of the
    intersections, sorted along the curve; with `full_output`, `(u, s, t, overlaps)`,
    `overlaps` a list of curve intervals `(u_start, u_end)` where the curve lies on the
    surface (no points are reported inside them). No intersection: empty arrays.
    """
    _check_curve(curve)
    _check_surface(surface)
    overlaps = []
    if start is None:
        tol = 1e-9 * (1 + _model_size(curve, surface)) if tol is None else _check_tol(tol)
        u, s, t, overlaps = _curve_surface_search(curve, surface, tol)
        u, s, t = _refined(curve, surface, u, s, t)
    else:
        u, s, t = start
    dtype = curve.knots.dtype
    u, s, t = (jnp.asarray(x, dtype=dtype).reshape(-1) for x in (u, s, t))
    if not u.shape == s.shape == t.shape:
        raise ValueError(
            f"start must be three arrays of one length, got {u.shape}, {s.shape}, {t.shape}"
        )
    if u.size:
        u, s, t = _polish_curve_surface(curve, surface, u, s, t)
    return (u, s, t, overlaps) if full_output else (u, s, t)


# Two surfaces.


@typing.final
class IntersectionCurve(eqx.Module):
    """One branch of the intersection of two surfaces.

    `curve`, `uv1` and `uv2` share one parameter `w` on `[0, 1]`: `curve(w)` is within
    `tol` of `s1(*uv1(w).T)` and of `s2(*uv2(w).T)`.

    - `curve`: the branch in space, a cubic `NURBSCurve`.
    - `uv1`, `uv2`: the branch in the parameter domains of `s1` and `s2` (2D curves).
    - `closed`: the branch returns to its start in space. The three curves are periodic
      when it also closes in both domains; a loop across the seam of a closed surface
      ends on both sides of the seam (open curves whose ends meet in space).
    - `ends_singular`: `(start, end)`: whether each end is a point where the surfaces are
      tangent (normals parallel: branches cross or touch there), found by Newton.
    - `params`: the traced points the curves interpolate, `(n, 4)` rows `(u1, v1, u2, v2)`
      (the first repeated at the end of a periodic branch), and `sites` their parameters
      `w`, concrete: what `surface_intersections(..., start=branches)` polishes again.
    - `periodic`: the curves are periodic interpolants.
    """

    curve: NURBSCurve
    uv1: NURBSCurve
    uv2: NURBSCurve
    closed: bool = eqx.field(static=True)
    ends_singular: tuple[bool, bool] = eqx.field(static=True)
    params: typing.Any = None
    sites: typing.Any = None
    periodic: bool = eqx.field(static=True, default=False)


class _Pair:
    """Both surfaces in NumPy, and the Newton steps that march on their intersection."""

    def __init__(self, s1, s2, tol, size):
        self.nets = _Net(s1), _Net(s2)
        self.lower = np.concatenate([self.nets[0].lower, self.nets[1].lower])
        self.upper = np.concatenate([self.nets[0].upper, self.nets[1].upper])
        self.tol, self.size = tol, size
        self.span = float(np.max(self.upper - self.lower))
        self.max_step = 0.05 * size

    def evaluate(self, x):
        (p1, j1), (p2, j2) = self.nets[0](x[0], x[1]), self.nets[1](x[2], x[3])
        return p1, j1, p2, j2

    def tangent(self, x):
        """`n1 x n2` of the unit normals: its length is the sine of their angle."""
        _, j1, _, j2 = self.evaluate(x)
        n1, n2 = np.cross(j1[:, 0], j1[:, 1]), np.cross(j2[:, 0], j2[:, 1])
        scale = np.linalg.norm(n1) * np.linalg.norm(n2)
        return np.cross(n1, n2) / scale if scale > 0 else np.zeros(3)

    def correct(self, x, target, direction, bound=None):
        """Newton onto both surfaces in the plane through `target` perpendicular to
        `direction` (or, with `bound = (k, value)`, with parameter `k` held at `value`).
        Returns the parameters, or None when Newton does not converge."""
        x = np.array(x, dtype=float)
        if bound is not None:
            x[bound[0]] = bound[1]
        for _ in range(30):
            p1, j1, p2, j2 = self.evaluate(x)
            matrix = np.zeros((4, 4))
            matrix[:3, :2], matrix[:3, 2:] = j1, -j2
            residual = np.zeros(4)
            residual[:3] = p1 - p2
            if bound is None:
                matrix[3, :2] = direction @ j1
                residual[3] = direction @ (p1 - target)
            else:
                matrix[3, bound[0]] = 1.0
            step = np.linalg.lstsq(matrix, -residual, rcond=None)[0]
            x = x + step
            if np.linalg.norm(step) <= 1e-15 * (1 + np.linalg.norm(x)):
                break
        p1, _, p2, _ = self.evaluate(x)
        if not np.all(np.isfinite(x)) or np.linalg.norm(p1 - p2) > 1e-3 * self.tol:
            return None
        return x

    def onto(self, x, steps=NEWTON_STEPS):
        """Gauss-Newton (least-norm steps) from `x` onto the intersection; None if it fails.
        From two patch centres its first step is the crossing of the tangent planes."""
        x = np.array(x, dtype=float)
        for _ in range(steps):
            p1, j1, p2, j2 = self.evaluate(x)
            step = np.linalg.lstsq(np.concatenate([j1, -j2], axis=1), p2 - p1, rcond=None)[0]
            x = np.clip(x + step, self.lower, self.upper)
            if np.linalg.norm(step) <= 1e-15 * (1 + np.linalg.norm(x)):
                break
        p1, _, p2, _ = self.evaluate(x)
        return x if steps == 1 or np.linalg.norm(p1 - p2) <= 1e-3 * self.tol else None

    def singular_point(self, x):
        """Gauss-Newton on `S1 = S2` with `n1` perpendicular to both tangents of `S2` (the
        normals parallel), from `x`; None if it does not converge."""

        def equations(x):
            p1, j1, p2, j2 = self.evaluate(x)
            n1 = np.cross(j1[:, 0], j1[:, 1])
            n1 = n1 / max(np.linalg.norm(n1), 1e-300)
            return np.concatenate([p1 - p2, self.size * (n1 @ j2)])

        x = np.array(x, dtype=float)
        for _ in range(NEWTON_STEPS):
            f = equations(x)
            jacobian = np.stack(
                [(equations(x + e) - equations(x - e)) / 2e-7 for e in 1e-7 * np.eye(4)], axis=1
            )
            step = np.linalg.lstsq(jacobian, -f, rcond=None)[0]
            x = x + step
            if np.linalg.norm(step) <= 1e-13 * (1 + np.linalg.norm(x)):
                break
        ok = (
            np.all(np.isfinite(x))
            and np.all(x >= self.lower - 1e-9)
            and np.all(x <= self.upper + 1e-9)
        )
        if not ok or np.linalg.norm(equations(x)[:3]) > self.tol:
            return None
        return np.clip(x, self.lower, self.upper)

    def step_length(self, curvature):
        """The step after which a cubic through the points deviates by about `tol / 4`
        (interpolation error `5 h^4 k^3 / 384` of a curve of curvature `k`)."""
        length = (384 / 5 * self.tol / 4 / max(curvature, 1e-12) ** 3) ** 0.25
        return min(length, self.max_step, _MAX_TURN / max(curvature, 1e-12))

    def point(self, x):
        return self.evaluate(x)[0]

    def march(self, x0, sign):
        """Points from `x0` (excluded) along `sign * tangent` and how the march ended:
        "boundary", "closed" (back at `x0`), "singular" (the last point is where the
        surfaces are tangent) or "stalled"."""
        start = self.point(x0)
        tangent = sign * self.tangent(x0)
        sine_here = np.linalg.norm(tangent)
        tangent = tangent / sine_here
        x, here, length, travelled = x0, start, self.max_step / 8, 0.0
        out = []
        while len(out) < _MAX_POINTS:
            slope = np.concatenate(
                [np.linalg.lstsq(j, tangent, rcond=None)[0] for j in self.evaluate(x)[1::2]]
            )
            ahead = start - here
            # Back at the start in space and in both domains (not across a seam).
            if (
                travelled > 2 * length
                and np.linalg.norm(ahead) <= 1.5 * length
                and ahead @ tangent > 0.5 * np.linalg.norm(ahead)
                and np.all(np.abs(x0 - x) <= 2 * length * np.abs(slope) + 1e-9 * self.span)
            ):
                return out, "closed"
            guess = x + length * slope
            new = self.correct(guess, here + length * tangent, tangent)
            if new is None:
                length /= 2
                if length < 1e-6 * self.tol:
                    return out, "stalled"
                continue
            outside = np.maximum(self.lower - new, new - self.upper)
            if np.any(outside > 0):
                k = int(np.argmax(outside))
                value = self.lower[k] if new[k] < self.lower[k] else self.upper[k]
                end = self.correct(new, here, tangent, bound=(k, value))
                if (
                    end is not None
                    and np.all(end >= self.lower - 1e-12)
                    and np.all(end <= self.upper + 1e-12)
                ):
                    if np.linalg.norm(self.point(end) - here) > 1e-3 * length:
                        out.append(np.clip(end, self.lower, self.upper))
                    return out, "boundary"
                length /= 2  # the boundary crossing is past another one: come closer
                if length < 1e-6 * self.tol:
                    return out, "boundary"
                continue
            turn = sign * self.tangent(new)
            sine = np.linalg.norm(turn)
            # Tangent surfaces here, or n1 x n2 reversed: the step went through a point
            # where the branches cross.
            if sine < _SINGULAR or turn @ tangent < 0:
                singular = self.singular_point(new if sine < _SINGULAR else 0.5 * (x + new))
                if singular is not None or sine < _SINGULAR:
                    out.append(new if singular is None else singular)
                    return out, "singular"
                length /= 2
                continue
            turn = turn / sine
            curvature = np.linalg.norm(turn - tangent) / length
            wanted = self.step_length(curvature)
            falling = (sine_here - sine) / length
            if falling > 0:  # approach a tangency by halves, never across it
                wanted = min(wanted, 0.5 * sine / falling)
            if length > 1.5 * wanted:  # too long for the curvature found: redo it shorter
                length = wanted
                continue
            out.append(new)
            travelled += length
            x, here, tangent, sine_here = new, self.point(new), turn, sine
            length = min(wanted, 2 * length)
        return out, "stalled"


def _edges(surface):
    """`(curve, k, value)`: each boundary curve of a surface, the parameter index it fixes
    (0: `u`, 1: `v`) and the value; edges collapsed to a point (poles) are left out."""
    (u0, u1), (v0, v1) = (tuple(float(x) for x in d) for d in surface.domain)
    w = surface.weights
    out = []
    for k, value, index in ((0, u0, 0), (0, u1, -1), (1, v0, 0), (1, v1, -1)):
        points = surface.control_points[index] if k == 0 else surface.control_points[:, index]
        weights = None if w is None else (w[index] if k == 0 else w[:, index])
        knots, degree = surface.knots[1 - k], surface.degree[1 - k]
        spread = np.ptp(np.asarray(points), axis=0).max()
        if spread > 0:
            out.append((NURBSCurve(points, degree, knots, weights), k, value))
    return out


def _boundary_starts(s1, s2, tol):
    """Parameters `(s1, t1, s2, t2)` where a boundary curve of one surface meets the other."""
    starts = []
    for first, (a, b) in enumerate(((s1, s2), (s2, s1))):
        for edge, k, value in _edges(a):
            along, s, t, _ = _curve_surface_search(edge, b, tol)
            for w, ss, tt in zip(along, s, t, strict=True):
                own = [value, w] if k == 0 else [w, value]
                starts.append(np.array([*own, ss, tt] if first == 0 else [ss, tt, *own]))
    return starts


def _stacked(net):
    """`(h, u, v)` of every Bezier patch of a `_Net`, stacked along a first axis."""
    patches = net.flat_patches()
    return (
        np.stack([q.h for q in patches]),
        np.array([q.u for q in patches]),
        np.array([q.v for q in patches]),
    )


def _shapes(h, rational):
    """`(low, high, size, deviation, along_u)` of a stack of patch nets `h` `(N, n + 1,
    m + 1, dim + 1)` (`deviation`: the largest distance of a control point from the
    bilinear patch of the corners; `along_u`: whether the patch is longer in `u`, the
    direction it is halved in)."""
    points = h[..., :-1] / h[..., -1:] if rational else h
    low, high = points.min(axis=(1, 2)), points.max(axis=(1, 2))
    a = np.linspace(0, 1, h.shape[1])[None, :, None, None]
    b = np.linspace(0, 1, h.shape[2])[None, None, :, None]
    p00, p10 = points[:, :1, :1], points[:, -1:, :1]
    p11, p01 = points[:, -1:, -1:], points[:, :1, -1:]
    bilinear = (1 - a) * (1 - b) * p00 + a * (1 - b) * p10 + a * b * p11 + (1 - a) * b * p01
    deviation = np.linalg.norm(points - bilinear, axis=-1).max(axis=(1, 2))
    along_u = np.linalg.norm(p10 - p00, axis=-1) + np.linalg.norm(p11 - p01, axis=-1)
    along_v = np.linalg.norm(p01 - p00, axis=-1) + np.linalg.norm(p11 - p10, axis=-1)
    size = np.linalg.norm(high - low, axis=1)
    return low, high, size, deviation, (along_u >= along_v)[:, 0, 0]


def _halves(side, along_u):
    """The two halves `(h, u, v)` of each patch of a stack, across its longer direction."""
    h, u, v = side
    left, right = np.empty_like(h), np.empty_like(h)
    (lu, ru), (lv, rv) = (u.copy(), u.copy()), (v.copy(), v.copy())
    for axis, rows, span, (low, high) in ((1, along_u, u, (lu, ru)), (2, ~along_u, v, (lv, rv))):
        # `halve` works along its first axis; the stack rides along behind it.
        halves = halve(np.moveaxis(h[rows], axis, 0))
        left[rows], right[rows] = (np.moveaxis(x, 0, axis) for x in halves)
        middle = span[rows].mean(axis=1)
        low[rows, 1], high[rows, 0] = middle, middle
    return (left, lu, lv), (right, ru, rv)


def _interior_pairs(pair, tol):
    """`(centres, points, reach)`: for every flat sub-patch pair whose boxes overlap (the
    starts of loops inside both domains), the parameters of the patches' centres, where the
    tangent planes there cross (nearest the centres: a first Gauss-Newton step), and the sum
    of the pair's sizes.

    One level of the subdivision at a time, every pair at once."""
    sides = [_stacked(net) for net in pair.nets]
    rational = [net.patches[0][0].rational for net in pair.nets]
    first, second = np.indices((len(sides[0][0]), len(sides[1][0]))).reshape(2, -1)
    a, b = (tuple(x[k] for x in side) for side, k in zip(sides, (first, second), strict=True))
    centres, points, reach = [], [], []
    for depth in range(25):
        (la, ha, za, da, ua), (lb, hb, zb, db, ub) = (
            _shapes(a[0], rational[0]),
            _shapes(b[0], rational[1]),
        )
        meet = ~(np.any(la > hb + tol, axis=1) | np.any(lb > ha + tol, axis=1))
        flat = (da <= _START_FLAT * np.maximum(za, tol)) & (db <= _START_FLAT * np.maximum(zb, tol))
        if depth == 24:
            flat[:] = True
        done = meet & flat
        centres.append(np.column_stack([x[done].mean(axis=1) for x in (*a[1:], *b[1:])]))
        points.append(
            _tangent_planes_crossing([x[done] for x in a], [x[done] for x in b], rational)
        )
        reach.append((za + zb)[done])
        more = meet & ~flat
        split_a = more & (za >= zb)
        split_b = more & (za < zb)
        halves_a = _halves(tuple(x[split_a] for x in a), ua[split_a])
        halves_b = _halves(tuple(x[split_b] for x in b), ub[split_b])
        a = tuple(
            np.concatenate([*(half[k] for half in halves_a), x[split_b], x[split_b]])
            for k, x in enumerate(a)
        )
        b = tuple(
            np.concatenate([x[split_a], x[split_a], *(half[k] for half in halves_b)])
            for k, x in enumerate(b)
        )
        if not len(a[0]):
            break
    return np.concatenate(centres), np.concatenate(points), np.concatenate(reach)


def _tangent_planes_crossing(a, b, rational):
    """The point nearest the centres of the patch stacks `a` and `b` (each `(h, u, v)`) where
    their tangent planes there cross: the first step of `_Pair.onto`, for every pair at once."""
    frames = []
    for (h, u, v), curved in zip((a, b), rational, strict=True):
        x, x_s, x_t = _patch_point(np.moveaxis(h, 0, 2), 0.5, 0.5, curved)
        jacobian = np.stack([x_s / np.diff(u), x_t / np.diff(v)], axis=-1)  # (N, 3, 2)
        frames.append((x, jacobian))
    (x1, j1), (x2, j2) = frames
    step = np.linalg.pinv(np.concatenate([j1, -j2], axis=-1)) @ (x2 - x1)[..., None]
    return x1 + (j1 @ step[:, :2])[..., 0]


def _polyline_gaps(points, polyline):
    """`(distances, segment lengths)`: from each of `points` `(M, 3)` to the nearest segment
    of a polyline, and that segment's length (in blocks: `M x segments` pairs)."""
    a, b = polyline[:-1], polyline[1:]
    d = b - a
    length2 = np.maximum(np.sum(d * d, axis=1), 1e-300)
    gaps, lengths = np.empty(len(points)), np.empty(len(points))
    block = max(1, 2**20 // len(a))
    for k in range(0, len(points), block):
        x = points[k : k + block, None]
        along = np.clip(np.sum((x - a) * d, axis=-1) / length2, 0, 1)
        distances = np.linalg.norm(a + along[..., None] * d - x, axis=-1)
        nearest = np.argmin(distances, axis=1)
        gaps[k : k + block] = distances[np.arange(len(x)), nearest]
        lengths[k : k + block] = np.sqrt(length2[nearest])
    return gaps, lengths


def _on_branch(x0, point, traced, tol, span):
    """Whether a start lies on a traced branch: near its polyline in space (within twice
    the largest sag of a chord whose arc turns by `_MAX_TURN`, `tan(turn / 4) / 2 ~ turn / 8`
    of its length, or `10 tol`) and in the parameters (a point on a seam of a closed surface
    has two, a domain apart)."""
    for line, params in traced:
        (gap,), (length,) = _polyline_gaps(point[None], line)
        if gap <= max(_MAX_TURN / 4 * length, 10 * tol):
            (gap,), (length,) = _polyline_gaps(x0[None], params)
            if gap <= max(_MAX_TURN / 4 * length, 1e-9 * span):
                return True
    return False


def _trace(pair, x0):
    """`(parameters, closed, ends_singular)` of the branch through `x0`."""
    forward, how = pair.march(x0, 1.0)
    if how == "closed":
        return np.array([x0, *forward, x0]), True, (False, False)
    backward, back_how = pair.march(x0, -1.0)
    params = np.array([*backward[::-1], x0, *forward])
    return params, False, (back_how == "singular", how == "singular")


def _midpoint(pair, params, space, k):
    """The point of the branch between points `k` and `k + 1` (Newton in the plane
    through the chord's middle, perpendicular to it); None if Newton fails."""
    chord = space[k + 1] - space[k]
    middle = 0.5 * (params[k] + params[k + 1])
    return pair.correct(middle, 0.5 * (space[k] + space[k + 1]), chord / np.linalg.norm(chord))


def _insert(pair, params, space, intervals):
    """The branch with a point added inside each of the `intervals` (where Newton works)."""
    added = [(k + 1, x) for k in intervals if (x := _midpoint(pair, params, space, k)) is not None]
    for k, x in added[::-1]:
        params = np.insert(params, k, x, axis=0)
        space = np.insert(space, k, pair.point(x), axis=0)
    return params, space, bool(added)


def _fit(pair, params, periodic):
    """Cubic interpolants of the space points and both parameter paths on one chord-length
    parametrization, with points added until every midpoint is within `tol` of both
    surfaces; returns the points' parameters `(n, 4)` and their chord-length sites `w`
    (`_branch_curves` builds the curves from them, differentiably).

    The count of points is raised to a multiple of `_BUCKET` (points added in the longest
    chords, which only makes the fit closer): `interpolate` compiles once per count, and
    branches then share a few counts."""
    space = np.array([pair.point(x) for x in params])
    for _ in range(_REFINEMENTS):
        wanted = -(-(len(params) - periodic) // _BUCKET) * _BUCKET + periodic
        while len(params) < wanted:
            chords = np.linalg.norm(np.diff(space, axis=0), axis=1)
            longest = np.argsort(chords)[::-1][: wanted - len(params)]
            params, space, grew = _insert(pair, params, space, sorted(longest))
            if not grew:
                break
        steps = np.linalg.norm(np.diff(space, axis=0), axis=1)
        w = np.concatenate([[0.0], np.cumsum(steps)]) / steps.sum()
        data = np.concatenate([space, params], axis=1)
        degree = min(3, len(data) - 1 - periodic)
        if periodic:
            joint = interpolate(data[:-1], degree, w, closed=True)
            trial = BSpline(np.asarray(joint.knots), np.asarray(joint.control_points), degree)
        else:
            # The open interpolant `interpolate` builds (knots by averaging, NURBS Book eq.
            # 9.8, as `averaged_knots`), in NumPy and scipy: nothing compiles per count.
            windows = [w[i : len(w) - degree + 1 + i] for i in range(degree)]
            interior = np.mean(windows, axis=0)[1:-1]
            knots = np.concatenate(
                [np.full(degree + 1, w[0]), interior, np.full(degree + 1, w[-1])]
            )
            trial = make_interp_spline(w, data, degree, knots)
        fitted = params, w
        # Checked at a quarter, the middle and three quarters of each interval: where the
        # parameter path crosses a knot of a surface (a jump in its second derivative)
        # the largest error need not sit in the middle.
        fractions = np.array([0.25, 0.5, 0.75])
        checked = w[:-1, None] + fractions * np.diff(w)[:, None]
        # scipy evaluates the trial fits: their point counts change every round, and the
        # library's jitted evaluation would compile once per count (the result is a NURBSCurve).
        values = trial(checked.ravel())
        on = np.clip(values[:, 3:], pair.lower, pair.upper)
        errors = [
            max(
                np.linalg.norm(pair.nets[0](*x[:2])[0] - c),
                np.linalg.norm(pair.nets[1](*x[2:])[0] - c),
            )
            for x, c in zip(on, values[:, :3], strict=True)
        ]
        bad = np.flatnonzero(np.array(errors).reshape(-1, 3).max(axis=1) > pair.tol)
        if bad.size == 0:
            break
        params, space, grew = _insert(pair, params, space, bad)
        if not grew:
            break
    return fitted  # the last points interpolated (and checked, unless the rounds ran out)


@eqx.filter_jit
def _polish_branch(s1, s2, params, ahead, behind):
    """One Newton step in JAX from the traced parameters `params` `(n, 4)` (held fixed):
    `x - J^-1 F(x)`, `F = [S1 - S2; (S1 - p) . T]` with the point `p` and the unit tangent
    `T` held fixed (the plane of `_Pair.correct`), or `F_4 = x_k - bound` at a point on a
    domain boundary (where a march ended: the point slides along that boundary). Values
    move by rounding; the derivative is the implicit-function one, reaching control points,
    weights and knots of both surfaces. Where the surfaces are tangent (a singular end) the
    system is singular: those points get no step (their parameters carry no gradient).

    `ahead`, `behind`: the indices of each point's neighbours along its branch (itself at
    an end): the points of several branches are polished in one call (one compiled
    program for all of them, `_polish_branches`).

    Returns `(points (n, 3), params (n, 4))`, the points `S1` at the new parameters (to
    first order, which is exact in value and in derivative)."""
    dtype = jnp.result_type(s1.control_points.dtype, s2.control_points.dtype, float)
    x = jax.lax.stop_gradient(jnp.asarray(params, dtype))
    d1 = s1.derivatives(x[:, 0], x[:, 1], 1)
    d2 = s2.derivatives(x[:, 2], x[:, 3], 1)
    p1, p2 = d1[:, 0, 0], d2[:, 0, 0]
    j1 = jnp.stack([d1[:, 1, 0], d1[:, 0, 1]], axis=-1)  # (n, 3, 2)
    j2 = jnp.stack([d2[:, 1, 0], d2[:, 0, 1]], axis=-1)
    # The plane, fixed: through the point, across the tangent n1 x n2 (the chord of the
    # neighbours where the surfaces are tangent).
    fixed = jax.lax.stop_gradient(p1)
    n1 = jnp.cross(j1[..., 0], j1[..., 1])
    n2 = jnp.cross(j2[..., 0], j2[..., 1])
    along = jax.lax.stop_gradient(jnp.cross(n1, n2))
    sine = jnp.linalg.norm(along, axis=-1) / jax.lax.stop_gradient(
        jnp.maximum(jnp.linalg.norm(n1, axis=-1) * jnp.linalg.norm(n2, axis=-1), 1e-300)
    )
    singular = sine < _SINGULAR
    chord = jnp.where((ahead == behind)[:, None], 1.0, fixed[ahead] - fixed[behind])
    along = jnp.where(singular[:, None], chord, along)
    tangent = along / jnp.maximum(jnp.linalg.norm(along, axis=-1, keepdims=True), 1e-300)
    # Boundary points: the parameter nearest a domain end, if within rounding of it.
    (a0, a1), (b0, b1) = s1.domain
    (c0, c1), (e0, e1) = s2.domain
    lower = jnp.stack([a0, b0, c0, e0]).astype(dtype)
    upper = jnp.stack([a1, b1, c1, e1]).astype(dtype)
    gaps = jax.lax.stop_gradient(jnp.minimum(jnp.abs(x - lower), jnp.abs(x - upper)))
    k = jnp.argmin(gaps, axis=-1)
    span = jax.lax.stop_gradient(jnp.max(upper - lower))
    on_edge = jnp.take_along_axis(gaps, k[:, None], axis=-1)[:, 0] <= 1e-12 * (1 + span)
    at_lower = jax.lax.stop_gradient(jnp.abs(x - lower) <= jnp.abs(x - upper))
    bound = jnp.where(at_lower, lower, upper)
    x_k = jnp.take_along_axis(x, k[:, None], axis=-1)[:, 0]
    bound_k = jnp.take_along_axis(jnp.broadcast_to(bound, x.shape), k[:, None], axis=-1)[:, 0]
    onehot = jax.nn.one_hot(k, 4, dtype=dtype)
    plane = jnp.einsum("nd,ndk->nk", tangent, j1)
    last_row = jnp.where(
        on_edge[:, None], onehot, jnp.concatenate([plane, jnp.zeros_like(plane)], axis=-1)
    )
    last = jnp.where(on_edge, x_k - bound_k, jnp.einsum("nd,nd->n", p1 - fixed, tangent))
    residual = jnp.concatenate([p1 - p2, last[:, None]], axis=-1)
    jacobian = jnp.concatenate([jnp.concatenate([j1, -j2], axis=-1), last_row[:, None]], axis=1)
    # The singular rows are replaced by the identity (and their residual by zero) so that
    # the batched solve stays finite there.
    jacobian = jnp.where(singular[:, None, None], jnp.eye(4, dtype=dtype), jacobian)
    residual = jnp.where(singular[:, None], 0.0, residual)
    step = jnp.linalg.solve(jacobian, residual[..., None])[..., 0]
    points = p1 - jnp.einsum("ndk,nk->nd", j1, step[:, :2])
    return points, x - step


def _polish_branches(s1, s2, branches):
    """`[(points, params), ...]`: `_polish_branch` on the traced parameters of every branch
    in `branches`, in one call, padded to a power of two points (a few compiled programs
    serve every call)."""
    sizes = [len(params) for params in branches]
    total = sum(sizes)
    padded = 1 << max(5, (total - 1).bit_length())
    params = np.concatenate([*map(np.asarray, branches), np.zeros((padded - total, 4))])
    index = np.arange(padded)
    ends = np.cumsum(sizes)
    last = np.isin(index, ends - 1) | (index >= total)
    first = np.isin(index, ends - np.array(sizes)) | (index >= total)
    ahead = np.where(last, index, index + 1)
    behind = np.where(first, index, index - 1)
    points, params = _polish_branch(s1, s2, params, ahead, behind)
    return [
        (points[end - size : end], params[end - size : end])
        for end, size in zip(ends, sizes, strict=True)
    ]


def _branch_curves(s1, s2, polished, w, periodic):
    """`(curve, uv1, uv2)`: the cubic interpolants, on the sites `w`, of the branch points
    `polished` by `_polish_branches`: differentiable functions of both surfaces."""
    data = jnp.concatenate(polished, axis=1)
    degree = min(3, len(data) - 1 - periodic)
    w = jnp.asarray(w, data.dtype)
    if periodic:
        joint = interpolate(data[:-1], degree, w, closed=True)
    else:
        joint = interpolate(data, degree, w)
    knots = joint.knots
    # The domain exactly [0, 1] (a periodic knot vector ends there only to rounding).
    knots = (knots - knots[degree]) / (knots[-degree - 1] - knots[degree])
    control = joint.control_points
    if not periodic:
        # The ends of the parameter curves inside the domains: a branch ending on a domain
        # boundary would otherwise come out 1 ulp beyond it, and `surface(*uv(1.0).T)` raise.
        # (Only the end control points: interior ones may lie outside where the curve
        # hugs the boundary.)
        lower = jnp.concatenate(
            [jnp.full(3, -jnp.inf), *(jnp.asarray(d)[:, 0] for d in (s1.domain, s2.domain))]
        )
        upper = jnp.concatenate(
            [jnp.full(3, jnp.inf), *(jnp.asarray(d)[:, 1] for d in (s1.domain, s2.domain))]
        )
        ends = jnp.clip(control[jnp.array([0, -1])], lower, upper)
        control = control.at[jnp.array([0, -1])].set(ends)
    return tuple(
        NURBSCurve(control[:, cols], degree, knots)
        for cols in (slice(0, 3), slice(3, 5), slice(5, 7))
    )


def _primal(x):
    """`x` without the tracers of `jax.grad` / `jax.jvp` around it (their primal values,
    concrete outside `jit`), so that the search runs on the surfaces' values; other
    tracers are returned as they are (the search then asks for `start=`)."""
    while isinstance(x, jax.core.Tracer) and hasattr(x, "primal"):
        x = x.primal
    return x


def surface_intersections(
    s1, s2, tol: float | None = None, *, start=None
) -> list[IntersectionCurve]:
    """Every branch of the intersection curve of two surfaces in 3D.

    Branches are traced from where a boundary curve of one surface meets the other and
    from flat sub-patch pairs (for loops inside both domains), marching on `n1 x n2` with
    Newton corrections onto both surfaces, and interpolated by cubics until the midpoints
    are within `tol` of both surfaces (see the module docstring).

    Gradients: the search runs in NumPy on the surfaces' values; then every traced point
    takes one Newton step in JAX (on both surfaces, in the fixed plane across the branch,
    or along the domain boundary it ends on) whose derivative is the implicit-function
    one, and the curves interpolate those points. So `jax.grad` of anything computed from
    the returned curves reaches the control points, weights and knots of both surfaces,
    and the call can sit directly inside the differentiated function::

        jax.grad(lambda P: f(dn.surface_intersections(S1(P), S2)[0].curve))(P)

    (under `jax.grad`, `jax.jvp` and the like the search takes the primal values; the
    branch topology is that of those values, and the derivative is that of the branches
    found). Under `jax.jit` the surfaces are not concrete: find the branches first, outside,
    and pass them as `start=`, which skips the search and only takes the Newton step
    (also the cheaper way to differentiate many times)::

        branches = dn.surface_intersections(S1(P0), S2)
        jax.jit(jax.grad(lambda P: f(dn.surface_intersections(S1(P), S2, start=branches)[0].curve)))

    A branch that ends at a singular point gets no step there (the system is singular):
    that end point follows `s1` at fixed parameters.

    Singular points, where the normals are parallel (two equal cylinders crossing, the
    Villarceau circles of a torus crossing on the bitangent plane), are not marched through:
    branches end there, at the point located by Newton, and `ends_singular` says which ends
    do. Surfaces tangent along a whole curve give no reliable result.

    **Arguments:**

    - `s1`, `s2`: `NURBSSurface`s in 3D (concrete, or traced by `jax.grad`; traced by
      `jit` only with `start`).
    - `tol`: largest distance of the fitted curves from both surfaces; None:
      `1e-7 (1 + size)`, the size the diagonal of the box of both control nets.
    - `start`: the list of `IntersectionCurve`s of an earlier call (on these surfaces or
      ones close to them, with the same topology): the search is skipped, their points
      are polished by one Newton step on `s1`, `s2` and interpolated again.

    **Returns:**

    A list of `IntersectionCurve`s; empty when the surfaces do not meet.
    """
    _check_surface(s1, "s1")
    _check_surface(s2, "s2")
    if start is not None:
        found = [(b.params, b.sites, b.periodic, b.closed, b.ends_singular) for b in start]
    else:
        found = _search_branches(*(jax.tree.map(_primal, s) for s in (s1, s2)), tol)
    if not found:
        return []
    polished = _polish_branches(s1, s2, [params for params, *_ in found])
    return [
        IntersectionCurve(
            *_branch_curves(s1, s2, points, w, periodic), closed, ends, params, w, periodic
        )
        for points, (params, w, periodic, closed, ends) in zip(polished, found, strict=True)
    ]


def _search_branches(s1, s2, tol):
    """`(params, w, periodic, closed, ends_singular)` of every branch, in NumPy."""
    if any(concrete(s.control_points) is None for s in (s1, s2)):
        _Net(s1 if concrete(s1.control_points) is None else s2)  # raises, naming `start=`
    size = _model_size(s1, s2)
    tol = 1e-7 * (1 + size) if tol is None else _check_tol(tol)
    pair = _Pair(s1, s2, tol, size)
    search_tol = min(1e-9 * (1 + size), tol)
    branches, traced = [], []

    def trace(x0):
        params, closed, ends = _trace(pair, x0)
        if len(params) < 2:
            return
        line = np.array([pair.point(x) for x in params])
        traced.append((line, params))
        space_closed = closed or np.linalg.norm(line[0] - line[-1]) <= 10 * tol
        params, w = _fit(pair, params, periodic=closed)
        branches.append((params, w, bool(closed), bool(space_closed), ends))

    def fresh(x0):
        """Not a tangential contact (reached from the branches that meet there), not on a
        traced branch."""
        tangent = np.linalg.norm(pair.tangent(x0))
        return tangent >= _SINGULAR and not _on_branch(x0, pair.point(x0), traced, tol, pair.span)

    for x0 in _boundary_starts(s1, s2, search_tol):
        if fresh(x0):
            trace(x0)
    centres, points, reach = _interior_pairs(pair, search_tol)
    # A pair near a traced branch can only find it again: no Newton from there.
    todo = np.ones(len(centres), dtype=bool)
    known = 0
    while True:
        for line, _ in traced[known:]:
            left = np.flatnonzero(todo)
            todo[left] = _polyline_gaps(points[left], line)[0] > reach[left]
        known = len(traced)
        if not todo.any():
            return branches
        k = int(np.argmax(todo))
        todo[k] = False
        x0 = pair.onto(centres[k])
        if x0 is not None and fresh(x0):
            trace(x0)
