"""Free-form deformation against Bernstein sums, de Casteljau and exact inverse maps."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import diffnurbs as dn
from diffnurbs._ffd import deform_image, ffd, ffd_lattice

rng = np.random.default_rng(4)
BOX_2D = (np.array([-1.0, 2.0]), np.array([3.0, 2.5]))
BOX_3D = (np.array([0.0, -1.0, 1.0]), np.array([1.0, 2.0, 1.5]))


def _points(box, n):
    low, high = box
    # Points inside the box and up to a quarter of its size outside (extrapolation).
    return low + rng.uniform(-0.25, 1.25, size=(n, len(low))) * (high - low)


def _bernstein(n, i, t):
    return math.comb(n, i) * t**i * (1 - t) ** (n - i)


@pytest.mark.parametrize("box", [BOX_2D, BOX_3D])
def test_undeformed_lattice_is_the_identity(box):
    for _ in range(3):
        degrees = tuple(int(d) for d in rng.integers(1, 5, size=len(box[0])))
        lattice = ffd_lattice(*box, degrees)
        assert lattice.shape == (*(d + 1 for d in degrees), len(degrees))
        points = _points(box, 20).reshape(4, 5, -1)
        np.testing.assert_allclose(ffd(points, lattice, *box), points, atol=1e-12)


def test_lattice_corners_and_spacing():
    lattice = ffd_lattice(*BOX_2D, (2, 3))
    np.testing.assert_allclose(lattice[0, 0], BOX_2D[0])
    np.testing.assert_allclose(lattice[-1, -1], BOX_2D[1])
    np.testing.assert_allclose(lattice[1, 2], [1.0, 2.0 + 0.5 * 2 / 3])


def test_moving_one_lattice_point_moves_points_by_its_bernstein_weight():
    lattice = ffd_lattice(*BOX_3D, (2, 3, 1))
    delta = np.array([0.3, -0.2, 0.5])
    moved = lattice.at[1, 2, 0].add(delta)
    points = _points(BOX_3D, 30)
    s = (points - BOX_3D[0]) / (BOX_3D[1] - BOX_3D[0])
    weight = _bernstein(2, 1, s[:, 0]) * _bernstein(3, 2, s[:, 1]) * _bernstein(1, 0, s[:, 2])
    np.testing.assert_allclose(
        ffd(points, moved, *BOX_3D), points + weight[:, None] * delta, atol=1e-12
    )


def test_ffd_is_the_bezier_surface_and_volume_of_the_lattice():
    lattice_2d = rng.normal(size=(3, 3, 2))  # the seed's biquadratic 3 x 3 grid
    s = rng.uniform(size=(10, 2))
    points = BOX_2D[0] + s * (BOX_2D[1] - BOX_2D[0])
    expected = dn.de_casteljau_surface(lattice_2d, s[:, 0], s[:, 1])
    np.testing.assert_allclose(ffd(points, lattice_2d, *BOX_2D), expected, atol=1e-12)
    lattice_3d = rng.normal(size=(2, 4, 3, 3))
    s = rng.uniform(size=(10, 3))
    points = BOX_3D[0] + s * (BOX_3D[1] - BOX_3D[0])
    expected = dn.de_casteljau_volume(lattice_3d, s[:, 0], s[:, 1], s[:, 2])
    np.testing.assert_allclose(ffd(points, lattice_3d, *BOX_3D), expected, atol=1e-12)


def test_ffd_gradients_match_finite_differences():
    lattice = ffd_lattice(*BOX_2D, (2, 2)) + 0.1 * rng.normal(size=(3, 3, 2))
    points = _points(BOX_2D, 7)

    def loss(lattice, points):
        return jnp.sum(jnp.sin(ffd(points, lattice, *BOX_2D)))

    grad_lattice, grad_points = jax.jit(jax.grad(loss, argnums=(0, 1)))(lattice, points)
    assert np.all(np.isfinite(grad_lattice)) and np.all(np.isfinite(grad_points))
    h = 1e-6
    for grad, argnum, x in ((grad_lattice, 0, lattice), (grad_points, 1, points)):
        direction = rng.normal(size=x.shape)
        args_plus, args_minus = [lattice, points], [lattice, points]
        args_plus[argnum], args_minus[argnum] = x + h * direction, x - h * direction
        fd = (loss(*args_plus) - loss(*args_minus)) / (2 * h)
        np.testing.assert_allclose(np.sum(grad * direction), fd, rtol=1e-6)


def test_ffd_float32():
    with jax.enable_x64(False):
        box = tuple(b.astype(np.float32) for b in BOX_3D)
        lattice = ffd_lattice(*box, (2, 2, 2))
        points = _points(BOX_3D, 5).astype(np.float32)
        out = ffd(points, lattice, *box)
        assert out.dtype == jnp.float32
        np.testing.assert_allclose(out, points, atol=1e-5)


def _coordinate_image(height, width):
    """Two channels holding each pixel's normalised (x, y): bilinear sampling is exact."""
    rows, cols = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    return np.stack([cols / (width - 1), rows / (height - 1)], axis=-1)


