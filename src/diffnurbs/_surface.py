"""Tensor-product NURBS surfaces."""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._basis import basis_funs, ders_basis_funs
from ._curve import clamp_to_domain, local_indices, safe_normalize
from ._knots import clamped_knots
from ._rational import from_homogeneous, rational_surface_derivatives, to_homogeneous
from ._validate import (
    check_control_count,
    check_degree,
    check_finite,
    check_knots,
    check_order,
    check_parameter,
    check_rank,
    check_weights,
    float_dtype,
)


def _pair(value, name):
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ValueError(f"{name} must be a pair (u direction, v direction), got {value!r}")
    return tuple(value)


class NURBSSurface(eqx.Module):
    """A (rational) tensor-product B-spline surface

    `S(u, v) = sum_ij N_{i,p}(u) N_{j,q}(v) w_ij P_ij / sum_ij N_{i,p}(u) N_{j,q}(v) w_ij`.

    `control_points[i, j]` is `P_ij`: the first axis runs along `u`, the second along `v`.
    Bezier patches are the case `p = nu - 1`, `q = nv - 1` with default knots. Parameters
    outside the domain raise `ValueError` when concrete and are clamped under `jit`.
    """

    control_points: Float[Array, "nu nv dim"]
    weights: Float[Array, "nu nv"] | None
    knots_u: Float[Array, " nu+p+1"]
    knots_v: Float[Array, " nv+q+1"]
    degree: tuple[int, int] = eqx.field(static=True)

    def __init__(
        self,
        control_points: ArrayLike,
        degree: tuple[int, int],
        knots: tuple[ArrayLike, ArrayLike] | None = None,
        weights: ArrayLike | None = None,
    ):
        """**Arguments:**

        - `control_points`: array of shape `(nu, nv, dim)`.
        - `degree`: `(p, q)`.
        - `knots`: `(U, V)`; None gives clamped uniform knots on [0, 1] in both directions.
        - `weights`: positive array of shape `(nu, nv)`; None gives a non-rational surface.
        """
        p, q = _pair(degree, "degree")
        self.degree = (check_degree(p, name="degree p"), check_degree(q, name="degree q"))
        points = jnp.asarray(control_points)
        check_rank(points, 3, "control_points", "(nu, nv, dim)")
        check_control_count(points.shape[0], self.degree[0], "control points along u")
        check_control_count(points.shape[1], self.degree[1], "control points along v")
        arrays = [
            points,
            *(() if knots is None else knots),
            *(() if weights is None else (weights,)),
        ]
        dtype = float_dtype(*[jnp.asarray(x) for x in arrays])
        self.control_points = check_finite(points.astype(dtype), "control_points")
        if knots is None:
            knots = tuple(
                clamped_knots(n, d, dtype=dtype)
                for n, d in zip(points.shape[:2], self.degree, strict=True)
            )
        knots_u, knots_v = (jnp.asarray(k, dtype=dtype) for k in _pair(knots, "knots"))
        self.knots_u = check_knots(knots_u, points.shape[0], self.degree[0], "knots U")
        self.knots_v = check_knots(knots_v, points.shape[1], self.degree[1], "knots V")
        if weights is not None:
            weights = check_weights(jnp.asarray(weights, dtype=dtype), points.shape[:2])
        self.weights = weights

    @property
    def knots(self) -> tuple[Array, Array]:
        return self.knots_u, self.knots_v

    @property
    def rational(self) -> bool:
        return self.weights is not None

    @property
    def dim(self) -> int:
        return self.control_points.shape[2]

    @property
    def domain(self) -> tuple[tuple[Array, Array], tuple[Array, Array]]:
        """`((u_min, u_max), (v_min, v_max))`."""
        p, q = self.degree
        return (self.knots_u[p], self.knots_u[-p - 1]), (self.knots_v[q], self.knots_v[-q - 1])

    def homogeneous_points(self) -> Float[Array, "nu nv dim+1"]:
        """Control points as `(w P, w)`; the plain points when the surface is not rational."""
        if self.weights is None:
            return self.control_points
        return to_homogeneous(self.control_points, self.weights)

    def _parameters(self, u, v):
        (u0, u1), (v0, v1) = self.domain
        u = jnp.asarray(u, dtype=self.knots_u.dtype)
        v = jnp.asarray(v, dtype=self.knots_u.dtype)
        check_parameter(u, u0, u1, "u")
        check_parameter(v, v0, v1, "v")
        return clamp_to_domain(u, u0, u1), clamp_to_domain(v, v0, v1)

    def _local_net(self, span_u, span_v):
        """The `(p + 1, q + 1)` homogeneous control points acting at each parameter pair."""
        p, q = self.degree
        rows = local_indices(span_u, p)[..., :, None]
        cols = local_indices(span_v, q)[..., None, :]
        return self.homogeneous_points()[rows, cols]

    def __call__(self, u: ArrayLike, v: ArrayLike) -> Float[Array, "... dim"]:
        """Points `S(u, v)`; `u` and `v` broadcast against each other."""
        u, v = jnp.broadcast_arrays(*self._parameters(u, v))
        span_u, funs_u = basis_funs(self.knots_u, self.degree[0], u)
        span_v, funs_v = basis_funs(self.knots_v, self.degree[1], v)
        net = self._local_net(span_u, span_v)
        points = jnp.einsum("...a,...b,...abd->...d", funs_u, funs_v, net)
        return from_homogeneous(points) if self.rational else points

    def grid(self, us: ArrayLike, vs: ArrayLike) -> Float[Array, "mu mv dim"]:
        """Points on the tensor grid `us x vs`, shape `(len(us), len(vs), dim)`.

        Contracts one direction at a time, so the cost is `O(mu (p + 1) nv + mu mv (q + 1))`
        instead of `O(mu mv (p + 1)(q + 1))` for scattered evaluation.
        """
        us, vs = self._parameters(us, vs)
        check_rank(us, 1, "us", "(a 1-D array of u values)")
        check_rank(vs, 1, "vs", "(a 1-D array of v values)")
        p, q = self.degree
        span_u, funs_u = basis_funs(self.knots_u, p, us)
        span_v, funs_v = basis_funs(self.knots_v, q, vs)
        rows = self.homogeneous_points()[local_indices(span_u, p)]  # (mu, p+1, nv, D)
        curves = jnp.einsum("ia,iajd->ijd", funs_u, rows)  # (mu, nv, D)
        cols = curves[:, local_indices(span_v, q)]  # (mu, mv, q+1, D)
        points = jnp.einsum("jb,ijbd->ijd", funs_v, cols)
        return from_homogeneous(points) if self.rational else points

    def derivatives(self, u: ArrayLike, v: ArrayLike, order: int) -> Float[Array, "... k l dim"]:
        """All partial derivatives `d^(k+l) S / du^k dv^l` for `0 <= k, l <= order`.

        SurfaceDerivs (NURBS Book A3.6) on the homogeneous surface, then the Leibniz rule
        (A4.4) when rational.

        **Returns:**

        Array of shape `broadcast(u, v).shape + (order + 1, order + 1, dim)`.
        """
        order = check_order(order)
        u, v = jnp.broadcast_arrays(*self._parameters(u, v))
        span_u, ders_u = ders_basis_funs(self.knots_u, self.degree[0], u, order)
        span_v, ders_v = ders_basis_funs(self.knots_v, self.degree[1], v, order)
        net = self._local_net(span_u, span_v)
        homogeneous = jnp.einsum("...ka,...lb,...abd->...kld", ders_u, ders_v, net)
        if not self.rational:
            return homogeneous
        return rational_surface_derivatives(homogeneous[..., :-1], homogeneous[..., -1])

    def normal(self, u: ArrayLike, v: ArrayLike) -> Float[Array, "... 3"]:
        """Unit normal `S_u x S_v / |S_u x S_v|` of a surface in 3D; zero where degenerate."""
        if self.dim != 3:
            raise ValueError(f"normal needs a surface in 3D, got dim = {self.dim}")
        ders = self.derivatives(u, v, 1)
        return safe_normalize(jnp.cross(ders[..., 1, 0, :], ders[..., 0, 1, :]))
