import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import random_curve

import diffnurbs as dn
from diffnurbs import KinematicSweep, frames

V = np.linspace(0.0, 1.0, 101)
EZ = np.array([0.0, 0.0, 1.0])

# Helix (a cos t, a sin t, b t), t in [0, 4 pi]: curvature a / c^2, torsion b / c^2.
A, B, T_MAX = 1.5, 0.4, 4 * math.pi
C = math.hypot(A, B)


def _helix():
    """A quintic least-squares fit of the helix, parametrised by t (error ~1e-10)."""
    n, degree = 60, 5
    t = np.linspace(0.0, T_MAX, 1200)
    knots = np.concatenate(
        [np.zeros(degree), np.linspace(0.0, T_MAX, n - degree + 1), np.full(degree, T_MAX)]
    )
    basis = np.asarray(dn.NURBSCurve(np.eye(n), degree, knots)(t))  # (samples, n)
    exact = np.stack([A * np.cos(t), A * np.sin(t), B * t], axis=-1)
    points = np.linalg.lstsq(basis, exact, rcond=None)[0]
    return dn.NURBSCurve(points, degree, knots)


HELIX = _helix()
T_HELIX = np.linspace(0.0, T_MAX, 77)


def _helix_frenet(t):
    tangent = np.stack([-A * np.sin(t), A * np.cos(t), np.full_like(t, B)], -1) / C
    normal = np.stack([-np.cos(t), -np.sin(t), np.zeros_like(t)], -1)
    binormal = np.stack([B * np.sin(t), -B * np.cos(t), np.full_like(t, A)], -1) / C
    return tangent, normal, binormal


def _assert_orthonormal(frame, atol=1e-12):
    frame = np.asarray(frame)
    gram = np.einsum("...ik,...jk->...ij", frame, frame)
    np.testing.assert_allclose(gram, np.broadcast_to(np.eye(3), gram.shape), atol=atol)
    # Right-handed: B = T x N.
    np.testing.assert_allclose(
        np.cross(frame[..., 0, :], frame[..., 1, :]), frame[..., 2, :], atol=atol
    )


def test_helix_fit_is_accurate():
    np.testing.assert_allclose(
        HELIX(T_HELIX),
        np.stack([A * np.cos(T_HELIX), A * np.sin(T_HELIX), B * T_HELIX], -1),
        atol=1e-8,
    )


