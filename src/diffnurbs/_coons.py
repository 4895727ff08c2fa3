"""Bilinear and bilinearly blended Coons patches (seed 002).

A bilinear patch interpolates four corners; a Coons patch interpolates four boundary
curves. Both are "transfinite" blends: the Coons patch is the sum of the two ruled
surfaces between opposite boundaries minus the bilinear patch of the corners, which both
ruled surfaces count once too often,

`S(u, v) = L_c(u, v) + L_d(u, v) - B(u, v)`,

- `L_c = (1 - v) c0(u) + v c1(u)` (ruled between the bottom and top curves),
- `L_d = (1 - u) d0(v) + u d1(v)` (ruled between the left and right curves),
- `B = (1 - u)(1 - v) P00 + u (1 - v) P10 + (1 - u) v P01 + u v P11`.
"""

import typing

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._curve import NURBSCurve
from ._knotops import greville
from ._misc import clamp_to_domain, safe_norm
from ._skinning import compatible, on_unit_domain
from ._surface import (
    AbstractSurface,
    NURBSSurface,
    autodiff_partials,
    autodiff_second_order,
)
from ._validate import check_rank, concrete, float_dtype


def bilinear_patch(p00: ArrayLike, p10: ArrayLike, p01: ArrayLike, p11: ArrayLike) -> NURBSSurface:
    """The bilinear patch through four corners (seed 002):
    `S(u, v) = (1 - v) [(1 - u) p00 + u p10] + v [(1 - u) p01 + u p11]`.

    Its isoparametric lines are straight; with non-coplanar corners it is a hyperbolic
    paraboloid. (The seed labels the corner at `u = 1, v = 0` as `P01`; here the first
    index runs along `u`, as in `NURBSSurface.control_points`.)

    **Arguments:**

    - `p00`, `p10`, `p01`, `p11`: the corners `S(0, 0)`, `S(1, 0)`, `S(0, 1)`, `S(1, 1)`,
      points of one dimension.

    **Returns:**

    A `NURBSSurface` of degree `(1, 1)` on `[0, 1] x [0, 1]`.
    """
    corners = [jnp.asarray(p) for p in (p00, p10, p01, p11)]
    for name, point in zip(("p00", "p10", "p01", "p11"), corners, strict=True):
        check_rank(point, 1, name, "(a point, shape (dim,))")
    shapes = {point.shape for point in corners}
    if len(shapes) != 1:
        raise ValueError(
            f"the four corners must have the same dimension, got shapes "
            f"{[point.shape for point in corners]}"
        )
    dtype = float_dtype(*corners)
    c00, c10, c01, c11 = (point.astype(dtype) for point in corners)
    return NURBSSurface(jnp.stack([jnp.stack([c00, c01]), jnp.stack([c10, c11])]), (1, 1))


def _unit_to_domain(curve: NURBSCurve, t: Array) -> Array:
    """`curve` at the parameter that `t` in [0, 1] maps to, linearly onto its domain."""
    lower, upper = curve.domain
    # (1 - t) a + t b hits both ends exactly; the clamp removes rounding just outside.
    return curve(clamp_to_domain((1 - t) * lower + t * upper, lower, upper))


# The corners as (u, v), each with the two curve ends that must meet there.
_CORNERS = (
    ((0, 0), ("c0", 0), ("d0", 0)),
    ((1, 0), ("c0", 1), ("d1", 0)),
    ((0, 1), ("c1", 0), ("d0", 1)),
    ((1, 1), ("c1", 1), ("d1", 1)),
)


