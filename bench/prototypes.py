"""Prototype kernels timed by bench/profile_kernels.py: proposals for src/, unused there.

What limits the current kernels on XLA:CPU (see bench/profile_kernels.py for the measurements):

- XLA emits each fusion as a loop over the output elements and recomputes, for every
  element, everything fused into it. A `(n_points, dim)` output is a concatenation, so
  work shared by the coordinates (span search, basis functions, the weight) is done
  `dim` times; where XLA refuses to fuse instead, each intermediate is written to and
  read back from memory (a pass over 8 MB per million points each).
- `jnp.searchsorted` (method "scan") and the gather of the `(n_points, p + 1, dim)`
  local control points followed by an `einsum` materialise large arrays: 128 MB for a
  million points of a rational curve in 3D.

The prototypes keep every array op of the current code differentiable (no custom calls):

1. `find_span`: the same bisection as a `lax.fori_loop`. The loop is a fusion barrier,
   so the span is computed once and stored, never recomputed inside its consumers.
2. Curves: power-basis (Taylor) coefficients of every span, `T[s, k] = C_w^(k)(U_s) / k!`,
   from A2.3 at the span starts (O(n p^2), once per call), then Horner per point. No
   division per point, `p + 1` gathers per coordinate, derivatives from the same table.
3. Grids: dense `(m, n)` basis matrices (the `p + 1` non-zeros scattered by comparison, no
   gather) and two matrix products (`dot_general`), like splipy's tensor path.
4. Scattered surface points: the current algorithm in chunks of a few thousand points
   (`lax.map`), so the gathered rows stay in cache, with the loop span search.
"""

import math

import jax
import jax.numpy as jnp

import diffnurbs as dn


def find_span(knots, degree: int, u):
    """Largest `i` in `[degree, n]` with `knots[i] <= u`, as `dn.find_span` (u in domain)."""
    last = knots.shape[0] - degree - 2
    lo = jnp.full(jnp.shape(u), degree, dtype=jnp.int32)
    size = last - degree + 1
    steps = math.ceil(math.log2(size)) if size > 1 else 0

    def halve(i, lo):
        mid = lo + jnp.left_shift(1, steps - 1 - i)
        inside = (mid <= last) & (knots[jnp.minimum(mid, last)] <= u)
        return jnp.where(inside, mid, lo)

    return jax.lax.fori_loop(0, steps, halve, lo) if steps else lo


def _clamp(u, knots, degree):
    lower, upper = knots[degree], knots[-degree - 1]
    return jnp.where(u < lower, lower, jnp.where(u > upper, upper, u))


def _safe_divide(num, den):
    zero = den == 0
    return jnp.where(zero, 0.0, num / jnp.where(zero, 1.0, den))


def basis_at(knots, degree: int, span, u):
    """A2.2 for a given span: the list of the `degree + 1` non-zero basis functions."""
    left = [u - knots[span + 1 - j] for j in range(degree + 1)]
    right = [knots[span + j] - u for j in range(degree + 1)]
    funs = [jnp.ones_like(u)]
    for j in range(1, degree + 1):
        saved = jnp.zeros_like(u)
        new = []
        for r in range(j):
            temp = _safe_divide(funs[r], right[r + 1] + left[j - r])
            new.append(saved + right[r + 1] * temp)
            saved = left[j - r] * temp
        funs = [*new, saved]
    return funs


def span_coefficients(curve: dn.NURBSCurve):
    """`T[s, k, d]`: Taylor coefficients of span `degree + s` of the homogeneous curve at its
    left knot, shape `(n_spans, degree + 1, dim [+ 1])`."""
    p, knots = curve.degree, curve.knots
    starts = jnp.arange(p, knots.shape[0] - p - 1)
    span, ders = dn.ders_basis_funs(knots, p, knots[starts], p)  # (S, p+1, p+1)
    local = curve.homogeneous_points()[span[:, None] - p + jnp.arange(p + 1)]
    scale = jnp.array([1 / math.factorial(k) for k in range(p + 1)], dtype=knots.dtype)
    return jnp.einsum("skr,srd->skd", ders, local) * scale[:, None]


def _locate(curve: dn.NURBSCurve, u):
    p, knots = curve.degree, curve.knots
    u = _clamp(jnp.asarray(u, knots.dtype), knots, p)
    span = find_span(knots, p, u)
    return span - p, u - knots[span]


