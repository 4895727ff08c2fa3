"""Exact conics as rational quadratic NURBS: circles, circular arcs, ellipses."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from ._curve import NURBSCurve
from ._validate import check_degree, concrete


def _arc_segments(sweep, segments):
    """Bezier segments for a sweep: one per started quarter turn (4 when the sweep is traced)."""
    if segments is not None:
        return check_degree(segments, minimum=1, name="segments")
    value = concrete(sweep)
    if value is None:
        return 4
    if not 0 < abs(value) <= 2 * math.pi * (1 + 1e-12):
        raise ValueError(f"the sweep angle must be non-zero and at most 2 pi, got {value}")
    return max(1, math.ceil(abs(value) / (math.pi / 2) - 1e-9))


def arc(
    radius: ArrayLike,
    start_angle: ArrayLike,
    end_angle: ArrayLike,
    center: ArrayLike = (0.0, 0.0),
    segments: int | None = None,
) -> NURBSCurve:
    """The circular arc from `start_angle` to `end_angle` (radians, counterclockwise when
    the end is larger), exactly, as a rational quadratic B-spline (NURBS Book A7.1).

    Each Bezier segment spans at most a quarter turn: its middle control point is where
    the end tangents meet, at distance `r / cos(h)` with weight `cos(h)`, `h` half the
    segment's angle. Radius, angles and center may be traced (then 4 segments are used).

    **Arguments:**

    - `radius`: positive radius.
    - `start_angle`, `end_angle`: angles in radians; `0 < |end - start| <= 2 pi`.
    - `center`: the center; its length is the dimension (>= 2). In 3D the arc lies in the
      plane of the first two axes through the center.
    - `segments`: number of Bezier segments (default: one per started quarter turn).

    **Returns:**

    A `NURBSCurve` of degree 2 on the domain [0, 1].
    """
    center = jnp.asarray(center, dtype=jnp.result_type(float))
    if center.ndim != 1 or center.shape[0] < 2:
        raise ValueError(f"center must be a point of dimension >= 2, got shape {center.shape}")
    radius_value = concrete(radius)
    if radius_value is not None and not (np.isfinite(radius_value) and radius_value > 0):
        raise ValueError(f"radius must be finite and positive, got {radius_value}")
    sweep = jnp.asarray(end_angle, center.dtype) - jnp.asarray(start_angle, center.dtype)
    count = _arc_segments(sweep, segments)
    points, weights = _arc_points(radius, start_angle, sweep, center, count)
    return NURBSCurve(points, 2, _arc_knots(count, center.dtype), weights)


@functools.partial(jax.jit, static_argnums=4)
def _arc_points(radius, start_angle, sweep, center, count):
    """The control points and weights of `arc` as one compiled program per segment count."""
    planar, weights = _arc_net(start_angle, sweep, count)
    return center + jnp.pad(radius * planar, ((0, 0), (0, center.shape[0] - 2))), weights


def arc_net(start_angle, sweep, segments=None):
    """Control points (on the unit circle's scale), weights and knots of an arc.

    **Arguments:**

    - `start_angle`, `sweep`: the arc in radians (either may be traced).
    - `segments`: Bezier segments; default one per started quarter turn (4 if traced).

    **Returns:**

    `(points, weights, knots)`: `(2 s + 1, 2)` points of the arc of radius 1 about the
    origin, their `2 s + 1` weights, and the `2 s + 4` knots on [0, 1].
    """
    count = _arc_segments(sweep, segments)
    return *_jit_arc_net(start_angle, sweep, count), _arc_knots(count)


def _arc_net(start_angle, sweep, count):
    half = jnp.asarray(sweep) / (2 * count)
    odd = np.arange(2 * count + 1) % 2 == 1
    angles = start_angle + half * np.arange(2 * count + 1)
    # The middle point of a segment is where its end tangents meet: at 1 / cos(half).
    distance = jnp.where(odd, 1.0 / jnp.cos(half), 1.0)
    points = distance[:, None] * jnp.stack([jnp.cos(angles), jnp.sin(angles)], axis=-1)
    return points, jnp.where(odd, jnp.cos(half), 1.0)


_jit_arc_net = jax.jit(_arc_net, static_argnums=2)


def _arc_knots(count, dtype=None):
    """The `2 count + 4` knots of an arc of `count` segments, built in NumPy: a count is a
    Python int, and eager `jnp` operations would compile a program for each."""
    interior = np.repeat(np.arange(1, count) / count, 2)
    knots = np.concatenate([[0.0] * 3, interior, [1.0] * 3])
    return jax.device_put(knots.astype(jax.dtypes.canonicalize_dtype(dtype or float)))


def circle(radius: ArrayLike, center: ArrayLike = (0.0, 0.0)) -> NURBSCurve:
    """The full circle, counterclockwise from angle 0: four quarter arcs (9 control points).

    **Arguments:**

    - `radius`: positive radius.
    - `center`: the center; its length is the dimension (a 3D circle lies in the plane of
      the first two axes).

    **Returns:**

    A closed `NURBSCurve` of degree 2 on [0, 1].
    """
    return arc(radius, 0.0, 2 * math.pi, center, segments=4)


def ellipse(
    semi_axis_a: ArrayLike, semi_axis_b: ArrayLike, center: ArrayLike = (0.0, 0.0)
) -> NURBSCurve:
    """The ellipse `(x / a)^2 + (y / b)^2 = 1` about `center`: the unit circle scaled.

    NURBS are affine invariant, so scaling the control points of the exact circle gives
    the exact ellipse with the same weights.

    **Arguments:**

    - `semi_axis_a`, `semi_axis_b`: positive semi-axes along the first and second axis.
    - `center`: the center (dimension >= 2).

    **Returns:**

    A closed `NURBSCurve` of degree 2 on [0, 1].
    """
    unit = circle(1.0, jnp.zeros(len(center)))
    for name, value in (("semi_axis_a", semi_axis_a), ("semi_axis_b", semi_axis_b)):
        value = concrete(value)
        if value is not None and not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be finite and positive, got {value}")
    scale = jnp.ones(len(center)).at[0].set(semi_axis_a).at[1].set(semi_axis_b)
    points = unit.control_points * scale + jnp.asarray(center)
    return NURBSCurve(points, 2, unit.knots, unit.weights)
