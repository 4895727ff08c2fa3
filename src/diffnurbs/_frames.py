"""Moving frames along a space curve and the kinematic sweep (seed 000 §2.4, eq. 2.5-2.9).

A frame is a `(3, 3)` array whose rows are `T, N, B`: the unit tangent and two unit vectors
spanning the normal plane, right-handed (`B = T x N`). The seed's matrix
`A(v) = [i_1 i_2 i_3]` (eq. 2.5) has these vectors as columns, so `A(v) = frame.T`.

The seed fixes only `i_1 = g' / |g'|` and leaves `i_2` as "some vector orthogonal to the
first": two standard choices are offered. The Frenet frame is local but undefined where the
curvature vanishes and flips across inflections; the rotation-minimising frame (RMF) is
continuous and does not twist about the tangent, so swept tubes do not corkscrew.
"""

import typing

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._curve import NURBSCurve
from ._misc import safe_norm, safe_normalize
from ._surface import AbstractSurface, autodiff_partials, autodiff_second_order
from ._validate import check_parameter

FRAME_KINDS = ("rmf", "frenet")

# Steps of the internal RMF table per knot span: the double-reflection method has a global
# error of O(h^4), so 64 steps keep it far below float32 resolution on reasonable paths.
_RMF_STEPS_PER_SPAN = 64


def _check_path(path: NURBSCurve) -> None:
    if path.dim != 3:
        raise ValueError(f"the path must be a curve in 3D, got dim = {path.dim}")


def _check_kind(kind: str) -> str:
    if kind not in FRAME_KINDS:
        raise ValueError(f"unknown frame kind {kind!r}, expected one of {FRAME_KINDS}")
    return kind


def _dot(a: Array, b: Array) -> Array:
    return jnp.sum(a * b, axis=-1, keepdims=True)


