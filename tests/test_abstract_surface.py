"""Every surface shares `AbstractSurface`: evaluation, derivatives, normals, point inversion,
meshes. Oracles: the exact NURBS form of a Coons patch (`to_nurbs`), finite differences, and
brute force over a dense grid."""

import numpy as np
import pytest

import diffnurbs as dn


def _coons():
    c0 = dn.NURBSCurve([[0, 0, 0], [1, 0, 0.4], [2, 0, 0]], 2)
    c1 = dn.NURBSCurve([[0, 2, 0], [0.7, 2, -0.3], [1.3, 2, 0.2], [2, 2, 0]], 3)
    d0 = dn.NURBSCurve([[0, 0, 0], [0, 1, 0.3], [0, 2, 0]], 2)
    d1 = dn.NURBSCurve([[2, 0, 0], [2.2, 1, 0], [2, 2, 0]], 2)
    return dn.CoonsPatch(c0, c1, d0, d1)


def _sweep(frame="rmf"):
    path = dn.NURBSCurve([[0, 0, 0], [1, 0, 1], [2, 1, 1], [3, 1, 0]], 3)
    profile = dn.NURBSCurve([[-0.2, 0.0], [0.0, 0.3], [0.2, 0.0]], 2)
    return dn.KinematicSweep(profile, path, frame)


SURFACES = {"coons": _coons, "sweep": _sweep}


def test_every_surface_is_an_abstract_surface():
    assert isinstance(_coons(), dn.AbstractSurface)
    assert isinstance(_sweep(), dn.AbstractSurface)
    assert isinstance(dn.bilinear_patch([0, 0], [1, 0], [0, 1], [1, 1]), dn.AbstractSurface)
    with pytest.raises(TypeError):
        dn.AbstractSurface()


def test_coons_derivatives_equal_those_of_its_exact_nurbs_form():
    patch = _coons()
    exact = patch.to_nurbs()
    u, v = np.array([0.0, 0.3, 0.5, 1.0]), np.array([0.2, 0.0, 0.7, 1.0])
    np.testing.assert_allclose(patch(u, v), exact(u, v), atol=1e-13)
    np.testing.assert_allclose(patch.derivatives(u, v, 2), exact.derivatives(u, v, 2), atol=1e-11)
    np.testing.assert_allclose(patch.normal(u, v), exact.normal(u, v), atol=1e-11)


@pytest.mark.parametrize("frame", ["rmf", "frenet"])
def test_sweep_derivatives_match_finite_differences(frame):
    sweep = _sweep(frame)
    u, v, h = np.array([0.2, 0.5, 0.8]), np.array([0.3, 0.6, 0.45]), 1e-4
    ders = np.asarray(sweep.derivatives(u, v, 1))

    # Fourth-order central differences: error O(h^4 S^(5)), far below the tolerance.
    def central(f):
        return (f(-2 * h) - 8 * f(-h) + 8 * f(h) - f(2 * h)) / (12 * h)

    np.testing.assert_allclose(ders[:, 0, 0], sweep(u, v), atol=1e-14)
    np.testing.assert_allclose(
        ders[:, 1, 0], central(lambda d: np.asarray(sweep(u + d, v))), atol=1e-7
    )
    np.testing.assert_allclose(
        ders[:, 0, 1], central(lambda d: np.asarray(sweep(u, v + d))), atol=1e-7
    )


@pytest.mark.parametrize("name", sorted(SURFACES))
def test_closest_point_matches_brute_force(name):
    # The gradient of the result (implicit function theorem) is the same code for every
    # surface and is checked in test_inversion; through the autodiff partials of a Coons
    # patch its compile alone took minutes.
    surface = SURFACES[name]()
    rng = np.random.default_rng(3)
    at = rng.uniform(0.1, 0.9, size=(6, 2))
    points = np.asarray(surface(at[:, 0], at[:, 1]) + 0.05 * rng.normal(size=(6, 3)))
    u, v = surface.closest_point(points)
    found = np.linalg.norm(np.asarray(surface(u, v)) - points, axis=-1)
    us = np.linspace(0.0, 1.0, 401)
    grid = np.asarray(surface.grid(us, us)).reshape(-1, 3)
    brute = np.min(np.linalg.norm(grid[None] - points[:, None], axis=-1), axis=1)
    # No sample of a fine grid is nearer, and the foot is a stationary point of the distance.
    assert np.all(found <= brute + 1e-12)
    ders = np.asarray(surface.derivatives(u, v, 1))
    residual = np.asarray(surface(u, v)) - points
    for tangent in (ders[:, 1, 0], ders[:, 0, 1]):
        np.testing.assert_allclose(np.sum(residual * tangent, axis=-1), 0.0, atol=1e-10)


@pytest.mark.parametrize("name", sorted(SURFACES))
def test_meshes_accept_every_surface(name):
    pytest.importorskip("pyvista")
    surface = SURFACES[name]()
    grid = dn.viz.surface_mesh(surface, samples=(7, 5))
    us, vs = np.linspace(0, 1, 7), np.linspace(0, 1, 5)
    expected = np.asarray(surface.grid(us, vs))
    np.testing.assert_allclose(
        np.asarray(grid.points).reshape(5, 7, 3).transpose(1, 0, 2), expected, atol=1e-12
    )
    mesh = dn.io.tessellate([surface], samples=(7, 5))
    assert mesh.n_points == 35 and mesh.n_cells == 2 * 6 * 4


def test_parameters_outside_the_domain_raise():
    for surface in (_coons(), _sweep()):
        with pytest.raises(ValueError, match="u must lie in the domain"):
            surface(1.5, 0.5)
        with pytest.raises(ValueError, match="v must lie in the domain"):
            surface.derivatives(0.5, -0.1, 1)
