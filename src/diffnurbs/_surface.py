"""Surfaces: the abstract base every surface shares, and tensor-product NURBS surfaces."""

import abc
import typing

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._basis import basis_funs, combine_local, dense_basis, ders_basis_funs, local_indices
from ._inversion import surface_closest_point
from ._knotops import (
    bezier_pieces,
    checked_insertion,
    checked_refinement,
    concrete_knots,
    elevate,
)
from ._knotremoval import check_tolerance, homogeneous_tolerance, reduce, remove, simplify
from ._knots import clamped_knots
from ._misc import clamp_to_domain, safe_norm, safe_normalize
from ._rational import AbstractRationalSpline, from_homogeneous, rational_surface_derivatives
from ._validate import (
    check_control_count,
    check_degree,
    check_degree_pair,
    check_finite,
    check_grid_axes,
    check_knots,
    check_order,
    check_pair,
    check_parameter,
    check_rank,
    check_weights,
    concrete,
    domain_ends,
    float_dtype,
)

# Above this many control points in a direction, a dense basis matrix wastes more work on
# zeros than the matrix product saves over the banded gathers.
_DENSE_GRID_LIMIT = 64


class AbstractSurface(eqx.Module):
    """A parametric surface `S(u, v)` on a rectangle of parameters.

    The public methods (`__call__`, `grid`, `derivatives`, `normal`, `closest_point`)
    check concrete parameters against `domain` and call the evaluation hooks below on
    arrays; under `jit` parameters are not checked and the hooks clamp them. Subclasses
    (`NURBSSurface`, `CoonsPatch`, `KinematicSweep`) are final and implement:

    - `domain`: `((u_min, u_max), (v_min, v_max))`;
    - `_points(u, v)`: points at broadcast parameter arrays;
    - `_grid(us, vs)`: points on the tensor grid of two 1-D arrays;
    - `_derivatives(u, v, order)`: the partials `d^(k+l) S / du^k dv^l`, `k, l <= order`
      (`autodiff_partials` derives them from `_points` where no closed form is at hand);
    - `_sampling()`: for each direction, the parameters between which the surface is
      smooth (knots) and how many samples per such span point inversion starts from;
    - optionally `_second_order(u, v)`: what point inversion needs, `S`, its Jacobian and
      its Hessian (the default takes them from `_derivatives(u, v, 2)`, whose entries
      of order 3 and 4 autodiff surfaces would compute for nothing).

    So `viz.surface_mesh`, `io.tessellate` and `closest_point` work on every surface.
    """

    @property
    @abc.abstractmethod
    def domain(self) -> tuple[tuple[Array, Array], tuple[Array, Array]]:
        """`((u_min, u_max), (v_min, v_max))`."""

    @property
    @abc.abstractmethod
    def dim(self) -> int:
        """Dimension of the space the surface lives in."""

    @abc.abstractmethod
    def _points(self, u: Array, v: Array) -> Array:
        """Points at parameter arrays of one shape."""

    @abc.abstractmethod
    def _grid(self, us: Array, vs: Array) -> Array:
        """Points on the grid `us x vs` of two 1-D parameter arrays."""

    @abc.abstractmethod
    def _derivatives(self, u: Array, v: Array, order: int) -> Array:
        """Partials up to `order` at parameter arrays of one shape."""

    @abc.abstractmethod
    def _sampling(self) -> tuple[tuple[Array, int], tuple[Array, int]]:
        """`((breaks_u, samples_u), (breaks_v, samples_v))` for point inversion."""

    def _second_order(self, u: Array, v: Array) -> tuple[Array, Array, Array]:
        """`(S, J, H)` at parameter arrays of one shape: points `(..., dim)`, the Jacobian
        `(..., dim, 2)` and the Hessian `(..., dim, 2, 2)` with respect to `(u, v)`."""
        ders = self._derivatives(u, v, 2)
        jacobian = jnp.stack([ders[..., 1, 0, :], ders[..., 0, 1, :]], axis=-1)
        mixed = ders[..., 1, 1, :]
        hessian = jnp.stack(
            [
                jnp.stack([ders[..., 2, 0, :], mixed], axis=-1),
                jnp.stack([mixed, ders[..., 0, 2, :]], axis=-1),
            ],
            axis=-2,
        )
        return ders[..., 0, 0, :], jacobian, hessian

    def _parameters(self, u, v):
        """Parameters as arrays; concrete ones outside the domain raise `ValueError`."""
        (u0, u1), (v0, v1) = self.domain
        dtype = jnp.result_type(u0)
        u, v = jnp.asarray(u, dtype=dtype), jnp.asarray(v, dtype=dtype)
        check_parameter(u, u0, u1, "u")
        check_parameter(v, v0, v1, "v")
        return u, v

    def __call__(self, u: ArrayLike, v: ArrayLike) -> Float[Array, "... dim"]:
        """Points `S(u, v)`; `u` and `v` broadcast against each other."""
        return self._points(*jnp.broadcast_arrays(*self._parameters(u, v)))

    def grid(self, us: ArrayLike, vs: ArrayLike) -> Float[Array, "mu mv dim"]:
        """Points on the tensor grid `us x vs`, shape `(len(us), len(vs), dim)`."""
        us, vs = self._parameters(us, vs)
        check_grid_axes(us, vs)
        return self._grid(us, vs)

    def derivatives(self, u: ArrayLike, v: ArrayLike, order: int) -> Float[Array, "... k l dim"]:
        """All partial derivatives `d^(k+l) S / du^k dv^l` for `0 <= k, l <= order`.

        **Returns:**

        Array of shape `broadcast(u, v).shape + (order + 1, order + 1, dim)`.
        """
        u, v = jnp.broadcast_arrays(*self._parameters(u, v))
        return self._derivatives(u, v, check_order(order))

    def normal(self, u: ArrayLike, v: ArrayLike) -> Float[Array, "... 3"]:
        """Unit normal `S_u x S_v / |S_u x S_v|` of a surface in 3D.

        Zero where the surface is degenerate (a pole, a collapsed edge): there
        `|S_u x S_v|` is rounding noise, below `64 eps (|S_u|^2 + |S_v|^2)`.
        """
        if self.dim != 3:
            raise ValueError(f"normal needs a surface in 3D, got dim = {self.dim}")
        return self._normal(*jnp.broadcast_arrays(*self._parameters(u, v)))

    @eqx.filter_jit
    def _normal(self, u: Array, v: Array) -> Array:
        ders = self._derivatives(u, v, 1)
        s_u, s_v = ders[..., 1, 0, :], ders[..., 0, 1, :]
        cross = jnp.cross(s_u, s_v)
        scale = jnp.sum(s_u * s_u, -1) + jnp.sum(s_v * s_v, -1)
        noise = 64 * jnp.finfo(cross.dtype).eps * scale
        degenerate = (safe_norm(cross) <= noise)[..., None]
        return jnp.where(degenerate, 0.0, safe_normalize(cross))

    def closest_point(
        self, point: ArrayLike, samples_per_span: int | None = None
    ) -> tuple[Float[Array, "..."], Float[Array, "..."]]:
        """Point inversion: the parameters `(u, v)` of the point `S(u, v)` nearest to `point`.

        Every query starts from the nearest segment of the grid lines through
        `samples_per_span` samples in each span between knots in each direction, and as
        many again spread evenly (default `p + 2` for a NURBS surface of degree `p`; near
        ties, as across a seam, start from each candidate), then a projected Newton method
        on `|S(u, v) - P|^2` converges inside the domain: on an edge or at a corner where
        the distance still falls beyond it. `jax.grad` of the result reaches the points and
        the surface. See `_inversion`.

        **Arguments:**

        - `point`: array of shape `(..., dim)`: one point or many.
        - `samples_per_span`: samples per span in each direction for the start; raise it
          for surfaces that fold within a span (the start grid must resolve every fold for
          the nearest of several minima to be found).

        **Returns:**

        A pair `(u, v)` of arrays of shape `point.shape[:-1]`, so that
        `surface(*surface.closest_point(point))` is the nearest point.
        """
        return surface_closest_point(self, point, samples_per_span)


