"""NURBS curves: evaluation, derivatives and differential geometry."""

import math
import typing

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._arclength import check_lengths, length_table, parameter_at_length, unit_speed_curve
from ._basis import basis_funs, combine_local, ders_basis_funs, find_span, span_derivatives
from ._inversion import curve_closest_point
from ._knotops import bezier_pieces, checked_insertion, checked_refinement, elevate
from ._knotremoval import check_tolerance, homogeneous_tolerance, reduce, remove, simplify
from ._knots import clamped_knots
from ._misc import clamp_to_domain, safe_divide, safe_norm, safe_normalize, safe_sqrt
from ._quadrature import integrate_panels
from ._rational import (
    AbstractRationalSpline,
    from_homogeneous,
    rational_columns,
    rational_curve_derivatives,
)
from ._validate import (
    check_control_count,
    check_degree,
    check_finite,
    check_knots,
    check_order,
    check_parameter,
    check_rank,
    check_weights,
    concrete,
    domain_ends,
    float_dtype,
)

# Evaluate points from per-span Taylor coefficients once there are this many parameters per
# span: building the table costs about as much as evaluating this many points directly.
_TABLE_POINTS_PER_SPAN = 32


@typing.final
class NURBSCurve(AbstractRationalSpline):
    """A (rational) B-spline curve `C(u) = sum_i N_{i,p}(u) w_i P_i / sum_i N_{i,p}(u) w_i`.

    Bezier curves are the special case of `degree = len(control_points) - 1` with the
    default knots; `weights=None` gives a non-rational B-spline. All array fields are
    pytree leaves, so `jax.grad` reaches control points, weights and knots.

    Parameters outside the domain raise `ValueError` when they are concrete; under `jit`
    they are clamped to the nearest end of the domain.
    """

    control_points: Float[Array, "n_control dim"]
    weights: Float[Array, " n_control"] | None
    knots: Float[Array, " n_control+p+1"]
    degree: int = eqx.field(static=True)

    def __init__(
        self,
        control_points: ArrayLike,
        degree: int,
        knots: ArrayLike | None = None,
        weights: ArrayLike | None = None,
    ):
        """**Arguments:**

        - `control_points`: array of shape `(n_control, dim)`.
        - `degree`: the degree `p`, `1 <= p < n_control`.
        - `knots`: `n_control + p + 1` non-decreasing knots; None gives clamped uniform
          knots on [0, 1].
        - `weights`: `n_control` positive weights; None gives a non-rational curve.
        """
        self.degree = check_degree(degree)
        points = jnp.asarray(control_points)
        check_rank(points, 2, "control_points", "(n_control, dim)")
        check_control_count(points.shape[0], self.degree)
        dtype = float_dtype(points, *(x for x in (knots, weights) if x is not None))
        self.control_points = check_finite(points.astype(dtype), "control_points")
        if knots is None:
            knots = clamped_knots(points.shape[0], self.degree, dtype=dtype)
        knots = jnp.asarray(knots, dtype=dtype)
        self.knots = check_knots(knots, points.shape[0], self.degree)
        if weights is not None:
            weights = check_weights(jnp.asarray(weights, dtype=dtype), points.shape[:1])
        self.weights = weights

    @property
    def domain(self) -> tuple[Array, Array]:
        """`(knots[p], knots[n_control])`, the parameter interval."""
        return domain_ends(self.knots, self.degree)

    def _from_homogeneous_points(
        self, points: Array, knots: Array, degree: int | None = None
    ) -> "NURBSCurve":
        """A curve of the same kind (and degree, unless given) from homogeneous points."""
        degree = self.degree if degree is None else degree
        if not self.rational:
            return NURBSCurve(points, degree, knots)
        return NURBSCurve(from_homogeneous(points), degree, knots, points[:, -1])

    def insert_knot(self, u: ArrayLike, times: int = 1) -> "NURBSCurve":
        """The same curve with the knot `u` inserted `times` times (the control points of
        Boehm's NURBS Book A5.1, computed at once; see `_knotops.insert`).

        The knot may end with multiplicity at most the degree. Works with a traced `u`
        (checks then skipped), so it can sit inside a loss function.
        """
        homogeneous = self.homogeneous_points()
        points, knots = checked_insertion(homogeneous, self.knots, self.degree, u, times)
        return self._from_homogeneous_points(points, knots)

    def refine(self, values: ArrayLike) -> "NURBSCurve":
        """The same curve with every knot of `values` inserted (knot refinement, one
        vectorised pass; see `_knotops.insert`). Values may be traced (checks then skipped)."""
        homogeneous = self.homogeneous_points()
        points, knots = checked_refinement(homogeneous, self.knots, self.degree, values)
        return self._from_homogeneous_points(points, knots)

    def remove_knot(
        self, u: float, times: int = 1, tol: float | None = None
    ) -> tuple["NURBSCurve", int]:
        """The curve with the interior knot `u` removed up to `times` times, as often as the
        curve moves by at most `tol` (NURBS Book A5.8): the inverse of `insert_knot`.

        **Arguments:**

        - `u`: an interior knot.
        - `times`: how many copies to try to remove (at most its multiplicity).
        - `tol`: how far the curve may move; None: `1e-12 (1 + max |P|)`, only exact
          removal (a knot that insertion added); `inf`: remove `times` copies whatever
          the change (then the control points may be traced, and `jax.grad` reaches them).

        **Returns:**

        `(curve, removed)`: the new curve and how many copies were removed.
        """
        knots = concrete(self.knots)
        if knots is None:
            raise ValueError("remove_knot needs concrete knots: they decide what is removed")
        times = check_degree(times, minimum=1, name="times")
        homogeneous = self.homogeneous_points()
        if tol is None:
            values = concrete(self.control_points)
            if values is None:
                raise ValueError("remove_knot needs concrete control points unless tol = inf")
            tol = 1e-12 * (1 + float(np.max(np.abs(values))))
        tol = check_tolerance(tol)
        if np.isfinite(tol):
            values = concrete(homogeneous)
            if values is None:
                raise ValueError("remove_knot with a finite tol needs concrete control points")
            tol = homogeneous_tolerance(values, self.rational, tol)
        rows, new_knots, removed, _ = remove(
            list(homogeneous), knots, self.degree, float(u), times, tol
        )
        if removed == 0:
            return self, 0
        return self._from_homogeneous_points(jnp.stack(rows), jnp.asarray(new_knots)), removed

    def simplify(self, tol: float) -> "NURBSCurve":
        """The curve with every knot removed that can go while the curve stays within `tol`
        of this one (the bound of each removal summed per span; see `_knotremoval`).

        **Arguments:**

        - `tol`: how far the simplified curve may be from this one, `> 0`.

        **Returns:**

        The simplified `NURBSCurve` (the same degree; concrete control points and knots).
        """
        knots, points = concrete(self.knots), concrete(self.homogeneous_points())
        if knots is None or points is None:
            raise ValueError("simplify needs a concrete curve (not traced)")
        points, knots = simplify(points, knots, self.degree, self.rational, check_tolerance(tol))
        return self._from_homogeneous_points(jnp.asarray(points), jnp.asarray(knots))

    def reduce_degree(self, tol: float | None = None) -> "NURBSCurve":
        """The curve of one degree less within `tol` of this one: the inverse of
        `elevate_degree` (see `_knotremoval.reduce`; concrete curve, clamped knots).

        **Arguments:**

        - `tol`: how far the reduced curve may be; None: `1e-12 (1 + max |P|)`, only exact
          reduction (a curve that degree elevation made).

        **Returns:**

        The `NURBSCurve` of degree `p - 1`, its knots as few as `tol` allows. Raises
        `ValueError` when no curve of degree `p - 1` is within `tol`.
        """
        if self.degree < 2:
            raise ValueError("reduce_degree needs degree >= 2: there is no degree 0 curve")
        knots, points = concrete(self.knots), concrete(self.homogeneous_points())
        if knots is None or points is None:
            raise ValueError("reduce_degree needs a concrete curve (not traced)")
        if tol is None:
            tol = 1e-12 * (1 + float(np.max(np.abs(concrete(self.control_points)))))
        tol = check_tolerance(tol)
        points, knots, error = reduce(points, knots, self.degree, self.rational, tol)
        points, knots = simplify(points, knots, self.degree - 1, self.rational, tol, error)
        return self._from_homogeneous_points(
            jnp.asarray(points), jnp.asarray(knots), self.degree - 1
        )

    def elevate_degree(self, times: int = 1) -> "NURBSCurve":
        """The same curve with its degree raised by `times`: every knot of the domain
        `times` more often, unclamped knots clamped first.

        Exact up to rounding; needs concrete knots (see `_knotops.elevate`).
        """
        times = check_degree(times, minimum=1, name="times")
        points, knots = elevate(self.homogeneous_points(), self.knots, self.degree, times)
        return self._from_homogeneous_points(points, knots, self.degree + times)

    def decompose(self) -> list["NURBSCurve"]:
        """The Bezier pieces of the curve, one per non-empty knot span (clamped, concrete knots)."""
        pieces = bezier_pieces(self.homogeneous_points(), self.knots, self.degree)
        return [self._from_homogeneous_points(piece, knots) for piece, knots in pieces]

    def _parameters(self, u: ArrayLike) -> Array:
        """Parameters as an array; concrete ones outside the domain raise `ValueError`."""
        u = jnp.asarray(u, dtype=self.knots.dtype)
        check_parameter(u, *self.domain)
        return u

    def _clamp(self, u: Array) -> Array:
        return clamp_to_domain(u, *self.domain)

    def __call__(self, u: ArrayLike) -> Float[Array, "... dim"]:
        """Points `C(u)` for parameters of any shape; returns `u.shape + (dim,)`."""
        return self._points(self._parameters(u))

    @eqx.filter_jit
    def _points(self, u: Array) -> Array:
        u = self._clamp(u)
        n_spans = self.knots.shape[0] - 2 * self.degree - 1
        if u.size >= _TABLE_POINTS_PER_SPAN * n_spans:
            columns = self._horner_columns(u)[0]
            if self.rational:
                reciprocal = 1 / columns[-1]  # one division per point, not one per coordinate
                columns = [column * reciprocal for column in columns[:-1]]
            return jnp.stack(columns, axis=-1)
        span, funs = basis_funs(self.knots, self.degree, u)
        points = combine_local(funs, self.homogeneous_points(), span, self.degree)
        return from_homogeneous(points) if self.rational else points

    def _horner_columns(self, u: Array, order: int = 0) -> list[list[Array]]:
        """`columns[k][d]`: coordinate `d` of the homogeneous `k`-th derivative, by Horner's
        rule on Taylor coefficients.

        On span `i` the curve is the polynomial `sum_j C^(j)(u_i) (u - u_i)^j / j!`, and its
        `k`-th derivative `sum_j C^(j + k)(u_i) (u - u_i)^j / j!`; the values `C^(j)(u_i)`
        come from `span_derivatives` at the span starts (one call for all spans), so every
        point costs a span search and `p - k` multiply-adds per coordinate, with no division.
        Coordinates are kept as separate arrays because XLA fuses each output element
        with everything it depends on: a stacked `(..., dim)` result would redo the
        span search and the other coordinates' work for every coordinate.
        """
        p = self.degree
        # Every span's polynomial at its first knot (empty spans give unused rows).
        spans = jnp.arange(p, self.knots.shape[0] - p - 1)
        starts = self.knots[p : -p - 1]
        ders = span_derivatives(self.knots, p, self.homogeneous_points(), spans, starts, p)
        values = jnp.stack(ders, axis=1)  # C^(j)(u_i)
        span = find_span(self.knots, p, u)
        row, t = span - p, u - self.knots[span]
        # 1 / j! as a factor: the table is computed once per span, not once per point.
        inverse = jnp.asarray([1 / math.factorial(j) for j in range(p + 1)], dtype=values.dtype)
        columns = []
        for k in range(min(order, p) + 1):
            table = values[:, k:, :] * inverse[: p + 1 - k, None]
            column = []
            for d in range(values.shape[-1]):
                value = table[:, p - k, d][row]
                for j in range(p - k - 1, -1, -1):
                    value = value * t + table[:, j, d][row]
                column.append(value)
            columns.append(column)
        zeros = [jnp.zeros_like(u)] * values.shape[-1]
        return columns + [zeros] * (order - min(order, p))

    def derivatives(self, u: ArrayLike, order: int) -> Float[Array, "... order+1 dim"]:
        """`C(u), C'(u), ..., C^(order)(u)`: CurveDerivs, then the Leibniz rule if rational
        (from per-span Taylor tables when there are many parameters per span, as for points).

        **Arguments:**

        - `u`: parameters, any shape.
        - `order`: highest derivative order, `>= 0`.

        **Returns:**

        Array of shape `u.shape + (order + 1, dim)`.
        """
        return self._derivatives(self._parameters(u), check_order(order))

    @eqx.filter_jit
    def _derivatives(self, u: Array, order: int) -> Array:
        u = self._clamp(u)
        n_spans = self.knots.shape[0] - 2 * self.degree - 1
        if u.size >= _TABLE_POINTS_PER_SPAN * n_spans:
            columns = self._horner_columns(u, order)
            if self.rational:
                columns = rational_columns(
                    [row[:-1] for row in columns], [row[-1] for row in columns]
                )
            return jnp.stack([jnp.stack(row, axis=-1) for row in columns], axis=-2)
        span, ders = ders_basis_funs(self.knots, self.degree, u, order)
        homogeneous = combine_local(ders, self.homogeneous_points(), span, self.degree)
        if not self.rational:
            return homogeneous
        return rational_curve_derivatives(homogeneous[..., :-1], homogeneous[..., -1])

    def tangent(self, u: ArrayLike) -> Float[Array, "... dim"]:
        """Unit tangent `C'(u) / |C'(u)|`; zero where the curve has zero speed."""
        return self._tangent(self._parameters(u))

    @eqx.filter_jit
    def _tangent(self, u: Array) -> Array:
        return safe_normalize(self._derivatives(u, 1)[..., 1, :])

    def curvature(self, u: ArrayLike) -> Float[Array, "..."]:
        """Curvature: signed `(x'y'' - y'x'') / |C'|^3` in 2D, `|C' x C''| / |C'|^3` otherwise.

        Zero where the speed is zero. Needs `dim >= 2`.
        """
        if self.dim < 2:
            raise ValueError(f"curvature needs a curve of dimension >= 2, got dim = {self.dim}")
        return self._curvature(self._parameters(u))

    @eqx.filter_jit
    def _curvature(self, u: Array) -> Array:
        ders = self._derivatives(u, 2)
        d1, d2 = ders[..., 1, :], ders[..., 2, :]
        if self.dim == 2:
            bend = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
        elif self.dim == 3:
            bend = safe_norm(jnp.cross(d1, d2))
        else:
            # |d1|^2 |d2|^2 - (d1.d2)^2 = |d1 x d2|^2 in any dimension (Lagrange's identity).
            gram = jnp.sum(d1 * d1, -1) * jnp.sum(d2 * d2, -1) - jnp.sum(d1 * d2, -1) ** 2
            bend = safe_sqrt(gram)
        speed3 = safe_norm(d1) ** 3
        return safe_divide(bend, speed3)

    def arc_length(self, a: ArrayLike | None = None, b: ArrayLike | None = None) -> Array:
        """Length of the curve between parameters `a` and `b` (default: the whole domain).

        Adaptive Gauss-Legendre quadrature starting from the knot spans, on which the
        speed is smooth; panels with a sharp feature are bisected (see `integrate_panels`).
        """
        lower, upper = self.domain
        a = lower if a is None else jnp.asarray(a, dtype=self.knots.dtype)
        b = upper if b is None else jnp.asarray(b, dtype=self.knots.dtype)
        check_parameter(jnp.stack([a, b]), lower, upper, name="(a, b)")
        ends = concrete(jnp.stack([a, b]))
        if ends is not None and ends[0] > ends[1]:
            raise ValueError(f"arc_length needs a <= b, got a = {ends[0]}, b = {ends[1]}")
        return self._length(a, b)

    @eqx.filter_jit
    def _length(self, a: Array, b: Array) -> Array:
        breaks = jnp.clip(self.knots[self.degree : -self.degree], a, b)

        def speed(u):
            return safe_norm(self._derivatives(u, 1)[..., 1, :])

        return integrate_panels(speed, breaks[:-1], breaks[1:])

    @eqx.filter_jit
    def _length_table(self) -> tuple[Array, Array, Array]:
        return length_table(self)

    @eqx.filter_jit
    def _parameter_at_length(self, s: Array, table: tuple[Array, Array, Array]) -> Array:
        return parameter_at_length(self, s, table)

    def parameter_at_length(self, s: ArrayLike) -> Float[Array, "..."]:
        """The parameter `u` at arc length `s` from the start: the inverse of `arc_length`,
        `arc_length(lower, u) = s` to rounding (relative `1e-12` or better).

        The length is tabulated on the quadrature panels of `arc_length` and inverted in its
        panel by safeguarded Newton steps (see `_arclength`). `jax.grad` reaches `s`
        (`du/ds = 1 / |C'(u)|`) and the curve (implicit function theorem).

        **Arguments:**

        - `s`: lengths of any shape, in `[0, L]`, `L` the curve's length; concrete values
          outside raise `ValueError`.

        **Returns:**

        Parameters of the shape of `s`. Where the curve stands still over an interval, the
        first parameter of that interval.
        """
        s = jnp.asarray(s, dtype=self.knots.dtype)
        table = self._length_table()
        check_lengths(s, table[2][-1])
        return self._parameter_at_length(s, table)

    def equal_arc_parameters(self, count: int) -> Float[Array, " count"]:
        """`count` parameters, both ends included, that cut the curve into `count - 1` pieces
        of equal length (constant-feed machining, animation at constant speed).

        **Arguments:**

        - `count`: the number of parameters, `>= 2`.

        **Returns:**

        Increasing parameters from the start to the end of the domain, shape `(count,)`.
        """
        count = check_degree(count, minimum=2, name="count")
        table = self._length_table()
        s = jnp.linspace(0.0, 1.0, count, dtype=self.knots.dtype) * table[2][-1]
        lower, upper = self.domain
        return self._parameter_at_length(s, table).at[0].set(lower).at[-1].set(upper)

    def reparametrize_by_arc_length(self, tol: float = 1e-6) -> "NURBSCurve":
        """A cubic B-spline `R(s)` on `[0, L]` with unit speed within `tol`, tracing this curve.

        `R` interpolates the curve's points and unit tangents at lengths chosen adaptively
        (a C^1 piecewise cubic Hermite curve, double interior knots) until, on every piece,
        `| |R'(s)| - 1 | <= tol` and `|R(s) - C(u(s))| <= tol L`. Needs concrete control
        points, weights and knots (the number of pieces depends on them); the control points
        of the result are differentiable with respect to the curve.

        **Arguments:**

        - `tol`: the bound on both errors, `> 0`.

        **Returns:**

        The unit-speed `NURBSCurve` (non-rational, degree 3).
        """
        if not (isinstance(tol, (int, float)) and tol > 0):
            raise ValueError(f"tol must be a positive number, got {tol!r}")
        if concrete(self.knots) is None or concrete(self.control_points) is None:
            raise ValueError("reparametrize_by_arc_length needs a concrete curve (not traced)")
        return unit_speed_curve(self, tol, self._length_table())

    def closest_point(
        self, point: ArrayLike, samples_per_span: int | None = None
    ) -> Float[Array, "..."]:
        """Point inversion: the parameter `u` of the point `C(u)` nearest to `point`.

        Every query starts from the nearest of a polyline through `samples_per_span`
        times as many points as there are knot spans, spread evenly over the domain, and
        the knots (default `3 (p + 1)`; near-ties, as across the seam of a closed curve,
        start from both candidates), then a projected Newton method on
        `|C(u) - P|^2` converges inside the domain; an end is the answer where the
        distance still falls beyond it. `jax.grad` of the result reaches the points and
        the curve (implicit function theorem). See `_inversion`.

        **Arguments:**

        - `point`: array of shape `(..., dim)`: one point or many.
        - `samples_per_span`: samples per knot span (on average) for the start; raise it
          for curves that wind back and forth within a span.

        **Returns:**

        Parameters of shape `point.shape[:-1]`, in the domain.
        """
        return curve_closest_point(self, point, samples_per_span)