def any_normal(t: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """A unit vector normal to the unit vector `t`, chosen deterministically.

    The coordinate axis least aligned with `t` (the first one on ties), with its component
    along `t` removed: it is never parallel to `t`, so the result is well conditioned.
    """
    axis = jnp.eye(3, dtype=t.dtype)[jnp.argmin(jnp.abs(t), axis=-1)]
    return safe_normalize(axis - _dot(axis, t) * t)


def _stack_frame(t: Array, n: Array) -> Array:
    """Rows `T, N, T x N`, with `N` made exactly orthogonal to `T` first."""
    n = safe_normalize(n - _dot(n, t) * t)
    return jnp.stack([t, n, jnp.cross(t, n)], axis=-2)


def _reflect(x: Array, axis: Array, c: Array) -> Array:
    """`x` reflected in the plane normal to `axis` (`c = |axis|^2`); unchanged if `c == 0`."""
    safe = jnp.where(c == 0, 1.0, c)
    return jnp.where(c == 0, x, x - (2 / safe) * _dot(axis, x) * axis)


def double_reflection(x0: Array, t0: Array, r0: Array, x1: Array, t1: Array) -> Array:
    """One step of the double-reflection method (Wang, Juttler, Zheng, Liu 2008, Alg. 1).

    Reflecting in the bisector plane of `x0, x1` carries the frame at `x0` to `x1`; a
    second reflection, in the plane that swaps the reflected tangent with `t1`, aligns
    the tangents. Two reflections make a rotation, so the
    reference vector `r0` stays a unit normal; the step is exact for circular arcs.

    **Arguments:**

    - `x0`, `t0`, `r0`: point, unit tangent and unit normal at the start of the step.
    - `x1`, `t1`: point and unit tangent at the end.

    **Returns:**

    The normal `r1` at `x1`. A step of zero length (or with equal tangents) leaves `r0`;
    a step of about rounding size turns `r0` about `t0 x t1` instead.
    """
    v1 = x1 - x0
    c1 = _dot(v1, v1)
    r_left = _reflect(r0, v1, c1)
    t_left = _reflect(t0, v1, c1)
    v2 = t1 - t_left
    reflected = _reflect(r_left, v2, _dot(v2, v2))
    # A step near rounding size (a query at a table sample) has a bisector plane made of
    # noise: the error is ~eps |x| / |x1 - x0|. There, turn r0 by the smallest rotation
    # taking t0 to t1 (about t0 x t1; well conditioned as t0 ~ t1), which errs by a higher
    # power of the step; switch below eps^(1/3) |x|.
    tol = jnp.finfo(x0.dtype).eps ** (2 / 3)
    short = c1 <= tol * (_dot(x0, x0) + _dot(x1, x1))
    den = 1 + _dot(t0, t1)
    safe = jnp.where(den > 0, den, 1.0)
    turned = r0 - jnp.where(den > 0, _dot(r0, t1) / safe, 0.0) * (t0 + t1)
    return jnp.where(short, turned, reflected)


@eqx.filter_jit
def _frenet(path: NURBSCurve, v: Array) -> Array:
    ders = path.derivatives(v, 2)
    d1, d2 = ders[..., 1, :], ders[..., 2, :]
    t = safe_normalize(d1)
    bend = jnp.cross(d1, d2)
    # Relative test: |C' x C''| = |C'| |C''| sin(angle), so this asks for an angle between
    # first and second derivative above ~1e-7 (float64) rather than an absolute size.
    tol = jnp.sqrt(jnp.finfo(d1.dtype).eps) * safe_norm(d1) * safe_norm(d2)
    curved = (safe_norm(bend) > tol)[..., None]
    b = jnp.where(curved, safe_normalize(bend), jnp.cross(t, any_normal(t)))
    return jnp.stack([t, jnp.cross(b, t), b], axis=-2)


def rmf_table(path: NURBSCurve) -> tuple[Array, Array, Array, Array]:
    """The rotation-minimising frame on a fixed fine sample of the path's domain.

    `_RMF_STEPS_PER_SPAN` equal steps in every knot span (empty spans give repeated
    samples, which the zero-length step leaves alone), propagated with `lax.scan` from
    `N(v_min) = any_normal(T(v_min))`.

    **Returns:**

    `(params, points, tangents, normals)`, sorted by parameter, the first of shape `(m,)`
    and the others `(m, 3)` with `m = steps * n_spans + 1`.
    """
    p = path.degree
    dtype = path.knots.dtype
    breaks = path.knots[p : path.knots.shape[0] - p]
    fractions = jnp.arange(_RMF_STEPS_PER_SPAN, dtype=dtype) / _RMF_STEPS_PER_SPAN
    inner = breaks[:-1, None] + (breaks[1:] - breaks[:-1])[:, None] * fractions
    params = jnp.concatenate([inner.ravel(), breaks[-1:]])
    ders = path.derivatives(params, 1)
    points, tangents = ders[:, 0, :], safe_normalize(ders[:, 1, :])
    start = any_normal(tangents[0])

    def step(r0, pair):
        (x0, t0), (x1, t1) = pair
        r1 = double_reflection(x0, t0, r0, x1, t1)
        return r1, r1

    pairs = ((points[:-1], tangents[:-1]), (points[1:], tangents[1:]))
    _, rest = jax.lax.scan(step, start, pairs)
    return params, points, tangents, jnp.concatenate([start[None], rest])


@eqx.filter_jit
def _rmf(path: NURBSCurve, v: Array) -> Array:
    return _rmf_from(rmf_table(path), path, v)


def _rmf_from(table, path: NURBSCurve, v: Array) -> Array:
    """The RMF at `v`: one double reflection from the sample of `table` just below `v`."""
    params, points, tangents, normals = table
    below = jnp.clip(jnp.searchsorted(params, v, side="right") - 1, 0, params.shape[0] - 1)
    ders = path.derivatives(v, 1)
    x, t = ders[..., 0, :], safe_normalize(ders[..., 1, :])
    r = double_reflection(points[below], tangents[below], normals[below], x, t)
    return _stack_frame(t, r)


def frames(path: NURBSCurve, v: ArrayLike, frame: str = "rmf") -> Float[Array, "... 3 3"]:
    """Moving frames along a space curve: rows `T, N, B`, right-handed.

    - `frame="frenet"`: `T = C'/|C'|`, `B = C' x C'' / |C' x C''|`, `N = B x T`. Where
      `C' x C''` vanishes (straight pieces, inflections: the Frenet frame is undefined
      there) the fallback is `N = any_normal(T)`, the axis least aligned with `T` made
      normal to it, so the result is NaN-free but may jump. The Frenet normal points to
      the centre of curvature, so it reverses across an inflection.
    - `frame="rmf"`: the rotation-minimising frame, `N' . B = 0` (no twist about `T`),
      started from `N(v_min) = any_normal(T(v_min))` and carried by the double-reflection
      method over a fixed table of 64 steps per knot span; each requested `v` takes one
      more double reflection from the table sample just below it, so any `v` array (in any
      order) gives the same frames.

    Where the path has zero speed `T` is zero and the frame is degenerate (no NaN).

    **Arguments:**

    - `path`: a `NURBSCurve` in 3D.
    - `v`: parameters in the path's domain, any shape.
    - `frame`: `"rmf"` (default) or `"frenet"`.

    **Returns:**

    Array of shape `v.shape + (3, 3)`; `frames[..., 0, :]` is `T`, `[..., 1, :]` is `N`,
    `[..., 2, :]` is `B`.
    """
    _check_path(path)
    _check_kind(frame)
    v = jnp.asarray(v, dtype=path.knots.dtype)
    check_parameter(v, *path.domain, "v")
    if frame == "frenet":
        return _frenet(path, v)
    return _rmf(path, v)


@typing.final
class KinematicSweep(AbstractSurface):
    """The surface traced by a profile carried rigidly by a moving frame (seed eq. 2.8).

    `S(u, v) = g(v) + A(v) X(u)`, where `A(v) = frames(path, v).T` and `X(u)` is the profile
    in the frame at the start of the path:

    - 3D profile (the seed's convention, eq. 2.6): the profile is given in world
      coordinates where it sits at `v_min`, `X(u) = A^{-1}(v_min) (C(u) - g(v_min))`, so
      `S(u, v_min) = C(u)` and `S = g(v) + M(v) (C(u) - g(v_min))` with
      `M(v) = A(v) A^{-1}(v_min)` (eq. 2.8-2.9). `A` is orthogonal, so `A^{-1} = A^T`.
      With the RMF the surface does not depend on the choice of `N(v_min)`.
    - 2D profile: `(x, y)` are coordinates in the normal plane,
      `S = g(v) + x N(v) + y B(v)`; the profile's origin rides on the path.

    Not a NURBS surface in general (the frame is not rational in `v`): the surface is
    evaluated pointwise. Figure 2.8 of the seed is captioned "surface of translation"
    (поверхность сдвига), but it shows this kinematic surface.
    """

    profile: NURBSCurve
    path: NURBSCurve
    frame: str = eqx.field(static=True)

    def __init__(self, profile: NURBSCurve, path: NURBSCurve, frame: str = "rmf"):
        """**Arguments:**

        - `profile`: the curve `C(u)` carried along, in 2D or 3D (see the class docstring).
        - `path`: the guide curve `g(v)`, in 3D.
        - `frame`: `"rmf"` (default) or `"frenet"`, as in `frames`.
        """
        _check_path(path)
        if profile.dim not in (2, 3):
            raise ValueError(f"the profile must be a curve in 2D or 3D, got dim = {profile.dim}")
        self.profile = profile
        self.path = path
        self.frame = _check_kind(frame)

    def _table(self):
        """The RMF table of the path (None for Frenet frames), computed once per
        evaluation and shared by every frame it needs: kept outside the autodiff of the
        partials, the table's loop is traced once, not once per order."""
        return rmf_table(self.path) if self.frame == "rmf" else None

    def _frames(self, v: Array, table) -> Array:
        if table is None:
            return _frenet(self.path, v)
        return _rmf_from(table, self.path, v)

    def _local(self, u: Array, table) -> Array:
        """Profile points as coordinates along `(T, N, B)` of the frame at `v_min`."""
        points = self.profile(u)
        if self.profile.dim == 2:
            return jnp.concatenate([jnp.zeros_like(points[..., :1]), points], axis=-1)
        v_min = self.path.domain[0]
        start = self._frames(v_min, table)
        return (points - self.path(v_min)) @ start.T  # rows of A^T (C - g): X per point

    @property
    def domain(self) -> tuple[tuple[Array, Array], tuple[Array, Array]]:
        """`(profile.domain, path.domain)`."""
        return self.profile.domain, self.path.domain

    @property
    def dim(self) -> int:
        return 3

    def _evaluate(self, u: Array, v: Array, table) -> Array:
        local = self._local(u, table)
        frame = self._frames(v, table)
        return self.path(v) + jnp.einsum("...k,...kd->...d", local, frame)

    @eqx.filter_jit
    def _points(self, u: Array, v: Array) -> Array:
        return self._evaluate(u, v, self._table())

    @eqx.filter_jit
    def _grid(self, us: Array, vs: Array) -> Array:
        # The profile and the frames are evaluated once per u and once per v.
        table = self._table()
        local = self._local(us, table)
        frame = self._frames(vs, table)
        return self.path(vs)[None] + jnp.einsum("ik,jkd->ijd", local, frame)

    @eqx.filter_jit
    def _derivatives(self, u: Array, v: Array, order: int) -> Array:
        table = self._table()
        return autodiff_partials(lambda u, v: self._evaluate(u, v, table), u, v, order)

    def _second_order(self, u: Array, v: Array) -> tuple[Array, Array, Array]:
        table = self._table()
        return autodiff_second_order(lambda u, v: self._evaluate(u, v, table), u, v)

    def _sampling(self):
        p, q = self.profile.degree, self.path.degree
        return (self.profile.knots[p:-p], p + 2), (self.path.knots[q:-q], q + 2)
