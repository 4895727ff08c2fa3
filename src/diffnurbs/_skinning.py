"""Skinning (lofting) a surface through section curves, and Gordon surfaces through a network
of curves (NURBS Book §10.3; Gordon's Boolean sum).

Sections are first made compatible: mapped onto [0, 1], raised to one degree, refined to one
knot vector (all exact). The loft then interpolates, for every control point index, the
sections' (homogeneous) control points across the sections, at parameters averaged over the
columns (NURBS Book eq. 9.8 style), so section `k` is the surface's curve `v = v_k`.

A Gordon surface through curves `C_k(u)` (at `v = v_k`) and `D_l(v)` (at `u = u_l`) is
`L_u + L_v - T`: the loft of the `C_k` in `v`, the loft of the `D_l` in `u`, minus the
tensor-product interpolant `T` of their intersection points, with the same degrees and knots
in each direction as the lofts, so that the two lofts' errors cancel along every curve of
the network.
"""

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from ._banded import collocation_solve
from ._curve import NURBSCurve
from ._knotops import merged_knots, missing_knots
from ._knots import averaged_knots, check_distinct_parameters
from ._rational import from_homogeneous
from ._surface import NURBSSurface
from ._validate import check_degree, concrete


def on_unit_domain(curve: NURBSCurve) -> NURBSCurve:
    """The same curve with its knots mapped linearly onto the domain [0, 1]."""
    lower, upper = curve.domain
    knots = (curve.knots - lower) / (upper - lower)
    return NURBSCurve(curve.control_points, curve.degree, knots, curve.weights)


def compatible(*curves: NURBSCurve) -> tuple[NURBSCurve, ...]:
    """The curves on [0, 1] with one degree and one knot vector (exact: elevation and
    insertion), so their control points correspond one to one; all rational (weights 1
    added) if any is."""
    curves = tuple(on_unit_domain(c) for c in curves)
    if any(c.rational for c in curves):
        curves = tuple(
            c
            if c.rational
            else NURBSCurve(
                c.control_points,
                c.degree,
                c.knots,
                jnp.ones(len(c.control_points), c.control_points.dtype),
            )
            for c in curves
        )
    degree = max(c.degree for c in curves)
    curves = tuple(c if c.degree == degree else c.elevate_degree(degree - c.degree) for c in curves)
    target = merged_knots(*(np.asarray(c.knots) for c in curves))
    return tuple(c.refine(missing_knots(np.asarray(c.knots), target)) for c in curves)


def _check_curves(curves, name: str) -> list[NURBSCurve]:
    curves = list(curves)
    if len(curves) < 2 or not all(isinstance(c, NURBSCurve) for c in curves):
        raise ValueError(f"{name} must be a sequence of at least 2 NURBSCurve, got {curves!r:.80}")
    dims = {c.dim for c in curves}
    if len(dims) != 1:
        raise ValueError(f"{name} must all have one dimension, got dimensions {sorted(dims)}")
    return curves


def _section_parameters(net: np.ndarray) -> np.ndarray:
    """Centripetal parameters of the sections, averaged over the control point columns."""
    steps = np.sqrt(np.linalg.norm(np.diff(net, axis=0), axis=-1))  # (K - 1, n)
    totals = steps.sum(axis=0)
    used = totals > 0
    if not used.any():
        raise ValueError("the sections all coincide: nothing to loft between")
    params = np.cumsum(steps[:, used] / totals[used], axis=0).mean(axis=1)
    return np.concatenate([[0.0], params[:-1], [1.0]])


