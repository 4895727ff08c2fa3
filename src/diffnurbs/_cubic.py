"""Cubic splines in matrix form (seed 002): Hermite, cardinal / Catmull-Rom, uniform B-spline.

A cubic segment in matrix form is `C(t) = [t^3, t^2, t, 1] @ M @ G`, `t` in [0, 1], with a
4 x 4 basis matrix `M` and four geometry rows `G`. `matrix_segment` evaluates that form
directly; the other functions here build the same curves as one `NURBSCurve`, so everything
the library does with curves (derivatives, knot insertion, length, plotting) applies to them:

- a Hermite segment (end points and end derivatives) is a cubic Bezier curve with inner
  control points `p0 + m0 / 3` and `p1 - m1 / 3`;
- a cardinal spline is a chain of Hermite segments, so it is a cubic B-spline with triple
  interior knots (C1 at the joints, which is all it has);
- the uniform cubic B-spline of seed 002 is a cubic B-spline with equally spaced
  (unclamped) knots, C2 everywhere.

Every curve uses the uniform parameter: segment `k` is the piece on `[k, k + 1]`, with
`t = u - k`, so its derivatives in `u` are the matrix form's derivatives in `t`.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._bezier import bezier_matrix
from ._curve import NURBSCurve
from ._validate import check_parameter, check_rank, concrete, float_dtype

# NumPy float64 constants (JAX arrays made at import time would be frozen at the dtype of
# that moment), converted when used. Rows: the coefficients of t^3, t^2, t, 1.
_MATRICES = {
    "bspline": np.array(
        [[-1.0, 3.0, -3.0, 1.0], [3.0, -6.0, 3.0, 0.0], [-3.0, 0.0, 3.0, 0.0], [1.0, 4.0, 1.0, 0.0]]
    )
    / 6.0,
    "catmull-rom": np.array(
        [
            [-1.0, 3.0, -3.0, 1.0],
            [2.0, -5.0, 4.0, -1.0],
            [-1.0, 0.0, 1.0, 0.0],
            [0.0, 2.0, 0.0, 0.0],
        ]
    )
    / 2.0,
    "hermite": np.array(
        [[2.0, -2.0, 1.0, 1.0], [-3.0, 3.0, -2.0, -1.0], [0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0, 0.0]]
    ),
}
_KINDS = ("bezier", "bspline", "catmull-rom", "hermite")


def cubic_matrix(kind: str, dtype=None) -> Float[Array, "4 4"]:
    """The basis matrix `M` of a cubic segment in matrix form, `C(t) = [t^3, t^2, t, 1] M G`
    (seed 002).

    **Arguments:**

    - `kind`: `"bezier"` (`bezier_matrix(3)`; geometry: the four control points),
      `"bspline"` (one segment of the uniform cubic B-spline,
      `(1/6) [[-1,3,-3,1],[3,-6,3,0],[-3,0,3,0],[1,4,1,0]]`), `"catmull-rom"`
      (`(1/2) [[-1,3,-3,1],[2,-5,4,-1],[-1,0,1,0],[0,2,0,0]]`, the segment between the
      middle two points) or `"hermite"` (geometry `(p0, p1, m0, m1)`).
    - `dtype`: floating dtype of the result (default: JAX's default float).

    **Returns:**

    Array of shape `(4, 4)`, rows the coefficients of `t^3, t^2, t, 1`.
    """
    if not isinstance(kind, str) or kind.lower() not in _KINDS:
        raise ValueError(f"kind must be one of {_KINDS}, got {kind!r}")
    dtype = dtype or jnp.result_type(float)
    if kind.lower() == "bezier":
        return bezier_matrix(3, dtype)
    return jnp.asarray(_MATRICES[kind.lower()], dtype=dtype)


def basis_or_matrix(basis, dtype) -> Float[Array, "4 4"]:
    """`cubic_matrix(basis, dtype)` when `basis` is a name, else `basis` as a `(4, 4)` array."""
    if isinstance(basis, str):
        return cubic_matrix(basis, dtype)
    matrix = jnp.asarray(basis, dtype=dtype)
    if matrix.shape != (4, 4):
        raise ValueError(f"a basis matrix must have shape (4, 4), got {matrix.shape}")
    return matrix


def matrix_segment(
    geometry: ArrayLike, basis: str | ArrayLike, t: ArrayLike
) -> Float[Array, "... dim"]:
    """Points `[t^3, t^2, t, 1] @ M @ G` of one cubic segment in matrix form (seed 002).

    **Arguments:**

    - `geometry`: array of shape `(4, dim)`: Bezier control points, four consecutive
      B-spline or Catmull-Rom points, or for `"hermite"` the rows `(p0, p1, m0, m1)`.
    - `basis`: `"bezier"`, `"bspline"`, `"catmull-rom"`, `"hermite"`, or a `(4, 4)` matrix.
    - `t`: parameters in [0, 1], any shape.

    **Returns:**

    Array of shape `t.shape + (dim,)`.
    """
    geometry = jnp.asarray(geometry)
    geometry = geometry.astype(jnp.result_type(geometry.dtype, float))
    check_rank(geometry, 2, "geometry", "(4, dim)")
    if geometry.shape[0] != 4:
        raise ValueError(f"geometry must have shape (4, dim), got {geometry.shape}")
    matrix = basis_or_matrix(basis, geometry.dtype)
    t = jnp.asarray(t, dtype=geometry.dtype)
    check_parameter(t, 0.0, 1.0, "t")
    powers = jnp.stack([t**3, t**2, t, jnp.ones_like(t)], axis=-1)
    return (powers @ matrix) @ geometry


def _as_points(points: ArrayLike, minimum: int, what: str) -> Array:
    points = jnp.asarray(points)
    check_rank(points, 2, "points", "(n_points, dim)")
    if points.shape[0] < minimum:
        raise ValueError(f"{what} needs at least {minimum} points, got {points.shape[0]}")
    return points.astype(float_dtype(points))


def _piecewise_bezier(starts, inner1, inner2, last, dtype) -> NURBSCurve:
    """One C0-knotted cubic B-spline from Bezier segments `(starts[k], inner1[k], inner2[k],
    starts[k + 1] or last)`, segment `k` on `[k, k + 1]`."""
    return _bezier_chain(_bezier_net(starts, inner1, inner2, last), dtype)


def _bezier_net(starts, inner1, inner2, last):
    """The control points of `_piecewise_bezier`, `3 count + 1` rows."""
    points = jnp.stack([starts, inner1, inner2], axis=1).reshape(3 * starts.shape[0], -1)
    return jnp.concatenate([points, last[None]], axis=0)


def _bezier_chain(points, dtype) -> NURBSCurve:
    """The cubic `NURBSCurve` on the control points of `_bezier_net`."""
    count = (points.shape[0] - 1) // 3
    # Triple interior knots: each segment is its own Bezier piece, joined with C0 by the
    # knots and C1 by the construction (shared end tangents).
    knots = np.concatenate([[0.0], np.repeat(np.arange(count + 1.0), 3), [float(count)]])
    return NURBSCurve(points, 3, jnp.asarray(knots, dtype=dtype))


def hermite_segment(p0: ArrayLike, p1: ArrayLike, m0: ArrayLike, m1: ArrayLike) -> NURBSCurve:
    """The cubic Hermite segment from `p0` to `p1` with derivatives `m0`, `m1` at the ends.

    The curve is `[t^3, t^2, t, 1] @ cubic_matrix("hermite") @ (p0, p1, m0, m1)` on [0, 1], built as
    the equivalent cubic Bezier curve `(p0, p0 + m0 / 3, p1 - m1 / 3, p1)` (a Bezier
    curve's end derivative is `3 (P1 - P0)`).

    **Arguments:**

    - `p0`, `p1`: end points, shape `(dim,)`.
    - `m0`, `m1`: derivatives `C'(0)`, `C'(1)`, shape `(dim,)`.

    **Returns:**

    A cubic `NURBSCurve` with 4 control points on the domain [0, 1].
    """
    rows = [jnp.asarray(x) for x in (p0, p1, m0, m1)]
    for name, row in zip(("p0", "p1", "m0", "m1"), rows, strict=True):
        check_rank(row, 1, name, "(dim,)")
        if row.shape != rows[0].shape:
            raise ValueError(f"{name} must have the shape of p0, {rows[0].shape}, got {row.shape}")
    p0, p1, m0, m1 = (row.astype(float_dtype(*rows)) for row in rows)
    return NURBSCurve(jnp.stack([p0, p0 + m0 / 3, p1 - m1 / 3, p1]), 3)


def cardinal_spline(
    points: ArrayLike, tension: ArrayLike = 0.0, closed: bool = False
) -> NURBSCurve:
    """The cardinal spline through `points`: Hermite segments with tangents from neighbours.

    The tangent at point `i` is `m_i = (1 - tension) / 2 (P_{i+1} - P_{i-1})`; tension 0
    is the Catmull-Rom spline, tension 1 gives zero tangents (a polyline traced with zero
    speed at each point). An open spline has no neighbour beyond its ends, so there the
    tangent is the one-sided difference with the same factor,
    `m_0 = (1 - tension) (P_1 - P_0)` and `m_{n-1} = (1 - tension) (P_{n-1} - P_{n-2})`:
    the central difference of the uniform parameter with the missing point reflected
    (`P_{-1} = 2 P_0 - P_1`), so no extra point is invented and a straight line of
    equally spaced points stays a line at uniform speed. A closed spline wraps around.

    **Arguments:**

    - `points`: array of shape `(n, dim)`; `n >= 2` (open) or `n >= 3` (closed).
    - `tension`: a finite scalar (may be traced).
    - `closed`: join the last point back to the first with one more segment.

    **Returns:**

    One cubic `NURBSCurve` through every point: `n - 1` segments (`n` closed), segment `k`
    on `[k, k + 1]` from `P_k` to `P_{k+1}`, knots of multiplicity 3 at the joints.
    `C(k) = P_k` and `C'(k) = m_k`.
    """
    points = _as_points(
        points, 3 if closed else 2, "a closed cardinal spline" if closed else "a cardinal spline"
    )
    tension = jnp.asarray(tension, dtype=points.dtype)
    if tension.ndim != 0:
        raise ValueError(f"tension must be a scalar, got shape {tension.shape}")
    value = concrete(tension)
    if value is not None and not np.isfinite(value):
        raise ValueError(f"tension must be finite, got {value}")
    return _bezier_chain(_cardinal_net(points, tension, closed), points.dtype)


@functools.partial(jax.jit, static_argnums=2)
def _cardinal_net(points, tension, closed):
    """The control points of `cardinal_spline`, as one compiled program."""
    scale = (1 - tension) / 2
    if closed:
        tangents = scale * (jnp.roll(points, -1, axis=0) - jnp.roll(points, 1, axis=0))
        ends, end_tangents = jnp.roll(points, -1, axis=0), jnp.roll(tangents, -1, axis=0)
        starts, start_tangents, last = points, tangents, points[0]
    else:
        tangents = jnp.concatenate(
            [
                2 * scale * (points[1:2] - points[:1]),
                scale * (points[2:] - points[:-2]),
                2 * scale * (points[-1:] - points[-2:-1]),
            ]
        )
        starts, start_tangents = points[:-1], tangents[:-1]
        ends, end_tangents, last = points[1:], tangents[1:], points[-1]
    return _bezier_net(starts, starts + start_tangents / 3, ends - end_tangents / 3, last)


def catmull_rom(points: ArrayLike, closed: bool = False) -> NURBSCurve:
    """The Catmull-Rom spline through `points`: `cardinal_spline` with tension 0.

    Each interior segment equals `matrix_segment(P[k-1 : k+3], "catmull-rom", t)`.
    """
    return cardinal_spline(points, 0.0, closed)


def uniform_cubic_bspline(points: ArrayLike, closed: bool = False) -> NURBSCurve:
    """The uniform cubic B-spline with control points `points` (seed 002's matrix form).

    Segment `k` is `[t^3, t^2, t, 1] @ cubic_matrix("bspline") @ P[k : k + 4]`, `t = u - k`. The
    curve is C2 and interpolates none of its points in general. A closed curve wraps the
    points (`P[n + j] = P[j]`), giving `n` segments and a C2 loop.

    **Arguments:**

    - `points`: array of shape `(n, dim)`; `n >= 4` (open) or `n >= 3` (closed).
    - `closed`: wrap the points around.

    **Returns:**

    A cubic `NURBSCurve` with equally spaced (unclamped) knots `-3, -2, ...`, on the domain
    `[0, n - 3]` (open) or `[0, n]` (closed).
    """
    points = _as_points(
        points,
        3 if closed else 4,
        "a closed uniform cubic B-spline" if closed else "a uniform cubic B-spline",
    )
    if closed:
        points = jnp.concatenate([points, points[:3]], axis=0)
    knots = np.arange(points.shape[0] + 4.0) - 3
    return NURBSCurve(points, 3, jnp.asarray(knots, dtype=points.dtype))