def _total_derivatives(points, u: Array, v: Array, total: int) -> list[Array]:
    """`[S, DS, ..., D^total S]` at one `(u, v)`: `D^m S` has shape `(dim,) + (2,) * m`,
    its last `m` axes picking `u` (0) or `v` (1) for each differentiation.

    Each order is one more forward-mode pass over the program of the previous ones, which
    it carries along as auxiliary output, so lower orders are not traced again. For the
    second order this compiles faster than a nest per entry (measured: a Coons patch's
    point inversion 12.5 s against 18 s); for a whole table of `autodiff_partials` the
    nests compile faster.
    """

    def differentiated(orders):
        def extended(x):
            def highest(x):
                found = orders(x)
                return found[-1], found

            derivative, found = jax.jacfwd(highest, has_aux=True)(x)
            return [*found, derivative]

        return extended

    orders = lambda x: [points(x[0], x[1])]  # noqa: E731
    for _ in range(total):
        orders = differentiated(orders)
    return orders(jnp.stack([u, v]))


def autodiff_partials(points, u: Array, v: Array, order: int) -> Array:
    """The partials `d^(k+l) S / du^k dv^l`, `0 <= k, l <= order`, of `points(u, v)` by
    nested forward-mode autodiff: for surfaces with no closed form for their derivatives.

    **Arguments:**

    - `points`: `S(u, v)` for scalar parameters, returning an array `(dim,)`.
    - `u`, `v`: parameter arrays of one shape.
    - `order`: highest order in each direction.

    **Returns:**

    Array of shape `u.shape + (order + 1, order + 1, dim)`.
    """

    def table(u, v):
        rows, along_u = [], points
        for _ in range(order + 1):
            row, along_v = [], along_u
            for _ in range(order + 1):
                row.append(along_v(u, v))
                along_v = jax.jacfwd(along_v, argnums=1)
            rows.append(jnp.stack(row))
            along_u = jax.jacfwd(along_u, argnums=0)
        return jnp.stack(rows)

    flat = jax.vmap(table)(jnp.ravel(u), jnp.ravel(v))
    return flat.reshape(u.shape + flat.shape[1:])