def loft(
    curves, degree_v: int = 3, parameters: ArrayLike | None = None, *, full_output: bool = False
):
    """The surface skinned through section curves: section `k` is its curve `v = v_k`.

    **Arguments:**

    - `curves`: two or more `NURBSCurve`s of one dimension (any degrees and knots; made
      compatible first). Rational sections are interpolated in homogeneous coordinates.
    - `degree_v`: the degree across the sections (lowered to `len(curves) - 1` if larger).
    - `parameters`: the increasing `v_k` of the sections in [0, 1]; None: centripetal
      parameters averaged over the control points.
    - `full_output`: also return the parameters.

    **Returns:**

    The `NURBSSurface` (u along the sections, v across them), or `(surface, parameters)`.
    """
    curves = compatible(*_check_curves(curves, "curves"))
    degree_v = min(check_degree(degree_v, name="degree_v"), len(curves) - 1)
    net = jnp.stack([c.homogeneous_points() for c in curves])  # (K, n, dim [+1])
    if parameters is None:
        values = concrete(jnp.stack([c.control_points for c in curves]))
        if values is None:
            raise ValueError("loft needs concrete sections, or the parameters given")
        parameters = _section_parameters(values)
    v = jnp.asarray(parameters, dtype=net.dtype)
    if v.shape != (len(curves),):
        raise ValueError(f"parameters must have shape ({len(curves)},), got {v.shape}")
    check_distinct_parameters(v, "sections")
    knots_v = averaged_knots(v, degree_v)
    flat = net.reshape(len(curves), -1)
    columns = collocation_solve(v, np.zeros(len(curves), int), knots_v, degree_v, flat)
    points = jnp.swapaxes(columns.reshape(net.shape), 0, 1)  # (n, K, dim [+1])
    knots = (curves[0].knots, knots_v)
    degree = (curves[0].degree, degree_v)
    if curves[0].rational:
        weights = points[..., -1]
        low = concrete(jnp.min(weights))
        if low is not None and low <= 0:
            raise ValueError(
                f"the loft's weights reach {low:.3g} between the sections: the rational "
                "sections' weights vary too much for a positive interpolant; expected sections "
                "with similar weights (or degree_v = 1)"
            )
        surface = NURBSSurface(from_homogeneous(points), degree, knots, weights)
    else:
        surface = NURBSSurface(points, degree, knots)
    return (surface, v) if full_output else surface


def _meeting(c: NURBSCurve, d: NURBSCurve, samples: int = 64) -> tuple[float, float, float]:
    """`(u, v, distance)` of the nearest points of two curves: the closest pair of dense
    samples, then Gauss-Newton on `C(u) - D(v)`."""
    s = np.linspace(0.0, 1.0, samples * (len(c.knots) + len(d.knots)))
    a, b = np.asarray(c(s)), np.asarray(d(s))
    gaps = np.linalg.norm(a[:, None] - b[None], axis=-1)
    i, j = np.unravel_index(np.argmin(gaps), gaps.shape)
    u, v = s[i], s[j]
    for _ in range(30):
        cu, dv = np.asarray(c.derivatives(u, 1)), np.asarray(d.derivatives(v, 1))
        jacobian = np.stack([cu[1], -dv[1]], axis=1)
        step = np.linalg.lstsq(jacobian, -(cu[0] - dv[0]), rcond=None)[0]
        u, v = float(np.clip(u + step[0], 0.0, 1.0)), float(np.clip(v + step[1], 0.0, 1.0))
        if np.max(np.abs(step)) < 1e-15:
            break
    return u, v, float(np.linalg.norm(np.asarray(c(u)) - np.asarray(d(v))))


def _common(surfaces: list[NURBSSurface]) -> list[NURBSSurface]:
    """The surfaces with one degree pair and one pair of knot vectors (exact)."""
    for axis, direction in ((0, "u"), (1, "v")):
        degree = max(s.degree[axis] for s in surfaces)
        surfaces = [
            s if s.degree[axis] == degree
            else s.elevate_degree(degree - s.degree[axis], direction=direction)
            for s in surfaces
        ]  # fmt: skip
        target = merged_knots(*(np.asarray(s.knots[axis]) for s in surfaces))
        surfaces = [
            s.refine(missing_knots(np.asarray(s.knots[axis]), target), direction=direction)
            for s in surfaces
        ]
    return surfaces


