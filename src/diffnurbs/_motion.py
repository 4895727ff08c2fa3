"""Surfaces of motion that are exact NURBS: extrusion and revolution (seed 000 §2.1-2.2).

In every result `u` runs along the profile curve and `v` along the motion.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from ._curve import NURBSCurve
from ._misc import safe_norm
from ._shapes import arc_net
from ._surface import NURBSSurface
from ._validate import concrete


def _unit_vector(vector, name, dim):
    vector = jnp.asarray(vector, dtype=jnp.result_type(float))
    if vector.shape != (dim,):
        raise ValueError(
            f"{name} must be a vector of length {dim} (the curve's dimension), "
            f"got shape {vector.shape}"
        )
    length, unit = _normalized(vector)
    length = concrete(length)
    if length is not None and not length > 0:
        raise ValueError(f"{name} must be non-zero, got {np.asarray(vector).tolist()}")
    return unit


@jax.jit
def _normalized(vector):
    """`(|v|, v / |v|)` as one compiled program."""
    length = safe_norm(vector)
    return length, vector / length


def _profile_weights(curve):
    if curve.weights is None:
        return jnp.ones(curve.control_points.shape[0], curve.control_points.dtype)
    return curve.weights


def extrude(curve: NURBSCurve, direction: ArrayLike, length: ArrayLike) -> NURBSSurface:
    """The extrusion `S(u, v) = C(u) + v * length * d / |d|`, `v` in [0, 1] (seed eq. 2.1).

    Exact: degree `(p, 1)`, the profile's knots and weights in `u`, two rows along `v`.

    **Arguments:**

    - `curve`: the profile `C(u)`.
    - `direction`: non-zero vector `d` of the curve's dimension.
    - `length`: the distance travelled.

    **Returns:**

    A `NURBSSurface` with `control_points.shape == (n_control, 2, dim)`.
    """
    step = jnp.asarray(length) * _unit_vector(direction, "direction", curve.dim)
    points = jnp.stack([curve.control_points, curve.control_points + step], axis=1)
    weights = None if curve.weights is None else jnp.stack([curve.weights] * 2, axis=1)
    knots_v = jnp.asarray([0.0, 0.0, 1.0, 1.0], curve.knots.dtype)
    return NURBSSurface(points, (curve.degree, 1), (curve.knots, knots_v), weights)


def revolve(
    curve: NURBSCurve,
    axis_point: ArrayLike,
    axis_direction: ArrayLike,
    angle: ArrayLike = 2 * math.pi,
) -> NURBSSurface:
    """The surface swept by a 3D profile turning about an axis, exactly (NURBS Book A8.1).

    Every control point `P_i` of the profile travels on the circle about the axis through
    it; the circle is the exact rational quadratic arc (one Bezier segment per started
    quarter turn), and the weights multiply: `w_ij = w_i * w_j(arc)`. The rotation is
    right-handed about `axis_direction`.

    **Arguments:**

    - `curve`: the profile, a curve in 3D.
    - `axis_point`: a point on the axis.
    - `axis_direction`: non-zero direction of the axis.
    - `angle`: the angle turned, `0 < |angle| <= 2 pi` (radians).

    **Returns:**

    A rational `NURBSSurface` of degree `(p, 2)`.
    """
    if curve.dim != 3:
        raise ValueError(f"revolve needs a profile in 3D, got dim = {curve.dim}")
    axis = _unit_vector(axis_direction, "axis_direction", 3)
    origin = jnp.asarray(axis_point, dtype=axis.dtype)
    if origin.shape != (3,):
        raise ValueError(f"axis_point must be a point in 3D, got shape {origin.shape}")
    planar, arc_weights, knots_v = arc_net(0.0, angle)
    points, weights = _revolved_net(curve, origin, axis, planar, arc_weights)
    knots = (curve.knots, knots_v.astype(curve.knots.dtype))
    return NURBSSurface(points, (curve.degree, 2), knots, weights)


@jax.jit
def _revolved_net(curve, origin, axis, planar, arc_weights):
    """The control points and weights of `revolve`, as one compiled program."""
    offset = curve.control_points - origin
    foot = origin + (offset @ axis)[:, None] * axis  # projection of each point on the axis
    radial = curve.control_points - foot  # zero for points on the axis: they stay put
    across = jnp.cross(axis, radial)  # radial turned a quarter turn about the axis
    points = (
        foot[:, None, :]
        + planar[None, :, 0, None] * radial[:, None, :]
        + planar[None, :, 1, None] * across[:, None, :]
    )
    return points, _profile_weights(curve)[:, None] * arc_weights[None, :]


def sweep(profile: NURBSCurve, path: NURBSCurve) -> NURBSSurface:
    """The translational sweep `S(u, v) = C(u) + g(v) - g(v_min)` (seed eq. 2.4), exactly.

    The profile keeps its orientation while its start of path moves along `g`. With
    `P_ij = C_i + G_j - g(v_min)` and `w_ij = w_i w_j`, the rational tensor product
    reproduces the sum because each basis is a partition of unity (NURBS Book §8.4).

    **Arguments:**

    - `profile`: the curve `C(u)`.
    - `path`: the curve `g(v)`, of the same dimension.

    **Returns:**

    A `NURBSSurface` of degree `(p, q)` on the two curves' domains.
    """
    if profile.dim != path.dim:
        raise ValueError(
            f"profile and path must have the same dimension, got {profile.dim} and {path.dim}"
        )
    start = path(path.domain[0])
    points = profile.control_points[:, None, :] + (path.control_points - start)[None, :, :]
    weights = None
    if profile.rational or path.rational:
        weights = _profile_weights(profile)[:, None] * _profile_weights(path)[None, :]
    degree = (profile.degree, path.degree)
    return NURBSSurface(points, degree, (profile.knots, path.knots), weights)
