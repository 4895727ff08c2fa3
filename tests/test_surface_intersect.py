"""`curve_surface_intersections` and `surface_intersections`.

Oracles: exact geometry (a line and a tangent line on a sphere, a plane cutting a sphere in
a circle, two cylinders crossing, the Villarceau circles of a torus), dense brute force
(sign changes of a height-field distance along a fine sampling, refined by bisection) on
random curves and patches, and central finite differences for the gradients.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial import cKDTree

import diffnurbs as dn


def profile_3d(arc, azimuth):
    """A planar arc `(rho, z)` placed in the half-plane at `azimuth` about the z axis."""
    p = np.asarray(arc.control_points)
    points = np.stack([p[:, 0] * math.cos(azimuth), p[:, 0] * math.sin(azimuth), p[:, 1]], 1)
    return dn.NURBSCurve(points, 2, arc.knots, arc.weights)


def sphere(radius=1.0, azimuth=0.7):
    """Exact sphere about the origin; its seam at `azimuth`, away from the test geometry."""
    meridian = profile_3d(dn.arc(radius, -math.pi / 2, math.pi / 2), azimuth)
    return dn.revolve(meridian, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))


def cylinder(radius, axis, seam, half_length=2.0):
    """Exact cylinder about the z (axis="z") or the y axis (axis="y"), seam at angle `seam`."""
    ring = dn.arc(radius, seam, seam + 2 * math.pi, center=(0.0, 0.0, -half_length))
    surface = dn.extrude(ring, (0.0, 0.0, 1.0), 2 * half_length)
    if axis == "z":
        return surface
    points = np.asarray(surface.control_points)[..., [0, 2, 1]]  # (x, y, z) -> (x, z, y)
    return dn.NURBSSurface(points, surface.degree, surface.knots, surface.weights)


def plane(origin, a, b):
    """The bilinear patch `origin + s a + t b`, `s, t` in [-1, 1]."""
    origin, a, b = (np.asarray(x, dtype=float) for x in (origin, a, b))
    corners = [[origin - a - b, origin - a + b], [origin + a - b, origin + a + b]]
    return dn.NURBSSurface(np.array(corners), (1, 1))


def samples(branches, count=4001):
    return [np.asarray(b.curve(np.linspace(0.0, 1.0, count))) for b in branches]


def check_fit(branches, s1, s2, tol):
    """Each branch's curve agrees with both surfaces on its parameter curves, within tol."""
    w = np.linspace(0.0, 1.0, 1001)
    for branch in branches:
        x = np.asarray(branch.curve(w))
        for surface, uv in ((s1, branch.uv1), (s2, branch.uv2)):
            params = np.asarray(uv(w))
            (u0, u1), (v0, v1) = (np.asarray(d) for d in surface.domain)
            on = np.asarray(surface(np.clip(params[:, 0], u0, u1), np.clip(params[:, 1], v0, v1)))
            assert np.abs(on - x).max() <= tol, np.abs(on - x).max()
            # The ends lie in the domain as they are (a branch ending on a boundary must not
            # come out beyond it by rounding): the surface evaluates there without a clip.
            ends = params[[0, -1]]
            np.testing.assert_allclose(surface(ends[:, 0], ends[:, 1]), x[[0, -1]], atol=tol)


def distance_to_polylines(points, lines):
    """Distance of each point to the nearest of dense polylines (nearest vertex, then its
    two segments)."""
    best = np.full(len(points), np.inf)
    for line in lines:
        _, k = cKDTree(line).query(points)
        for a, b in ((np.maximum(k - 1, 0), k), (k, np.minimum(k + 1, len(line) - 1))):
            d = line[b] - line[a]
            length2 = np.maximum(np.sum(d * d, axis=1), 1e-300)
            along = np.clip(np.sum((points - line[a]) * d, axis=1) / length2, 0, 1)
            best = np.minimum(best, np.linalg.norm(line[a] + along[:, None] * d - points, axis=1))
    return best


SPHERE = sphere()
LINE = dn.NURBSCurve(np.array([[-2.0, 0.3, 0.2], [2.0, 0.1, 0.4]]), 1)