def gordon(u_curves, v_curves, tol: float = 1e-6) -> NURBSSurface:
    """The Gordon surface through a network of curves: every `u_curves[k]` is its curve
    `v = v_k` and every `v_curves[l]` its curve `u = u_l`.

    The curves are mapped onto [0, 1]; each `u_curves[k]` must meet each `v_curves[l]`
    (within `tol`), and at one parameter `u_l` along every u-curve and one `v_k` along every
    v-curve (a compatible network: reparametrize the curves first otherwise). The first and
    last curves of each family are the boundary (`u_0 = v_0 = 0`, `u_L = v_K = 1`), and the
    curves come in order.

    **Arguments:**

    - `u_curves`, `v_curves`: two or more non-rational `NURBSCurve`s each, one dimension.
    - `tol`: how far apart the curves may pass at an intersection, and how much the
      intersection parameters may differ along the network.

    **Returns:**

    The non-rational `NURBSSurface` `L_u + L_v - T` (see `_skinning`).
    """
    u_curves = [on_unit_domain(c) for c in _check_curves(u_curves, "u_curves")]
    v_curves = [on_unit_domain(c) for c in _check_curves(v_curves, "v_curves")]
    if u_curves[0].dim != v_curves[0].dim:
        raise ValueError("u_curves and v_curves must have one dimension")
    if any(c.rational for c in u_curves + v_curves):
        raise ValueError(
            "gordon needs non-rational curves: the Boolean sum of rational lofts has no common "
            "denominator"
        )
    meets = np.array([[_meeting(c, d) for d in v_curves] for c in u_curves])  # (K, L, 3)
    far = np.unravel_index(np.argmax(meets[..., 2]), meets.shape[:2])
    if meets[far][2] > tol:
        raise ValueError(
            f"u_curves[{far[0]}] and v_curves[{far[1]}] do not meet: they pass "
            f"{meets[far][2]:.3g} apart (tol = {tol}); expected a network of intersecting curves"
        )
    u_at, v_at = meets[..., 0], meets[..., 1]  # u_at[k, l]: where v-curve l crosses u-curve k
    for name, values, axis in (("u", u_at, 0), ("v", v_at, 1)):
        spread = np.ptp(values, axis=axis).max()
        if spread > tol:
            raise ValueError(
                f"the network is not compatible: the crossings' {name} parameters differ by "
                f"{spread:.3g} along the network (tol = {tol}); expected every curve to meet "
                f"the others at one {name} (reparametrize the curves)"
            )
    u_l, v_k = u_at.mean(axis=0), v_at.mean(axis=1)
    for name, values in (("u", u_l), ("v", v_k)):
        if values[0] > tol or values[-1] < 1 - tol or np.any(np.diff(values) <= 0):
            raise ValueError(
                f"the network must have curves along its boundary and in order: the crossings' "
                f"{name} parameters are {np.round(values, 6).tolist()}, expected an increasing "
                f"sequence from 0 to 1 (sort the curves; add the boundary curves)"
            )
        values[0], values[-1] = 0.0, 1.0  # the ends exactly, as the curves' domains
    degree_u, degree_v = min(3, len(v_curves) - 1), min(3, len(u_curves) - 1)
    across_v = loft(u_curves, degree_v, v_k)
    across_u = loft(v_curves, degree_u, u_l)
    across_u = NURBSSurface(
        jnp.swapaxes(across_u.control_points, 0, 1), across_u.degree[::-1], across_u.knots[::-1]
    )
    # T: the crossings interpolated along u (the same degree and knots as the loft of the
    # v-curves), then across v (as the loft of the u-curves).
    crossings = jnp.asarray([[np.asarray(c(u)) for u in u_l] for c in u_curves])  # (K, L, dim)
    knots_u = averaged_knots(jnp.asarray(u_l), degree_u)
    rows = [
        NURBSCurve(collocation_solve(jnp.asarray(u_l), np.zeros(len(u_l), int), knots_u,
                                     degree_u, row), degree_u, knots_u)
        for row in crossings
    ]  # fmt: skip
    tensor = loft(rows, degree_v, v_k)
    parts = _common([across_v, across_u, tensor])
    points = parts[0].control_points + parts[1].control_points - parts[2].control_points
    return NURBSSurface(points, parts[0].degree, parts[0].knots)