def test_deform_image_identity():
    identity = ffd_lattice((0.0, 0.0), (1.0, 1.0), (2, 2))
    gray = rng.uniform(size=(9, 12))
    np.testing.assert_allclose(deform_image(gray, identity), gray, atol=1e-12)
    color = rng.integers(0, 256, size=(7, 5, 3), dtype=np.uint8)
    out = deform_image(color, identity)
    assert out.shape == color.shape and jnp.issubdtype(out.dtype, jnp.floating)
    np.testing.assert_allclose(out, color, atol=1e-9)


def test_deform_image_affine_lattice_is_the_inverse_affine_map():
    # An affine lattice gives the affine map x -> A x + b; the output at p is the source
    # at A^-1 (p - b), exact for the linear coordinate image.
    a, b = np.array([[0.8, 0.1], [-0.05, 0.9]]), np.array([0.1, 0.05])
    lattice = ffd_lattice((0.0, 0.0), (1.0, 1.0), (2, 2)) @ a.T + b
    image = _coordinate_image(11, 13)
    out = deform_image(image, lattice)
    expected = (image - b) @ np.linalg.inv(a).T
    inside = np.all((expected >= 0) & (expected <= 1), axis=-1)
    assert inside.sum() > 50 and (~inside).sum() > 10
    np.testing.assert_allclose(out[inside], expected[inside], atol=1e-12)
    np.testing.assert_array_equal(out[~inside], 0.0)


def test_deform_image_curved_lattice_inverts_the_ffd():
    # Push the middle of the biquadratic grid: the output holds the source coordinates,
    # which ffd must map back onto the output pixel.
    lattice = ffd_lattice((0.0, 0.0), (1.0, 1.0), (2, 2)).at[1, 1].add([0.15, -0.1])
    image = _coordinate_image(15, 17)
    out = deform_image(image, lattice, fill=-1.0)
    found = np.all(out >= 0, axis=-1)
    assert found.mean() > 0.9
    np.testing.assert_allclose(
        ffd(out[found], lattice, (0.0, 0.0), (1.0, 1.0)), image[found], atol=1e-10
    )
    # A smooth gradient of the warped image w.r.t. the lattice.
    grad = jax.grad(lambda lat: jnp.sum(deform_image(image, lat)[..., 0] ** 2))(lattice)
    assert np.all(np.isfinite(grad)) and np.any(grad != 0)


def test_errors():
    lattice = ffd_lattice(*BOX_2D, (2, 2))
    points = _points(BOX_2D, 3)
    with pytest.raises(ValueError, match="box_min must be < box_max on every axis"):
        ffd(points, lattice, BOX_2D[0], [3.0, 2.0])
    with pytest.raises(ValueError, match="box_min must be < box_max"):
        ffd_lattice([0.0, 1.0], [1.0, 1.0], (1, 1))
    with pytest.raises(ValueError, match="same dimension"):
        ffd_lattice([0.0, 0.0], [1.0, 1.0, 1.0], (1, 1))
    with pytest.raises(ValueError, match="the box must have dimension 2"):
        ffd(points, lattice, BOX_3D[0], BOX_3D[1])
    with pytest.raises(ValueError, match=r"points must have shape \(\.\.\., 2\)"):
        ffd(points[:, :1], lattice, *BOX_2D)
    with pytest.raises(ValueError, match="lattice must have shape"):
        ffd(points, lattice[..., :1], *BOX_2D)
    with pytest.raises(ValueError, match="lattice must have shape"):
        ffd(points, np.zeros((2, 2, 2, 2)), *BOX_2D)
    with pytest.raises(ValueError, match="at least p \\+ 1 = 2 lattice points along axis 0"):
        ffd(points, lattice[:1], *BOX_2D)
    with pytest.raises(ValueError, match="lattice must be finite"):
        ffd(points, lattice.at[0, 0, 0].set(np.nan), *BOX_2D)
    with pytest.raises(ValueError, match="degree must be a tuple of 2 ints"):
        ffd_lattice(*BOX_2D, (2, 2, 2))
    with pytest.raises(ValueError, match=r"degree\[1\] must be >= 1"):
        ffd_lattice(*BOX_2D, (2, 0))
    with pytest.raises(ValueError, match="the box must be 2D or 3D"):
        ffd_lattice([0.0], [1.0], (2,))
    with pytest.raises(ValueError, match=r"image must have shape \(H, W\)"):
        deform_image(np.zeros(5), lattice)
    with pytest.raises(ValueError, match="H, W >= 2"):
        deform_image(np.zeros((1, 5)), lattice)
    with pytest.raises(ValueError, match="deform_image needs a 2D lattice"):
        deform_image(np.zeros((4, 4)), ffd_lattice(*BOX_3D, (1, 1, 1)))
    with pytest.raises(ValueError, match="iterations must be >= 1"):
        deform_image(np.zeros((4, 4)), lattice, iterations=0)


def test_box_checked_under_jit():
    lattice = ffd_lattice(*BOX_2D, (1, 1))
    run = jax.jit(lambda high: ffd(_points(BOX_2D, 2), lattice, BOX_2D[0], high))
    run(BOX_2D[1])
    with pytest.raises(Exception, match="box_min must be < box_max"):
        run(np.array([3.0, 1.0]))
