"""Free-form deformation (FFD) by a Bezier lattice, and warping raster images with it
(seed 002: "FFD on the plane for a raster image with a biquadratic 3 x 3 Bezier grid").

A point `x` in the box `[box_min, box_max]` gets local coordinates
`s = (x - box_min) / (box_max - box_min)` and moves to the tensor-product Bezier map of the
lattice at `s`, `X(s) = sum_ijk B_{i,l}(s_0) B_{j,m}(s_1) B_{k,n}(s_2) P_ijk`. The regular
lattice `P_ijk = box_min + (i / l, j / m, k / n) (box_max - box_min)` gives `X(s) = x`
(linear precision of the Bernstein basis), so moving lattice points deforms space smoothly
from the identity.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.ndimage import map_coordinates
from jaxtyping import Array, ArrayLike, Float

from ._basis import bernstein
from ._validate import check_control_count, check_degree, check_finite, concrete, float_dtype


def _box(box_min, box_max, dim=None):
    """`box_min`, `box_max` as arrays of shape `(dim,)`, checked `box_min < box_max`."""
    low, high = jnp.asarray(box_min), jnp.asarray(box_max)
    dtype = float_dtype(low, high)
    low, high = low.astype(dtype), high.astype(dtype)
    if low.ndim != 1 or low.shape != high.shape:
        raise ValueError(
            f"box_min and box_max must be points of the same dimension, got shapes "
            f"{low.shape} and {high.shape}"
        )
    if dim is not None and low.shape[0] != dim:
        raise ValueError(f"the box must have dimension {dim} (the lattice's), got {low.shape[0]}")
    lo, hi = concrete(low), concrete(high)
    if lo is None or hi is None:
        high = eqx.error_if(high, ~jnp.all(low < high), "box_min must be < box_max")
    elif not np.all(lo < hi):
        axis = int(np.argmax(~(lo < hi)))
        raise ValueError(
            f"box_min must be < box_max on every axis, got {lo[axis]} >= {hi[axis]} on axis {axis}"
        )
    return low, high


def _lattice(lattice):
    lattice = jnp.asarray(lattice)
    lattice = lattice.astype(jnp.result_type(lattice.dtype, float))
    dim = lattice.ndim - 1
    if dim not in (2, 3) or lattice.shape[-1] != dim:
        raise ValueError(
            "lattice must have shape (nu, nv, 2) in 2D or (nu, nv, nw, 3) in "
            f"3D, got {lattice.shape}"
        )
    for axis, count in enumerate(lattice.shape[:-1]):
        # A Bezier lattice's degree along an axis is its count there less one, at least 1.
        check_control_count(count, 1, f"lattice points along axis {axis}")
    return check_finite(lattice, "lattice")


def ffd_lattice(
    box_min: ArrayLike, box_max: ArrayLike, degree: tuple[int, ...]
) -> Float[Array, "... dim"]:
    """The undeformed regular Bezier lattice of a box: `ffd` with it is the identity.

    **Arguments:**

    - `box_min`, `box_max`: opposite corners of the box, shape `(dim,)`, `dim` 2 or 3.
    - `degree`: the Bezier degree along each axis, `dim` ints >= 1 (`(2, 2)` is the
      seed's biquadratic 3 x 3 grid).

    **Returns:**

    Array of shape `(nu, nv, dim)` or `(nu, nv, nw, dim)` (degree plus one points per axis):
    `P[i, j, k] = box_min + (i / l, j / m, k / n) * (box_max - box_min)`.
    """
    low, high = _box(box_min, box_max)
    if not isinstance(degree, (tuple, list)) or len(degree) != low.shape[0]:
        raise ValueError(
            f"degree must be a tuple of {low.shape[0]} ints (one per axis of the box), "
            f"got {degree!r}"
        )
    if low.shape[0] not in (2, 3):
        raise ValueError(f"the box must be 2D or 3D, got dimension {low.shape[0]}")
    degree = [check_degree(d, name=f"degree[{i}]") for i, d in enumerate(degree)]
    steps = [np.arange(d + 1) / d for d in degree]
    unit = np.stack(np.meshgrid(*steps, indexing="ij"), axis=-1)
    return low + jnp.asarray(unit, low.dtype) * (high - low)


def _bezier_map(lattice: Array, s: Array) -> Array:
    """The Bezier map of `lattice` at local coordinates `s` of shape `(N, dim)`.

    Bernstein polynomials extend outside [0, 1] as polynomials, so this extrapolates.
    """
    dim = s.shape[-1]
    q = jnp.einsum("ni,i...->n...", bernstein(lattice.shape[0] - 1, s[:, 0]), lattice)
    for axis in range(1, dim):
        weights = bernstein(lattice.shape[axis] - 1, s[:, axis])
        q = jnp.einsum("ni,ni...->n...", weights, q)
    return q


def ffd(
    points: ArrayLike, lattice: ArrayLike, box_min: ArrayLike, box_max: ArrayLike
) -> Float[Array, "... dim"]:
    """Points moved by the free-form deformation of a Bezier lattice over a box.

    `X(x) = sum B_i(s_0) B_j(s_1) [B_k(s_2)] P_ij[k]` with `s = (x - box_min) /
    (box_max - box_min)`. Points outside the box are not an error: the Bernstein
    polynomials are extended as polynomials, so the deformation extrapolates smoothly
    (and, for the regular lattice, is still the identity). Differentiable in the points,
    the lattice and the box.

    **Arguments:**

    - `points`: array of shape `(..., dim)`, `dim` 2 or 3.
    - `lattice`: control points, shape `(nu, nv, 2)` in 2D or
      `(nu, nv, nw, 3)` in 3D; `ffd_lattice` gives the undeformed one.
    - `box_min`, `box_max`: the box the lattice spans, shape `(dim,)`, `box_min < box_max`.

    **Returns:**

    Array of the shape of `points`.
    """
    lattice = _lattice(lattice)
    dim = lattice.shape[-1]
    low, high = _box(box_min, box_max, dim)
    points = jnp.asarray(points)
    if points.ndim < 1 or points.shape[-1] != dim:
        raise ValueError(
            f"points must have shape (..., {dim}) to match the {dim}D lattice, got {points.shape}"
        )
    dtype = float_dtype(points, lattice, low)
    s = (points.astype(dtype) - low) / (high - low)
    flat = _bezier_map(lattice.astype(dtype), s.reshape(-1, dim))
    return flat.reshape(points.shape)


def deform_image(
    image: ArrayLike, lattice: ArrayLike, iterations: int = 20, fill: float = 0.0
) -> Float[Array, "H W ..."]:
    """Warp a raster image by the 2D FFD of a Bezier lattice (seed 002).

    The lattice lives in normalised image coordinates: a pixel at row `r`, column `c`
    is the point `(x, y) = (c / (W - 1), r / (H - 1))` of the unit square, so
    `ffd_lattice((0, 0), (1, 1), (2, 2))` is the undeformed biquadratic 3 x 3 grid, and
    content at `x` moves to `ffd(x)`.

    Inverse mapping: for every output pixel `p` the source point `x` with `ffd(x) = p`
    is found by `iterations` Newton steps started at `x = p` (2 x 2 Jacobian by forward
    autodiff), and the source is sampled there bilinearly. Unlike forward scattering
    this leaves no holes and stays differentiable in the lattice. Pixels whose Newton
    iteration does not converge (residual above a tenth of a pixel, e.g. where the map
    folds over) or whose source lies outside the image get `fill`. Where the map is not
    one-to-one, the preimage nearest the start is taken.

    **Arguments:**

    - `image`: array of shape `(H, W)` or `(H, W, C)`, `H, W >= 2`; integer images are
      converted to floats.
    - `lattice`: 2D Bezier lattice of shape `(nu, nv, 2)` over the unit square.
    - `iterations`: Newton steps, a Python int >= 1.
    - `fill`: value of pixels without a source.

    **Returns:**

    The warped image, a float array of the shape of `image`.
    """
    image = jnp.asarray(image)
    if image.ndim not in (2, 3) or min(image.shape[:2]) < 2:
        raise ValueError(
            f"image must have shape (H, W) or (H, W, C) with H, W >= 2, got {image.shape}"
        )
    lattice = _lattice(lattice)
    if lattice.shape[-1] != 2:
        raise ValueError(f"deform_image needs a 2D lattice (nu, nv, 2), got {lattice.shape}")
    iterations = check_degree(iterations, name="iterations")
    dtype = float_dtype(image, lattice)
    image, lattice = image.astype(dtype), lattice.astype(dtype)
    return _deform(image, lattice, iterations, jnp.asarray(fill, dtype))


@eqx.filter_jit
def _deform(image: Array, lattice: Array, iterations: int, fill: Array) -> Array:
    height, width = image.shape[:2]
    rows, cols = jnp.meshgrid(
        jnp.arange(height, dtype=image.dtype), jnp.arange(width, dtype=image.dtype), indexing="ij"
    )
    scale = jnp.asarray([width - 1, height - 1], image.dtype)
    targets = jnp.stack([cols, rows], axis=-1).reshape(-1, 2) / scale

    def forward(x):  # one point (2,) -> (2,)
        return _bezier_map(lattice, x[None])[0]

    jacobian = jax.vmap(jax.jacfwd(forward))

    def newton(_, x):
        residual = _bezier_map(lattice, x) - targets
        (a, b), (c, d) = jnp.moveaxis(jacobian(x), (1, 2), (0, 1))
        det = a * d - b * c
        safe = jnp.where(det == 0, 1.0, det)
        # Solve J dx = residual for the 2 x 2 Jacobian; a singular one leaves x alone.
        step = jnp.stack(
            [d * residual[:, 0] - b * residual[:, 1], a * residual[:, 1] - c * residual[:, 0]], -1
        )
        return x - jnp.where((det == 0)[:, None], 0.0, step / safe[:, None])

    sources = jax.lax.fori_loop(0, iterations, newton, targets)
    residual = (_bezier_map(lattice, sources) - targets) * scale  # in pixels
    converged = jnp.all(jnp.abs(residual) < 0.1, axis=-1)
    pixel = sources * scale  # (column, row)
    inside = jnp.all((pixel >= -1e-6) & (pixel <= scale + 1e-6), axis=-1)
    coordinates = [pixel[:, 1], pixel[:, 0]]
    channels = image.reshape(height, width, -1)
    sample = jax.vmap(
        lambda channel: map_coordinates(channel, coordinates, order=1, mode="nearest"),
        in_axes=-1,
        out_axes=-1,
    )
    sampled = sample(channels)
    sampled = jnp.where((converged & inside)[:, None], sampled, fill)
    return sampled.reshape(image.shape)