def autodiff_second_order(points, u: Array, v: Array) -> tuple[Array, Array, Array]:
    """`S`, its Jacobian and its Hessian in `(u, v)` by forward-mode autodiff; see
    `AbstractSurface._second_order`: the entries that point inversion uses, without the
    partials of order 3 and 4 that the table of `autodiff_partials(..., order=2)` holds.
    """
    flat = jax.vmap(lambda u, v: _total_derivatives(points, u, v, 2))(jnp.ravel(u), jnp.ravel(v))
    return tuple(d.reshape(u.shape + d.shape[1:]) for d in flat)


@typing.final
class NURBSSurface(AbstractRationalSpline, AbstractSurface):
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
        self.degree = check_degree_pair(degree)
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
        knots_u, knots_v = (jnp.asarray(k, dtype=dtype) for k in check_pair(knots, "knots"))
        self.knots_u = check_knots(knots_u, points.shape[0], self.degree[0], "knots U")
        self.knots_v = check_knots(knots_v, points.shape[1], self.degree[1], "knots V")
        if weights is not None:
            weights = check_weights(jnp.asarray(weights, dtype=dtype), points.shape[:2])
        self.weights = weights

    @property
    def knots(self) -> tuple[Array, Array]:
        return self.knots_u, self.knots_v

    @property
    def domain(self) -> tuple[tuple[Array, Array], tuple[Array, Array]]:
        """`((u_min, u_max), (v_min, v_max))`."""
        p, q = self.degree
        return domain_ends(self.knots_u, p), domain_ends(self.knots_v, q)

    def _from_homogeneous_points(self, points, knots_u, knots_v, degree=None) -> "NURBSSurface":
        """A surface of the same kind (and degrees, unless given) from homogeneous points."""
        degree = self.degree if degree is None else degree
        if not self.rational:
            return NURBSSurface(points, degree, (knots_u, knots_v))
        weights = points[..., -1]
        return NURBSSurface(from_homogeneous(points), degree, (knots_u, knots_v), weights)

    def _along(self, direction: str, operation) -> "NURBSSurface":
        """Apply a curve operation `(points, knots, degree) -> (points, knots)` to every row
        (`direction="u"`) or column (`"v"`) of the homogeneous net."""
        if direction not in ("u", "v"):
            raise ValueError(f'direction must be "u" or "v", got {direction!r}')
        along_v = direction == "v"
        points = self.homogeneous_points()
        points = jnp.swapaxes(points, 0, 1) if along_v else points
        points, knots = operation(points, self.knots[along_v], self.degree[along_v])
        degree = knots.shape[0] - points.shape[0] - 1  # raised by degree elevation
        if along_v:
            return self._from_homogeneous_points(
                jnp.swapaxes(points, 0, 1), self.knots_u, knots, (self.degree[0], degree)
            )
        return self._from_homogeneous_points(points, knots, self.knots_v, (degree, self.degree[1]))

    def insert_knot(
        self, value: ArrayLike, times: int = 1, *, direction: str = "u"
    ) -> "NURBSSurface":
        """The same surface with a knot inserted `times` times along `direction` ("u" or "v").

        The control points of NURBS Book A5.3 (Boehm's algorithm on every row or column of
        the net), computed at once (see `NURBSCurve.insert_knot`).
        """

        def operation(points, knots, degree):
            return checked_insertion(points, knots, degree, value, times)

        return self._along(direction, operation)

    def refine(self, values: ArrayLike, *, direction: str = "u") -> "NURBSSurface":
        """The same surface with every knot of `values` inserted along `direction`."""

        def operation(points, knots, degree):
            return checked_refinement(points, knots, degree, values)

        return self._along(direction, operation)

    def elevate_degree(self, times: int = 1, *, direction: str = "u") -> "NURBSSurface":
        """The same surface with its degree along `direction` raised by `times`
        (see `NURBSCurve.elevate_degree`)."""
        times = check_degree(times, minimum=1, name="times")
        return self._along(direction, lambda points, knots, p: elevate(points, knots, p, times))

    def _tolerance(self, tol: float | None) -> float:
        """`tol` checked; None: `1e-12 (1 + max |P|)` (only exact changes); needs a concrete net."""
        values = concrete(self.control_points)
        if values is None:
            raise ValueError("this operation needs a concrete surface (not traced)")
        return check_tolerance(1e-12 * (1 + float(np.max(np.abs(values)))) if tol is None else tol)

    def remove_knot(
        self, value: float, times: int = 1, tol: float | None = None, *, direction: str = "u"
    ) -> tuple["NURBSSurface", int]:
        """The surface with the knot `value` removed up to `times` times along `direction`,
        as often as every row (or column) of the net allows within `tol` (NURBS Book A5.8 on
        whole rows; see `NURBSCurve.remove_knot`, whose `tol` conventions it shares).

        **Returns:**

        `(surface, removed)`.
        """
        times = check_degree(times, minimum=1, name="times")
        tol = self._tolerance(tol)
        removed = 0

        def operation(points, knots, degree):
            nonlocal removed
            values = np.asarray(points)
            scaled = homogeneous_tolerance(values, self.rational, tol)
            rows, knots, removed, _ = remove(
                list(values), concrete_knots(knots, "knot removal"), degree, float(value),
                times, scaled,
            )  # fmt: skip
            return jnp.asarray(np.stack(rows)), jnp.asarray(knots)

        surface = self._along(direction, operation)
        return (surface, removed) if removed else (self, 0)

    def simplify(self, tol: float, *, direction: str = "u") -> "NURBSSurface":
        """The surface with every knot along `direction` removed that can go while the
        surface stays within `tol` (see `NURBSCurve.simplify`)."""
        tol = self._tolerance(tol)

        def operation(points, knots, degree):
            points, knots = simplify(
                np.asarray(points), concrete_knots(knots, "simplify"), degree, self.rational, tol
            )
            return jnp.asarray(points), jnp.asarray(knots)

        return self._along(direction, operation)

    def reduce_degree(self, tol: float | None = None, *, direction: str = "u") -> "NURBSSurface":
        """The surface of one degree less along `direction` within `tol` of this one: the
        inverse of `elevate_degree` (see `NURBSCurve.reduce_degree`)."""
        if self.degree[direction == "v"] < 2:
            raise ValueError(f"reduce_degree needs degree >= 2 along {direction}")
        tol = self._tolerance(tol)

        def operation(points, knots, degree):
            points, knots, error = reduce(
                np.asarray(points), concrete_knots(knots, "degree reduction"), degree,
                self.rational, tol,
            )  # fmt: skip
            points, knots = simplify(points, knots, degree - 1, self.rational, tol, error)
            return jnp.asarray(points), jnp.asarray(knots)

        return self._along(direction, operation)

    def decompose(self) -> list[list["NURBSSurface"]]:
        """The Bezier patches of the surface, `patches[i][j]` on the i-th u and j-th v span."""
        p, q = self.degree
        patches = []
        for strip, knots_u in bezier_pieces(self.homogeneous_points(), self.knots_u, p):
            pieces = bezier_pieces(jnp.swapaxes(strip, 0, 1), self.knots_v, q)
            patches.append(
                [
                    self._from_homogeneous_points(jnp.swapaxes(piece, 0, 1), knots_u, knots_v)
                    for piece, knots_v in pieces
                ]
            )
        return patches

    def _clamp(self, u, v):
        (u0, u1), (v0, v1) = self.domain
        return clamp_to_domain(u, u0, u1), clamp_to_domain(v, v0, v1)

    def _local_net(self, span_u, span_v):
        """The `(p + 1, q + 1)` homogeneous control points acting at each parameter pair."""
        p, q = self.degree
        rows = local_indices(span_u, p)[..., :, None]
        cols = local_indices(span_v, q)[..., None, :]
        return self.homogeneous_points()[rows, cols]

    @eqx.filter_jit
    def _points(self, u: Array, v: Array) -> Array:
        u, v = jnp.broadcast_arrays(*self._clamp(u, v))
        (p, q), points = self.degree, self.homogeneous_points()
        span_u, funs_u = basis_funs(self.knots_u, p, u)
        span_v, funs_v = basis_funs(self.knots_v, q, v)
        nv = points.shape[1]
        first = (span_u - p) * nv + (span_v - q)  # flat index of the first active point
        # One array per coordinate, summed term by term: XLA then fuses each coordinate
        # into one pass without materialising the (..., p + 1, q + 1, dim) local nets.
        columns = []
        for coordinate in points.reshape(-1, points.shape[2]).T:
            total = 0.0
            for a in range(p + 1):
                row = sum(funs_v[..., b] * coordinate[first + a * nv + b] for b in range(q + 1))
                total = total + funs_u[..., a] * row
            columns.append(total)
        if self.rational:
            columns = [column / columns[-1] for column in columns[:-1]]
        return jnp.stack(columns, axis=-1)

    @eqx.filter_jit
    def _grid(self, us: Array, vs: Array) -> Array:
        # One direction at a time, with basis matrices (len(us), nu) and (len(vs), nv): two
        # matrix products when the net is small, the banded p + 1 non-zeros per row
        # (gathers) when it is large.
        us, vs = self._clamp(us, vs)
        (p, q), points = self.degree, self.homogeneous_points()
        span_u, funs_u = basis_funs(self.knots_u, p, us)
        span_v, funs_v = basis_funs(self.knots_v, q, vs)
        if max(points.shape[:2]) <= _DENSE_GRID_LIMIT:
            basis_u = dense_basis(span_u, funs_u, p, points.shape[0])
            basis_v = dense_basis(span_v, funs_v, q, points.shape[1])
            grid = jnp.einsum("ia,abd,jb->ijd", basis_u, points, basis_v)
        else:
            curves = combine_local(funs_u, points, span_u, p)  # (mu, nv, D)
            cols = curves[:, local_indices(span_v, q)]  # (mu, mv, q + 1, D)
            grid = jnp.einsum("jb,ijbd->ijd", funs_v, cols)
        return from_homogeneous(grid) if self.rational else grid

    @eqx.filter_jit
    def _derivatives(self, u: Array, v: Array, order: int) -> Array:
        # SurfaceDerivs (NURBS Book A3.6) on the homogeneous net, then the Leibniz rule
        # (A4.4) when rational.
        u, v = jnp.broadcast_arrays(*self._clamp(u, v))
        span_u, ders_u = ders_basis_funs(self.knots_u, self.degree[0], u, order)
        span_v, ders_v = ders_basis_funs(self.knots_v, self.degree[1], v, order)
        net = self._local_net(span_u, span_v)
        homogeneous = jnp.einsum("...ka,...lb,...abd->...kld", ders_u, ders_v, net)
        if not self.rational:
            return homogeneous
        return rational_surface_derivatives(homogeneous[..., :-1], homogeneous[..., -1])

    def _sampling(self):
        (p, q), (knots_u, knots_v) = self.degree, self.knots
        return (knots_u[p:-p], p + 2), (knots_v[q:-q], q + 2)