@eqx.filter_jit
def _corners(curves, tol):
    """Distances between the curve ends at each corner, the `(2, 2, dim)` corners (averaged
    ends, first index along `u`) and the allowed distance `tol * size`."""
    ends = {}
    for name, curve in curves.items():
        ends[name] = _unit_to_domain(curve, jnp.asarray([0.0, 1.0], curve.control_points.dtype))
    all_points = jnp.concatenate([curve.control_points for curve in curves.values()])
    size = safe_norm(jnp.max(all_points, axis=0) - jnp.min(all_points, axis=0))
    gaps, corners = [], {}
    for (u, v), (a, ia), (b, ib) in _CORNERS:
        gaps.append(safe_norm(ends[a][ia] - ends[b][ib]))
        corners[u, v] = 0.5 * (ends[a][ia] + ends[b][ib])
    corners = jnp.stack(
        [jnp.stack([corners[0, 0], corners[0, 1]]), jnp.stack([corners[1, 0], corners[1, 1]])]
    )
    return jnp.stack(gaps), corners, tol * size


@typing.final
class CoonsPatch(AbstractSurface):
    """The bilinearly blended Coons patch of four boundary curves (seed 002).

    `S(u, 0) = c0(u)`, `S(u, 1) = c1(u)`, `S(0, v) = d0(v)`, `S(1, v) = d1(v)` on
    `[0, 1] x [0, 1]`; each curve's own domain is mapped linearly onto [0, 1]. The
    patch is evaluated directly as `L_c + L_d - B` (see the module docstring), so rational
    curves are reproduced exactly. Corners are the averages of the two curve ends that
    meet there (equal within `tol` by construction). `to_nurbs` gives the exact
    `NURBSSurface` of a patch with non-rational boundaries.
    """

    c0: NURBSCurve
    c1: NURBSCurve
    d0: NURBSCurve
    d1: NURBSCurve
    corners: Float[Array, "2 2 dim"]

    def __init__(
        self,
        c0: NURBSCurve,
        c1: NURBSCurve,
        d0: NURBSCurve,
        d1: NURBSCurve,
        tol: float = 1e-9,
    ):
        """**Arguments:**

        - `c0`, `c1`: the curves at `v = 0` and `v = 1`, running in `u`.
        - `d0`, `d1`: the curves at `u = 0` and `u = 1`, running in `v`.
        - `tol`: allowed distance between curve ends meeting at a corner, relative to the
          size (bounding-box diagonal) of all control points.

        Concrete curves whose ends miss a corner raise `ValueError`; under tracing the
        check goes through `eqx.error_if`.
        """
        if not np.isscalar(tol) or not tol >= 0:
            raise ValueError(f"tol must be a number >= 0, got {tol!r}")
        curves = {"c0": c0, "c1": c1, "d0": d0, "d1": d1}
        for name, curve in curves.items():
            if not isinstance(curve, NURBSCurve):
                raise ValueError(f"{name} must be a NURBSCurve, got {type(curve).__name__}")
        dims = {name: curve.control_points.shape[-1] for name, curve in curves.items()}
        if len(set(dims.values())) != 1:
            raise ValueError(f"the four curves must have the same dimension, got {dims}")
        gaps, corners, limit = _corners(curves, tol)
        gap_values, limit_value = concrete(gaps), concrete(limit)
        if gap_values is None or limit_value is None:
            corners = eqx.error_if(
                corners, jnp.any(gaps > limit), "the boundary curves do not meet at a corner"
            )
        else:
            for gap, ((u, v), (a, ia), (b, ib)) in zip(gap_values, _CORNERS, strict=True):
                if gap > limit_value:
                    raise ValueError(
                        f"corner (u, v) = ({u}, {v}): {a} at its {('start', 'end')[ia]} and "
                        f"{b} at its {('start', 'end')[ib]} are {gap:.3g} apart; expected "
                        f"<= tol * size = {limit_value:.3g}"
                    )
        self.c0, self.c1, self.d0, self.d1 = c0, c1, d0, d1
        self.corners = corners

    @property
    def domain(self) -> tuple[tuple[Array, Array], tuple[Array, Array]]:
        """`((0, 1), (0, 1))`: each boundary curve is mapped onto [0, 1]."""
        zero, one = jnp.zeros((), self.corners.dtype), jnp.ones((), self.corners.dtype)
        return (zero, one), (zero, one)

    @property
    def dim(self) -> int:
        return self.corners.shape[-1]

    def _blend(self, cu0, cu1, dv0, dv1, u, v):
        """`L_c + L_d - B` from the boundary points; `u`, `v` with a trailing axis."""
        (p00, p01), (p10, p11) = self.corners
        ruled_c = (1 - v) * cu0 + v * cu1
        ruled_d = (1 - u) * dv0 + u * dv1
        corners = (1 - u) * ((1 - v) * p00 + v * p01) + u * ((1 - v) * p10 + v * p11)
        return ruled_c + ruled_d - corners

    # One compiled function per patch and shape, instead of one per boundary curve.
    @eqx.filter_jit
    def _points(self, u: Array, v: Array) -> Array:
        cu0, cu1 = _unit_to_domain(self.c0, u), _unit_to_domain(self.c1, u)
        dv0, dv1 = _unit_to_domain(self.d0, v), _unit_to_domain(self.d1, v)
        return self._blend(cu0, cu1, dv0, dv1, u[..., None], v[..., None])

    @eqx.filter_jit
    def _grid(self, us: Array, vs: Array) -> Array:
        # Each boundary curve is evaluated once per grid line, not once per point.
        cu0, cu1 = (_unit_to_domain(c, us)[:, None, :] for c in (self.c0, self.c1))
        dv0, dv1 = (_unit_to_domain(d, vs)[None, :, :] for d in (self.d0, self.d1))
        return self._blend(cu0, cu1, dv0, dv1, us[:, None, None], vs[None, :, None])

    @eqx.filter_jit
    def _derivatives(self, u: Array, v: Array, order: int) -> Array:
        return autodiff_partials(self._points, u, v, order)

    def _second_order(self, u: Array, v: Array) -> tuple[Array, Array, Array]:
        return autodiff_second_order(self._points, u, v)

    def _sampling(self):
        def along(a, b):  # the knots of two opposite curves on [0, 1], as for a degree-p net
            breaks = [on_unit_domain(c).knots[c.degree : -c.degree] for c in (a, b)]
            return jnp.sort(jnp.concatenate(breaks)), max(a.degree, b.degree) + 2

        return along(self.c0, self.c1), along(self.d0, self.d1)

    def to_nurbs(self) -> NURBSSurface:
        """The patch as an exact B-spline surface (non-rational boundary curves, concrete knots).

        Opposite curves get one degree and one knot vector on [0, 1] (degree elevation and
        knot refinement). The B-spline coefficients of `u -> u` are the Greville abscissae
        `xi_i` (linear precision), so every term of `L_c + L_d - B` is a tensor product in
        the common bases and the control points are
        `(1 - eta_j) C0_i + eta_j C1_i + (1 - xi_i) D0_j + xi_i D1_j - B(xi_i, eta_j)`.

        **Returns:**

        A `NURBSSurface` on `[0, 1] x [0, 1]` equal to the patch.
        """
        rational = [name for name in ("c0", "c1", "d0", "d1") if getattr(self, name).rational]
        if rational:
            raise ValueError(
                f"to_nurbs needs non-rational boundary curves, but {rational} have weights: "
                "the blend of rational curves has the product of their weight functions as "
                "denominator; evaluate the CoonsPatch directly instead"
            )
        c0, c1 = compatible(self.c0, self.c1)
        d0, d1 = compatible(self.d0, self.d1)
        xi = greville(c0.knots, c0.degree)[:, None, None]
        eta = greville(d0.knots, d0.degree)[None, :, None]
        cu0, cu1 = (c.control_points[:, None, :] for c in (c0, c1))
        dv0, dv1 = (d.control_points[None, :, :] for d in (d0, d1))
        points = self._blend(cu0, cu1, dv0, dv1, xi, eta)
        return NURBSSurface(points, (c0.degree, d0.degree), (c0.knots, d0.knots))