def test_a_line_meets_the_sphere_where_the_geometry_says():
    u, s, t = dn.curve_surface_intersections(LINE, SPHERE)
    points = np.asarray(LINE(u))
    assert points.shape == (2, 3)
    np.testing.assert_allclose(np.linalg.norm(points, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(SPHERE(s, t)), points, atol=1e-12)
    # Brute force: sign changes of |C(u)| - 1 on a fine sampling, and the nearest point
    # of a dense grid on the sphere.
    grid = np.linspace(0.0, 1.0, 20001)
    inside = np.linalg.norm(np.asarray(LINE(grid)), axis=1) - 1.0
    changes = grid[np.flatnonzero(np.diff(np.sign(inside)))]
    np.testing.assert_allclose(u, changes, atol=1e-4)
    us = np.linspace(0.0, 1.0, 801)
    dense = np.asarray(SPHERE.grid(us, us))
    for point, s_k, t_k in zip(points, np.asarray(s), np.asarray(t), strict=True):
        i, j = np.unravel_index(np.argmin(np.linalg.norm(dense - point, axis=-1)), dense.shape[:2])
        assert abs(us[i] - s_k) < 3e-3 and abs(us[j] - t_k) < 3e-3


def test_tangent_lines_touch_the_sphere_once():
    # Lines tangent at the pole (where the patches degenerate), at (0, -0.8, 0.6), and at
    # random points.
    rng = np.random.default_rng(0)
    normals = [np.array([0.0, 0.0, 1.0]), np.array([0.0, -0.8, 0.6])]
    normals += [n / np.linalg.norm(n) for n in rng.normal(size=(2, 3))]
    for normal in normals:
        along = np.cross(normal, rng.normal(size=3))
        along /= np.linalg.norm(along)
        tangent = dn.NURBSCurve(np.array([normal - 2 * along, normal + 2 * along]), 1)
        u, s, t, overlaps = dn.curve_surface_intersections(tangent, SPHERE, full_output=True)
        assert u.shape == (1,) and overlaps == [], (normal, u, overlaps)
        # A double root: the contact is known to about the square root of the rounding
        # (1e-8); the bound leaves a factor of ten.
        np.testing.assert_allclose(np.asarray(tangent(u))[0], normal, atol=1e-6)
        np.testing.assert_allclose(np.asarray(SPHERE(s, t))[0], normal, atol=1e-6)


def test_a_curve_lying_on_the_sphere_is_an_overlap():
    ring = dn.arc(0.8, 0.2, 2.0, center=(0.0, 0.0, 0.6))  # on the sphere: z = 0.6, rho = 0.8
    end = np.asarray(ring.control_points)[-1]
    # Then a C0 straight piece out through the sphere's outside.
    points = np.concatenate([np.asarray(ring.control_points), [1.5 * end, 2.0 * end]])
    knots = np.concatenate([np.asarray(ring.knots)[:-1] * (2 / 3), [1.0, 1.0, 1.0]])
    weights = np.concatenate([np.asarray(ring.weights), [1.0, 1.0]])
    curve = dn.NURBSCurve(points, 2, knots, weights)
    u, _, _, overlaps = dn.curve_surface_intersections(curve, SPHERE, full_output=True)
    assert len(u) == 0 and len(overlaps) == 1, (u, overlaps)
    np.testing.assert_allclose(overlaps[0], (0.0, 2 / 3), atol=1e-3)


def height_field(rng, shape, low, high):
    """A bicubic B-spline surface `(x, y, f(x, y))` on [0, 1]^2: control points at the
    Greville abscissae (linear precision: the first two coordinates are the parameters)."""
    surface = dn.NURBSSurface(np.zeros((*shape, 3)), (3, 3))
    xs = [np.convolve(np.asarray(k), np.ones(3) / 3, "valid")[1:-1] for k in surface.knots]
    x, y = np.meshgrid(*xs, indexing="ij")
    heights = rng.uniform(low, high, shape)
    return dn.NURBSSurface(np.stack([x, y, heights], axis=-1), (3, 3))


@pytest.mark.parametrize("seed", [0, 1])
def test_random_curve_and_bicubic_surface_against_a_dense_brute_force(seed):
    rng = np.random.default_rng(seed)
    surface = height_field(rng, (5, 5), 0.3, 0.7)
    points = np.concatenate(
        [rng.uniform(0.05, 0.95, (8, 2)), rng.uniform(0.0, 1.0, (8, 1))], axis=1
    )
    curve = dn.NURBSCurve(points, 3, weights=rng.uniform(0.5, 2.0, 8))
    u, s, t = dn.curve_surface_intersections(curve, surface)
    assert np.abs(np.asarray(curve(u)) - np.asarray(surface(s, t))).max(initial=0) < 1e-13
    # Brute force: the curve's height above the surface changes sign at each crossing.
    grid = np.linspace(0.0, 1.0, 40001)
    x = np.asarray(curve(grid))
    above = x[:, 2] - np.asarray(surface(x[:, 0], x[:, 1]))[:, 2]
    changes = grid[np.flatnonzero(np.diff(np.sign(above)))]
    assert len(changes) >= 2
    assert len(u) == len(changes), (np.asarray(u), changes)
    np.testing.assert_allclose(u, changes, atol=1e-4)


def test_gradients_by_the_implicit_function_theorem():
    line_points = jnp.asarray(LINE.control_points)
    weights = jnp.asarray(SPHERE.weights)
    start = dn.curve_surface_intersections(LINE, SPHERE)

    def first_point(points, weights, start=None):
        line = dn.NURBSCurve(points, 1)
        surface = dn.NURBSSurface(SPHERE.control_points, SPHERE.degree, SPHERE.knots, weights)
        u, _, _ = dn.curve_surface_intersections(line, surface, start=start)
        return line(u)[0] @ jnp.array([1.0, 2.0, -1.0])

    grads = jax.grad(first_point, argnums=(0, 1))(line_points, weights, start)
    rng, step = np.random.default_rng(3), 1e-6
    for k, value in enumerate((line_points, weights)):
        direction = rng.normal(size=value.shape)
        shifted = [list((line_points, weights)) for _ in range(2)]
        shifted[0][k] = value + step * direction
        shifted[1][k] = value - step * direction
        central = (first_point(*shifted[0]) - first_point(*shifted[1])) / (2 * step)
        assert np.isclose(np.sum(grads[k] * direction), central, rtol=1e-6, atol=1e-9)


def test_a_plane_cuts_the_sphere_in_a_closed_circle():
    cut = plane((-0.5, 0.0, 0.0), (0.0, 2.0, 0.0), (0.0, 0.0, 2.0))
    branches = dn.surface_intersections(cut, SPHERE)
    tol = 1e-7 * (1 + 4 * math.sqrt(2))  # the default: 1e-7 (1 + size)
    assert len(branches) == 1 and branches[0].closed
    assert branches[0].ends_singular == (False, False)
    (x,) = samples(branches)
    radius = np.linalg.norm(x[:, 1:], axis=1)
    off = np.hypot(x[:, 0] + 0.5, radius - math.sqrt(0.75))  # distance to the exact circle
    assert off.max() <= tol, off.max()
    angles = np.linspace(0.0, 2 * math.pi, 500)
    exact = np.stack(
        [np.full(500, -0.5), math.sqrt(0.75) * np.cos(angles), math.sqrt(0.75) * np.sin(angles)],
        axis=1,
    )
    assert distance_to_polylines(exact, [x]).max() <= tol  # the whole circle is covered
    check_fit(branches, cut, SPHERE, tol)


def test_cylinders_of_different_radii_crossing():
    wide, narrow = cylinder(1.0, "z", 0.0), cylinder(0.6, "y", 0.3)
    branches = dn.surface_intersections(wide, narrow)
    tol = 1e-7 * (1 + math.sqrt(4 + 16 + 4))
    assert len(branches) == 2, len(branches)
    assert all(b.closed and b.ends_singular == (False, False) for b in branches)
    for x in samples(branches):
        assert np.abs(np.hypot(x[:, 0], x[:, 1]) - 1.0).max() <= tol
        assert np.abs(np.hypot(x[:, 0], x[:, 2]) - 0.6).max() <= tol
    angles = np.linspace(0.0, 2 * math.pi, 400)
    x, z = 0.6 * np.cos(angles), 0.6 * np.sin(angles)
    y = np.sqrt(1 - x**2)
    exact = np.concatenate([np.stack([x, y, z], 1), np.stack([x, -y, z], 1)])
    assert distance_to_polylines(exact, samples(branches)).max() <= tol
    check_fit(branches, wide, narrow, tol)


def check_ends(branches, s1, s2, singular):
    """Every end is a singular point (flagged, met by four branch ends: two branches cross
    there) or lies on a boundary of a domain (where the seams of closed surfaces split
    branches)."""
    at_singular = np.zeros(len(singular), int)
    for branch in branches:
        ends = np.asarray(branch.curve(np.array([0.0, 1.0])))
        params = [np.asarray(uv(np.array([0.0, 1.0]))) for uv in (branch.uv1, branch.uv2)]
        for k in range(2):
            gaps = np.linalg.norm(singular - ends[k], axis=1)
            if branch.ends_singular[k]:
                assert gaps.min() <= 1e-6, gaps.min()
                at_singular[np.argmin(gaps)] += 1
                continue
            assert gaps.min() > 1e-3
            edge = min(
                np.abs(np.asarray(surface.domain) - uv[k][:, None]).min()
                for surface, uv in ((s1, params[0]), (s2, params[1]))
            )
            assert edge <= 1e-9, edge
    np.testing.assert_array_equal(at_singular, 4)


def test_equal_cylinders_end_at_the_singular_points():
    first, second = cylinder(1.0, "z", 0.4), cylinder(1.0, "y", 1.1)
    branches = dn.surface_intersections(first, second)
    tol = 1e-7 * (1 + math.sqrt(4 + 16 + 4))
    # Two ellipses in the planes y = z and y = -z cross at (+-1, 0, 0).
    singular = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    check_ends(branches, first, second, singular)
    for branch, x in zip(branches, samples(branches), strict=True):
        assert not branch.closed
        assert np.abs(np.hypot(x[:, 0], x[:, 1]) - 1.0).max() <= tol
        assert np.abs(np.hypot(x[:, 0], x[:, 2]) - 1.0).max() <= tol
        assert np.minimum(np.abs(x[:, 1] - x[:, 2]), np.abs(x[:, 1] + x[:, 2])).max() <= 2 * tol
    angles = np.linspace(0.0, 2 * math.pi, 400)
    c, s = np.cos(angles), np.sin(angles)
    exact = np.concatenate([np.stack([c, s, s], 1), np.stack([c, s, -s], 1)])
    assert distance_to_polylines(exact, samples(branches)).max() <= tol
    check_fit(branches, first, second, tol)


def test_villarceau_circles_on_the_bitangent_plane():
    major, minor = 2.0, 1.0
    tube = profile_3d(dn.arc(minor, 0.5, 0.5 + 2 * math.pi, center=(major, 0.0)), 1.0)
    torus = dn.revolve(tube, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    tilt = math.asin(minor / major)
    along = np.array([math.cos(tilt), 0.0, math.sin(tilt)])
    cut = plane((0.0, 0.0, 0.0), 3.5 * along, (0.0, 3.5, 0.0))
    branches = dn.surface_intersections(torus, cut)
    nets = [np.asarray(s.control_points).reshape(-1, 3) for s in (torus, cut)]
    tol = 1e-7 * (1 + np.linalg.norm(np.ptp(np.concatenate(nets), axis=0)))
    # The circles of radius R about (0, +-r, 0) in the plane cross where it touches the torus.
    touch = math.sqrt(major**2 - minor**2) * along
    check_ends(branches, torus, cut, np.stack([touch, -touch]))
    normal = np.array([-math.sin(tilt), 0.0, math.cos(tilt)])
    for branch, x in zip(branches, samples(branches), strict=True):
        assert not branch.closed
        assert np.abs(x @ normal).max() <= tol
        to_circles = [
            np.abs(np.linalg.norm(x - centre, axis=1) - major)
            for centre in ([0.0, minor, 0.0], [0.0, -minor, 0.0])
        ]
        assert np.minimum(*to_circles).max() <= tol
    angles = np.linspace(0.0, 2 * math.pi, 400)
    ring = major * (np.outer(np.cos(angles), along) + np.outer(np.sin(angles), [0.0, 1.0, 0.0]))
    offset = np.array([0.0, minor, 0.0])
    exact = np.concatenate([ring + offset, ring - offset])
    assert distance_to_polylines(exact, samples(branches)).max() <= tol
    check_fit(branches, torus, cut, tol)


def test_random_bicubic_patches_against_a_dense_brute_force():
    rng = np.random.default_rng(7)
    floor = height_field(rng, (4, 4), 0.3, 0.7)  # z = f(x, y)
    wall = height_field(rng, (4, 4), 0.3, 0.7)  # x = g(y, z): coordinates permuted
    wall = dn.NURBSSurface(np.asarray(wall.control_points)[..., [2, 0, 1]], (3, 3))
    branches = dn.surface_intersections(floor, wall)
    tol = 1e-7 * (1 + math.sqrt(3))
    assert branches
    check_fit(branches, floor, wall, tol)
    # Brute force: on a fine grid of the wall, the height above the floor changes sign
    # across the intersection; bisection along each grid edge where it does.
    ys = np.linspace(0.0, 1.0, 301)

    def above(a, b):
        x = np.asarray(wall(a, b))
        return x, x[:, 2] - np.asarray(floor(*np.clip(x[:, :2].T, 0.0, 1.0)))[:, 2]

    a, b = np.meshgrid(ys, ys, indexing="ij")
    _, h = above(a.ravel(), b.ravel())
    h = h.reshape(a.shape)
    edges = []
    for axis in (0, 1):
        first = (slice(None, -1), slice(None)) if axis == 0 else (slice(None), slice(None, -1))
        second = (slice(1, None), slice(None)) if axis == 0 else (slice(None), slice(1, None))
        hits = np.flatnonzero((np.sign(h[first]) != np.sign(h[second])).ravel())
        lo = np.stack([a[first].ravel()[hits], b[first].ravel()[hits]], 1)
        hi = np.stack([a[second].ravel()[hits], b[second].ravel()[hits]], 1)
        edges.append((lo, hi))
    lo, hi = (np.concatenate(x) for x in zip(*edges, strict=True))
    sign_lo = np.sign(above(lo[:, 0], lo[:, 1])[1])
    for _ in range(45):
        mid = 0.5 * (lo + hi)
        same = np.sign(above(mid[:, 0], mid[:, 1])[1]) == sign_lo
        lo, hi = np.where(same[:, None], mid, lo), np.where(same[:, None], hi, mid)
    brute = above(lo[:, 0], lo[:, 1])[0]
    assert len(brute) > 100
    lines = samples(branches, 20001)
    assert distance_to_polylines(brute, lines).max() <= tol  # none missed
    for x in lines:  # none extra: every branch point is on both surfaces, near the brute force
        heights = np.asarray(floor(*np.clip(x[:, :2].T, 0.0, 1.0)))[:, 2]
        assert np.abs(x[:, 2] - heights).max() <= tol
        assert distance_to_polylines(x[::50], [brute]).max() <= 2 / 300


def test_every_branch_of_two_height_fields_once():
    # Two height fields over one square (x = u, y = v for both) meet where z1 - z2 = 0: the
    # zero contour of the difference on a fine grid (marching squares, matplotlib) has as
    # many pieces, and as many closed ones, as there are branches, none traced twice.
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(2)
    s1, s2 = height_field(rng, (10, 10), 0.3, 0.7), height_field(rng, (10, 10), 0.3, 0.7)
    branches = dn.surface_intersections(s1, s2)
    check_fit(branches, s1, s2, 1e-7 * (1 + math.sqrt(3)))
    grid = np.linspace(0.0, 1.0, 801)
    u, v = (x.ravel() for x in np.meshgrid(grid, grid, indexing="ij"))
    difference = np.asarray(s1(u, v))[:, 2] - np.asarray(s2(u, v))[:, 2]
    pieces = plt.contour(grid, grid, difference.reshape(801, 801).T, [0.0]).allsegs[0]
    plt.close("all")
    loops = sum(np.allclose(piece[0], piece[-1]) for piece in pieces)
    assert loops >= 2  # the case asks something: loops inside the square, not only arcs
    assert (len(branches), sum(b.closed for b in branches)) == (len(pieces), loops)
    lines = samples(branches, 2001)
    for k, line in enumerate(lines):  # distinct branches of generic surfaces do not meet
        others = [x for j, x in enumerate(lines) if j != k]
        assert distance_to_polylines(line, others).min() > 1e-3


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="curve must be a curve in 3D"):
        dn.curve_surface_intersections(dn.circle(1.0), SPHERE)
    with pytest.raises(ValueError, match="surface must be a NURBSSurface"):
        dn.curve_surface_intersections(LINE, LINE)
    with pytest.raises(ValueError, match="s2 must be a NURBSSurface"):
        dn.surface_intersections(SPHERE, np.eye(3))
    flat = dn.NURBSSurface(np.zeros((2, 2, 2)), (1, 1))
    with pytest.raises(ValueError, match="s1 must be a surface in 3D"):
        dn.surface_intersections(flat, SPHERE)
    with pytest.raises(ValueError, match="tol must be a positive"):
        dn.surface_intersections(SPHERE, SPHERE, tol=-1.0)


def horizontal_plane(c):
    """The bilinear patch `z = c` over [-2, 2]^2, `c` possibly traced."""
    xy = jnp.array([[[-2.0, -2.0], [-2.0, 2.0]], [[2.0, -2.0], [2.0, 2.0]]])
    return dn.NURBSSurface(jnp.concatenate([xy, jnp.full((2, 2, 1), c)], axis=-1), (1, 1))


def test_gradient_of_the_circle_radius_cut_from_the_sphere():
    """`z = c` cuts the unit sphere in a circle of radius `sqrt(1 - c^2)`; the radius of the
    returned curve differentiates to `-c / sqrt(1 - c^2)` (through the plane's control
    points, the search called inside `jax.grad`). The value computed under `jax.grad` is the
    one computed without it."""
    w = jnp.linspace(0.0, 1.0, 1001)

    def radius(c):
        (branch,) = dn.surface_intersections(horizontal_plane(c), SPHERE)
        x = branch.curve(w)
        return jnp.mean(jnp.hypot(x[:, 0], x[:, 1]))

    c = 0.3
    value, grad = jax.value_and_grad(radius)(c)
    assert float(value) == float(radius(c))
    assert abs(float(value) - math.sqrt(1 - c**2)) <= 1e-6
    # Every data point's derivative is the exact one (implicit function theorem); the
    # cubic through them carries them with its own interpolation error, relative ~1e-7
    # here like that of the circle itself.
    np.testing.assert_allclose(float(grad), -c / math.sqrt(1 - c**2), rtol=1e-6)


def gauss_nodes(curve, count=4):
    """Gauss-Legendre nodes and weights on each knot span of a curve (concrete knots)."""
    breaks = np.unique(np.asarray(curve.knots))
    x, a = np.polynomial.legendre.leggauss(count)
    half = np.diff(breaks)[:, None] / 2
    return (breaks[:-1, None] + half * (x + 1)).ravel(), (half * a).ravel()


def test_gradient_through_crossing_cylinders_against_finite_differences():
    """`jax.grad` of a scalar of both branches w.r.t. one control point of `s1`, against
    central differences of the whole function (the search run again each time; the step
    keeps the two loops). The scalar is an integral over arc length (the length and a first
    moment), which does not depend on where along the branch the traced points fall (that
    moves with the search; the Newton step holds it fixed). With `start=` the same
    gradient comes out under `jit`."""
    wide, narrow = cylinder(1.0, "z", 0.0), cylinder(0.6, "y", 0.3)
    weights = jnp.array([0.3, -0.5, 0.8])
    index = (2, 0)  # a point of the ring at z = -2, near y = 1 where the narrow one crosses

    def moved(delta):
        points = jnp.asarray(wide.control_points).at[index].add(delta)
        return dn.NURBSSurface(points, wide.degree, wide.knots, wide.weights)

    def scalar(delta, start=None, nodes=None):
        branches = dn.surface_intersections(moved(delta), narrow, start=start)
        assert len(branches) == 2
        total = 0.0
        for k, branch in enumerate(branches):
            at, quadrature = gauss_nodes(branch.curve) if nodes is None else nodes[k]
            d = branch.curve.derivatives(at, 1)
            speed = jnp.linalg.norm(d[:, 1], axis=-1)
            total += jnp.sum(quadrature * speed * (1.0 + d[:, 0] @ weights))
        return total, branches

    zero = jnp.zeros(3)
    grad, start = jax.grad(scalar, has_aux=True)(zero)  # the search inside jax.grad
    direction = np.array([0.6, -0.3, 0.74])
    step = 1e-4
    central = (scalar(step * direction)[0] - scalar(-step * direction)[0]) / (2 * step)
    np.testing.assert_allclose(float(grad @ direction), float(central), rtol=1e-5, atol=1e-7)
    nodes = [gauss_nodes(b.curve) for b in start]
    again = jax.jit(jax.grad(lambda d: scalar(d, start, nodes)[0]))(zero)
    np.testing.assert_allclose(np.asarray(again), np.asarray(grad), rtol=1e-10, atol=1e-12)