def curve_points(curve: dn.NURBSCurve, u):
    """`curve(u)` by span search + Horner on the span's power-basis coefficients."""
    table = span_coefficients(curve)
    s, t = _locate(curve, u)
    p, dims = curve.degree, table.shape[-1]
    columns = []
    for d in range(dims):
        acc = table[:, p, d][s]
        for k in range(p - 1, -1, -1):
            acc = acc * t + table[:, k, d][s]
        columns.append(acc)
    if curve.rational:
        columns = [c / columns[-1] for c in columns[:-1]]
    return jnp.stack(columns, axis=-1)


def curve_derivatives(curve: dn.NURBSCurve, u, order: int):
    """`curve.derivatives(u, order)` from the same table (derivatives of the polynomials)."""
    table = span_coefficients(curve)
    s, t = _locate(curve, u)
    p, dims = curve.degree, table.shape[-1]
    rows = []
    for k in range(order + 1):
        row = []
        for d in range(dims):
            if k > p:
                row.append(jnp.zeros_like(t))
                continue
            acc = table[:, p, d][s] * (math.factorial(p) // math.factorial(p - k))
            for j in range(p - 1, k - 1, -1):
                acc = acc * t + table[:, j, d][s] * (math.factorial(j) // math.factorial(j - k))
            row.append(acc)
        rows.append(jnp.stack(row, axis=-1))
    homogeneous = jnp.stack(rows, axis=-2)
    if not curve.rational:
        return homogeneous
    return dn.rational_curve_derivatives(homogeneous[..., :-1], homogeneous[..., -1])


def dense_basis(knots, degree: int, n_control: int, u):
    """`(len(u), n_control)` matrix of all basis functions (mostly zeros)."""
    u = _clamp(u, knots, degree)
    span = find_span(knots, degree, u)
    funs = basis_at(knots, degree, span, u)
    index = jnp.arange(n_control)
    first = (span - degree)[:, None]
    return sum(f[:, None] * (index == first + r) for r, f in enumerate(funs))


def surface_grid(surface: dn.NURBSSurface, us, vs):
    """`surface.grid(us, vs)` with dense basis matrices and two matrix products."""
    (p, q), (knots_u, knots_v) = surface.degree, surface.knots
    points = surface.homogeneous_points()
    nu, nv, _ = points.shape
    basis_u = dense_basis(knots_u, p, nu, jnp.asarray(us, knots_u.dtype))
    basis_v = dense_basis(knots_v, q, nv, jnp.asarray(vs, knots_v.dtype))
    rows = jnp.einsum("ia,abd->dib", basis_u, points)  # (dim, mu, nv)
    grid = jnp.einsum("dib,jb->dij", rows, basis_v)  # (dim, mu, mv)
    if surface.rational:
        grid = grid[:-1] / grid[-1:]
    return jnp.moveaxis(grid, 0, -1)


def _surface_block(surface: dn.NURBSSurface, u, v):
    (p, q), (knots_u, knots_v) = surface.degree, surface.knots
    u, v = _clamp(u, knots_u, p), _clamp(v, knots_v, q)
    span_u, span_v = find_span(knots_u, p, u), find_span(knots_v, q, v)
    funs_u = jnp.stack(basis_at(knots_u, p, span_u, u), axis=-1)
    funs_v = jnp.stack(basis_at(knots_v, q, span_v, v), axis=-1)
    points = surface.homogeneous_points()
    nv, dims = points.shape[1], points.shape[2]
    first = (span_u - p) * nv + (span_v - q)
    offsets = (jnp.arange(p + 1)[:, None] * nv + jnp.arange(q + 1)).reshape(-1)
    local = points.reshape(-1, dims)[first[:, None] + offsets]  # (C, (p+1)(q+1), dim)
    weights = (funs_u[:, :, None] * funs_v[:, None, :]).reshape(first.shape[0], -1)
    out = jnp.einsum("ck,ckd->cd", weights, local)
    return out[:, :-1] / out[:, -1:] if surface.rational else out


def surface_points(surface: dn.NURBSSurface, u, v, chunk: int = 2048):
    """`surface(u, v)` for 1-D `u`, `v` of one length, `chunk` points at a time."""
    dtype = surface.knots_u.dtype
    u, v = jnp.asarray(u, dtype), jnp.asarray(v, dtype)
    count = u.shape[0]
    pad = -count % chunk
    u = jnp.pad(u, (0, pad), constant_values=surface.knots_u[0])
    v = jnp.pad(v, (0, pad), constant_values=surface.knots_v[0])
    blocks = jax.lax.map(
        lambda uv: _surface_block(surface, *uv), (u.reshape(-1, chunk), v.reshape(-1, chunk))
    )
    return blocks.reshape(-1, blocks.shape[-1])[:count]