@pytest.mark.parametrize("kind", ["rmf", "frenet"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_frames_are_orthonormal_with_the_unit_tangent_first(kind, seed):
    path = random_curve(np.random.default_rng(seed), 3, n_control=8, dim=3)
    frame = frames(path, V, kind)
    assert frame.shape == (101, 3, 3)
    _assert_orthonormal(frame)
    np.testing.assert_allclose(frame[:, 0], path.tangent(V), atol=1e-12)


def test_circle_frames_are_exact():
    radius = 2.0
    path = dn.circle(radius, center=(0.0, 0.0, 0.0))
    radial = np.asarray(path(V)) / radius
    rmf = np.asarray(frames(path, V))
    # A planar path's RMF keeps the plane normal fixed; N0 = e_x is the outward normal at
    # v = 0, so N stays radial and B = T x N = -e_z.
    np.testing.assert_allclose(rmf[:, 1], radial, atol=1e-12)
    np.testing.assert_allclose(rmf[:, 2], np.broadcast_to(-EZ, (101, 3)), atol=1e-12)
    frenet = np.asarray(frames(path, V, "frenet"))  # N points to the centre
    np.testing.assert_allclose(frenet[:, 1], -radial, atol=1e-12)
    np.testing.assert_allclose(frenet[:, 2], np.broadcast_to(EZ, (101, 3)), atol=1e-12)


def test_frenet_on_a_helix_matches_the_closed_form():
    frame = np.asarray(frames(HELIX, T_HELIX, "frenet"))
    for row, exact in enumerate(_helix_frenet(T_HELIX)):
        np.testing.assert_allclose(frame[:, row], exact, atol=1e-6)


def test_rmf_on_a_helix_matches_the_closed_form():
    # RMF normal U = cos(theta) N + sin(theta) B with theta' = -torsion * ds/dt = -B / C.
    frame = np.asarray(frames(HELIX, T_HELIX))
    _, normal, binormal = _helix_frenet(T_HELIX)
    theta0 = math.atan2(frame[0, 1] @ binormal[0], frame[0, 1] @ normal[0])
    theta = theta0 - B / C * T_HELIX
    exact = np.cos(theta)[:, None] * normal + np.sin(theta)[:, None] * binormal
    np.testing.assert_allclose(frame[:, 1], exact, atol=1e-6)
    _assert_orthonormal(frame)


def _twist(path, v, kind, h=1e-5):
    """`dN/dv . B` by central differences."""
    d_normal = (frames(path, v + h, kind)[:, 1] - frames(path, v - h, kind)[:, 1]) / (2 * h)
    return np.sum(np.asarray(d_normal) * np.asarray(frames(path, v, kind)[:, 2]), -1)


def test_rmf_has_no_twist_and_frenet_does():
    v = np.linspace(0.3, T_MAX - 0.3, 23)
    np.testing.assert_allclose(_twist(HELIX, v, "rmf"), 0.0, atol=1e-7)
    # Frenet: N' = -kappa T + tau B per unit length, so N' . B = torsion * speed = B / C.
    np.testing.assert_allclose(_twist(HELIX, v, "frenet"), B / C, atol=1e-5)
    path = random_curve(np.random.default_rng(5), 4, n_control=9, dim=3, rational=True)
    v = np.linspace(0.05, 0.95, 31)
    speed = np.linalg.norm(np.asarray(path.derivatives(v, 1))[:, 1], axis=-1)
    # A wild random path: Frenet twists by up to ~4 rad per unit length here, the RMF by
    # ~1e-5 (central-difference error plus ~1e-10 steps where v crosses a table sample).
    assert np.max(np.abs(_twist(path, v, "frenet") / speed)) > 1.0
    np.testing.assert_allclose(_twist(path, v, "rmf") / speed, 0.0, atol=5e-5)


def test_rmf_does_not_depend_on_the_order_or_shape_of_v():
    path = random_curve(np.random.default_rng(7), 3, n_control=7, dim=3)
    v = np.random.default_rng(8).uniform(0, 1, size=40)
    order = np.argsort(v)
    whole = np.asarray(frames(path, v))
    np.testing.assert_allclose(np.asarray(frames(path, v[order])), whole[order], atol=1e-14)
    np.testing.assert_allclose(frames(path, v.reshape(5, 8)), whole.reshape(5, 8, 3, 3), atol=1e-14)
    np.testing.assert_allclose(frames(path, v[3]), whole[3], atol=1e-14)
    np.testing.assert_allclose(jax.jit(frames)(path, v), whole, atol=1e-14)


def test_at_an_inflection_frenet_flips_and_rmf_stays_continuous():
    # A planar S-curve lifted to 3D; its inflection is at v = 0.5 by symmetry.
    path = dn.NURBSCurve([[0, 0, 0], [1, 1, 0], [2, -1, 0], [3, 0, 0]], 3)
    before, after = np.array([0.45]), np.array([0.55])
    frenet_n = [np.asarray(frames(path, v, "frenet"))[0, 1] for v in (before, after)]
    np.testing.assert_allclose(frenet_n[0] @ frenet_n[1], -1.0, atol=1e-3)
    rmf = np.asarray(frames(path, V))
    # The RMF of a planar curve keeps the plane normal: here N0 = e_z and N stays e_z.
    np.testing.assert_allclose(rmf[:, 1], np.broadcast_to(EZ, (101, 3)), atol=1e-12)
    assert np.max(np.linalg.norm(np.diff(rmf, axis=0), axis=-1)) < 0.1
    # At the inflection itself Frenet falls back to a finite frame.
    middle = np.asarray(frames(path, 0.5, "frenet"))
    assert np.all(np.isfinite(middle))
    _assert_orthonormal(middle)


def test_frenet_on_a_straight_line_uses_the_documented_fallback():
    path = dn.NURBSCurve([[0, 0, 0], [1, 2, 2], [2, 4, 4]], 2)
    frame = np.asarray(frames(path, V, "frenet"))
    _assert_orthonormal(frame)
    t = np.array([1.0, 2.0, 2.0]) / 3  # least aligned axis: e_x
    normal = np.array([1.0, 0.0, 0.0]) - t[0] * t
    np.testing.assert_allclose(
        frame[:, 1], np.broadcast_to(normal / np.linalg.norm(normal), (101, 3)), atol=1e-12
    )


@pytest.mark.parametrize("frame", ["rmf", "frenet"])
def test_circle_swept_along_a_line_is_a_cylinder(frame):
    radius, axis = 0.7, np.array([1.0, -2.0, 0.5])
    profile = dn.circle(radius)
    path = dn.NURBSCurve(np.outer([0.0, 0.3, 0.8, 1.0], axis) + 1.0, 3)
    surface = KinematicSweep(profile, path, frame)
    u, v = np.meshgrid(np.linspace(0, 1, 33), np.linspace(0, 1, 17), indexing="ij")
    points = np.asarray(surface(u, v))
    offset = points - np.asarray(path(v))
    unit = axis / np.linalg.norm(axis)
    np.testing.assert_allclose(offset @ unit, 0.0, atol=1e-12)  # each circle in the normal plane
    np.testing.assert_allclose(np.linalg.norm(offset, axis=-1), radius, atol=1e-12)
    grid = surface.grid(u[:, 0], v[0])
    np.testing.assert_allclose(grid, points, atol=1e-14)


def test_3d_profile_follows_the_seed_convention():
    # Eq. 2.6-2.8: S(u, v_min) = C(u), and along a planar circular path the RMF turns
    # about the circle's axis, so M(v) is the rotation about e_z by the polar angle of g(v).
    rng = np.random.default_rng(11)
    profile = random_curve(rng, 3, n_control=6, dim=3)
    path = dn.circle(2.0, center=(0.0, 0.0, 0.0))
    surface = KinematicSweep(profile, path)
    u = np.linspace(0, 1, 21)
    np.testing.assert_allclose(surface(u, 0.0), profile(u), atol=1e-12)
    v = np.linspace(0, 1, 13)
    g = np.asarray(path(v))
    angle = np.arctan2(g[:, 1], g[:, 0])
    cos, sin = np.cos(angle), np.sin(angle)
    rotation = np.zeros((13, 3, 3))
    rotation[:, 0, 0], rotation[:, 0, 1], rotation[:, 1, 0], rotation[:, 1, 1] = cos, -sin, sin, cos
    rotation[:, 2, 2] = 1.0
    exact = np.einsum("jab,ib->ija", rotation, np.asarray(profile(u)) - g[0])
    np.testing.assert_allclose(surface.grid(u, v), exact + g[None], atol=1e-12)


def test_gradients_wrt_the_path_are_finite_and_match_finite_differences():
    path = random_curve(np.random.default_rng(3), 3, n_control=6, dim=3)
    profile = dn.circle(0.2)
    us, vs = np.linspace(0, 1, 9), np.linspace(0, 1, 11)

    def loss(points):
        moved = dn.NURBSCurve(points, path.degree, path.knots, path.weights)
        return jnp.sum(KinematicSweep(profile, moved).grid(us, vs) ** 2)

    grad = np.asarray(jax.jit(jax.grad(loss))(path.control_points))
    assert np.all(np.isfinite(grad)) and np.any(grad != 0)
    direction = np.random.default_rng(4).normal(size=grad.shape)
    h = 1e-6
    numeric = (
        loss(path.control_points + h * direction) - loss(path.control_points - h * direction)
    ) / (2 * h)
    np.testing.assert_allclose(np.sum(grad * direction), numeric, rtol=1e-6)
    frenet = jax.grad(lambda p: jnp.sum(frames(dn.NURBSCurve(p, 3), vs, "frenet")))
    assert np.all(np.isfinite(frenet(path.control_points)))


def test_float32():
    path = dn.NURBSCurve(
        np.asarray(HELIX.control_points, np.float32), 5, np.asarray(HELIX.knots, np.float32)
    )
    frame = frames(path, np.asarray(T_HELIX, np.float32))
    assert frame.dtype == jnp.float32
    _assert_orthonormal(frame, atol=1e-5)
    circle = dn.circle(0.2)
    profile = dn.NURBSCurve(
        np.asarray(circle.control_points, np.float32),
        2,
        np.asarray(circle.knots, np.float32),
        np.asarray(circle.weights, np.float32),
    )
    grid = KinematicSweep(profile, path).grid(
        np.linspace(0, 1, 5, dtype=np.float32), T_HELIX[:4].astype(np.float32)
    )
    assert grid.dtype == jnp.float32 and np.all(np.isfinite(grid))


def test_errors():
    planar = dn.circle(1.0)
    space = dn.circle(1.0, center=(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="path must be a curve in 3D, got dim = 2"):
        frames(planar, 0.5)
    with pytest.raises(ValueError, match="unknown frame kind 'bishop'"):
        frames(space, 0.5, "bishop")
    with pytest.raises(ValueError, match="must lie in the domain"):
        frames(space, 1.5)
    with pytest.raises(ValueError, match="path must be a curve in 3D"):
        KinematicSweep(space, planar)
    with pytest.raises(ValueError, match="unknown frame kind"):
        KinematicSweep(planar, space, "bishop")
    with pytest.raises(ValueError, match="profile must be a curve in 2D or 3D, got dim = 4"):
        KinematicSweep(dn.circle(1.0, center=(0.0,) * 4), space)
    with pytest.raises(ValueError, match="profile must be a curve in 2D or 3D, got dim = 1"):
        KinematicSweep(dn.NURBSCurve([[0.0], [1.0]], 1), space)
    with pytest.raises(ValueError, match="us must have 1 dimensions"):
        KinematicSweep(planar, space).grid(np.zeros((2, 2)), np.zeros(2))
