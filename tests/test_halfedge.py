"""Half-edge meshes against counts known from topology, brute-force searches and scipy."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, Delaunay

import diffnurbs as dn

rng = np.random.default_rng(16)

TETRAHEDRON = (
    np.array([(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)], float),
    [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)],
)
CUBE = (
    np.array([(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)], float),
    [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)],
)


def grid_faces(rows, cols, wrap_rows=False, wrap_cols=False):
    """Quads of a (rows x cols) vertex grid, counterclockwise in (i, j); optionally closed."""
    index = np.arange(rows * cols).reshape(rows, cols)
    if wrap_rows:
        index = np.vstack([index, index[:1]])
    if wrap_cols:
        index = np.hstack([index, index[:, :1]])
    a, b = index[:-1, :-1], index[1:, :-1]
    c, d = index[1:, 1:], index[:-1, 1:]
    return np.stack([a, b, c, d], axis=-1).reshape(-1, 4)


def grid_points(rows, cols):
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    return np.stack([i, j, np.zeros_like(i)], axis=-1).reshape(-1, 3).astype(float)


def brute_force_twins(faces):
    half_edges = [(f[k], f[(k + 1) % len(f)]) for f in faces for k in range(len(f))]
    return np.array(
        [
            next((j for j, (c, d) in enumerate(half_edges) if (c, d) == (b, a)), -1)
            for a, b in half_edges
        ]
    )


def assert_invariants(mesh):
    h = np.arange(mesh.n_half_edges)
    paired = mesh.twin >= 0
    assert np.array_equal(mesh.twin[mesh.twin[paired]], h[paired])  # twin of twin is itself
    assert np.array_equal(mesh.origin[mesh.twin[paired]], mesh.target[paired])
    assert np.array_equal(mesh.prev[mesh.next], h)
    assert np.array_equal(mesh.face[mesh.next], mesh.face)  # next stays in the face
    for f, face in enumerate(mesh.faces()):
        walk = [mesh.face_start[f]]
        for _ in range(len(face) - 1):
            walk.append(mesh.next[walk[-1]])
        assert mesh.next[walk[-1]] == walk[0]  # the face closes after len(face) steps
        assert np.array_equal(mesh.origin[walk], face)


ANNULUS_FACES = grid_faces(4, 6, wrap_cols=True)


@pytest.mark.parametrize(
    "name, points, faces, counts, chi, loops",
    [
        ("tetrahedron", *TETRAHEDRON, (4, 6, 4), 2, 0),
        ("cube", *CUBE, (8, 12, 6), 2, 0),
        ("disc grid", grid_points(4, 6), grid_faces(4, 6), (24, 3 * 6 + 4 * 5, 15), 1, 1),
        (
            "annulus",
            grid_points(4, 6),
            grid_faces(4, 6, wrap_cols=True),
            (24, 3 * 6 + 4 * 6, 18),
            0,
            2,
        ),
        ("torus", grid_points(4, 6), grid_faces(4, 6, True, True), (24, 4 * 6 + 4 * 6, 24), 0, 0),
    ],
)
def test_counts_and_euler_characteristic(name, points, faces, counts, chi, loops):
    mesh = dn.HalfEdgeMesh(faces, points)
    assert (mesh.n_vertices, mesh.n_edges, mesh.n_faces) == counts, name
    assert mesh.euler_characteristic == chi
    assert len(mesh.boundary_loops()) == loops
    assert len(mesh.edges()) == counts[1]
    assert len({tuple(sorted(e)) for e in mesh.edges().tolist()}) == counts[1]  # each edge once
    assert_invariants(mesh)
    assert all(len(mesh.one_ring(v)) >= 2 for v in range(mesh.n_vertices))


def test_twins_against_brute_force_on_a_delaunay_triangulation():
    points = rng.uniform(size=(40, 2))
    triangles = Delaunay(points).simplices
    # scipy does not promise an orientation: make every triangle counterclockwise.
    a, b, c = (points[triangles[:, k]] for k in range(3))
    cross = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    triangles = np.where(cross[:, None] > 0, triangles, triangles[:, ::-1])
    mesh = dn.HalfEdgeMesh(triangles, points)
    assert np.array_equal(mesh.twin, brute_force_twins(triangles.tolist()))
    assert mesh.euler_characteristic == 1  # a triangulated convex polygon is a disc
    (loop,) = mesh.boundary_loops()
    hull = ConvexHull(points).vertices  # counterclockwise, like the faces
    start = int(np.flatnonzero(hull == loop[0])[0])
    assert np.array_equal(loop, np.roll(hull, -start))
    assert_invariants(mesh)


def test_one_rings_of_a_grid():
    rows, cols = 4, 5
    mesh = dn.HalfEdgeMesh(grid_faces(rows, cols), grid_points(rows, cols))
    index = np.arange(rows * cols).reshape(rows, cols)
    interior = index[2, 2]
    ring = mesh.one_ring(interior)
    # Quads only: the one-ring holds the 4 edge neighbours (not the diagonals).
    assert sorted(ring) == sorted([index[1, 2], index[3, 2], index[2, 1], index[2, 3]])
    # In order around the vertex: consecutive neighbours are corners of one face.
    faces = [set(face.tolist()) for face in mesh.faces()]
    for a, b in zip(ring, np.roll(ring, -1), strict=True):
        assert any({a, b, interior} <= face for face in faces)
    corner = mesh.one_ring(index[0, 0])
    assert sorted(corner) == sorted([index[1, 0], index[0, 1]])
    edge = mesh.one_ring(index[0, 2])  # a boundary vertex: the ring starts and ends there
    assert len(edge) == 3 and {edge[0], edge[-1]} == {index[0, 1], index[0, 3]}


def test_boundary_loop_of_a_grid_is_its_perimeter():
    rows, cols = 3, 5
    mesh = dn.HalfEdgeMesh(grid_faces(rows, cols), grid_points(rows, cols))
    (loop,) = mesh.boundary_loops()
    index = np.arange(rows * cols).reshape(rows, cols)
    perimeter = np.concatenate(
        [index[:-1, 0], index[-1, :-1], index[:0:-1, -1], index[0, :0:-1]]
    )  # counterclockwise in (i, j), like the faces
    start = int(np.flatnonzero(perimeter == loop[0])[0])
    assert np.array_equal(loop, np.roll(perimeter, -start))


def revolved_sphere():
    half = dn.arc(1.0, -math.pi / 2, math.pi / 2, center=(0.0, 0.0, 0.0))
    return dn.revolve(half, (0.0, 0.0, 0.0), (0.0, 1.0, 0.0))


@pytest.mark.parametrize("samples", [(5, 7), (9, 13)])
def test_welded_sphere_is_closed_with_euler_characteristic_two(samples):
    nu, nv = samples
    grid = np.asarray(revolved_sphere().grid(np.linspace(0, 1, nu), np.linspace(0, 1, nv)))
    points, faces = dn.weld_vertices(grid.reshape(-1, 3), grid_faces(nu, nv))
    mesh = dn.HalfEdgeMesh(faces, points)
    # The seam column v = 1 merges into v = 0, each pole row into one point.
    assert mesh.n_vertices == (nu - 2) * (nv - 1) + 2
    assert sorted({len(face) for face in faces}) == [3, 4]  # triangles at the poles
    assert mesh.euler_characteristic == 2
    assert mesh.boundary_loops() == [] and np.all(mesh.twin >= 0)
    poles = np.flatnonzero(np.isclose(np.abs(points[:, 1]), 1.0))
    assert all(len(mesh.one_ring(int(p))) == nv - 1 for p in poles)
    assert_invariants(mesh)


def test_nurbs_patch_is_a_disc():
    surface = dn.NURBSSurface(rng.normal(size=(4, 5, 3)), (3, 2))
    grid = np.asarray(surface.grid(np.linspace(0, 1, 6), np.linspace(0, 1, 8)))
    points, faces = dn.weld_vertices(grid.reshape(-1, 3), grid_faces(6, 8))
    mesh = dn.HalfEdgeMesh(faces, points)
    assert (mesh.n_vertices, mesh.euler_characteristic) == (48, 1)
    assert [len(loop) for loop in mesh.boundary_loops()] == [2 * 5 + 2 * 7]


def test_weld_matches_connected_components_of_close_pairs():
    centers = rng.normal(size=(30, 3))
    points = np.repeat(centers, 3, axis=0) + rng.normal(scale=1e-12, size=(90, 3))
    order = rng.permutation(90)
    points = points[order]
    faces = [tuple(range(k, k + 3)) for k in range(0, 87, 3)]
    welded, _ = dn.weld_vertices(points, faces, tolerance=1e-9)
    size = np.linalg.norm(np.ptp(points, axis=0))
    close = np.linalg.norm(points[:, None] - points[None], axis=-1) <= 1e-9 * size
    count, _ = connected_components(coo_matrix(close), directed=False)
    assert count == 30 and len(welded) == count


def test_weld_drops_collapsed_faces_and_unused_points():
    points = np.array([(0, 0, 0), (1, 0, 0), (1, 0, 0), (0, 1, 0), (5, 5, 5)], float)
    welded, faces = dn.weld_vertices(points, [(0, 1, 2), (0, 1, 2, 3)])
    assert len(faces) == 1 and sorted(faces[0].tolist()) == [0, 1, 2]
    assert len(welded) == 3  # the unused point (5, 5, 5) is gone


def test_points_stay_differentiable():
    faces = grid_faces(3, 3)

    def total_area(scale):
        mesh = dn.HalfEdgeMesh(faces, scale * jnp.asarray(grid_points(3, 3)))
        corners = mesh.points[np.stack(mesh.faces())]
        diagonal_cross = jnp.cross(corners[:, 2] - corners[:, 0], corners[:, 3] - corners[:, 1])
        return 0.5 * jnp.linalg.norm(diagonal_cross, axis=-1).sum()

    np.testing.assert_allclose(total_area(2.0), 16.0)
    np.testing.assert_allclose(jax.grad(total_area)(2.0), 16.0)  # d(4 s^2)/ds at s = 2


def test_bad_meshes_are_rejected():
    points, faces = TETRAHEDRON
    flipped = [faces[0][::-1], *faces[1:]]
    with pytest.raises(ValueError, match="opposite directions"):
        dn.HalfEdgeMesh(flipped, points)
    with pytest.raises(ValueError, match="opposite directions"):  # an edge in three faces
        dn.HalfEdgeMesh([(0, 1, 2), (1, 0, 3), (0, 1, 3)], points)
    with pytest.raises(ValueError, match="at least 3 vertex"):
        dn.HalfEdgeMesh([(0, 1)], points)
    with pytest.raises(ValueError, match=r"expected indices in \[0, 4\)"):
        dn.HalfEdgeMesh([(0, 1, 4)], points)
    with pytest.raises(ValueError, match="repeats a vertex"):
        dn.HalfEdgeMesh([(0, 1, 0)], points)
    with pytest.raises(ValueError, match="at least one face"):
        dn.HalfEdgeMesh([], points)
    with pytest.raises(ValueError, match="finite"):
        dn.HalfEdgeMesh(faces, np.where(points == 1, np.nan, points))
    with pytest.raises(ValueError, match="tolerance must be positive"):
        dn.weld_vertices(points, faces, tolerance=0.0)


def test_non_manifold_vertex_is_reported():
    # Two triangles touching only at vertex 0 (a "bowtie").
    points = np.array([(0, 0, 0), (1, 0, 0), (1, 1, 0), (-1, 0, 0), (-1, -1, 0)], float)
    mesh = dn.HalfEdgeMesh([(0, 1, 2), (0, 3, 4)], points)
    with pytest.raises(ValueError, match="non-manifold"):
        mesh.one_ring(0)
    assert sorted(mesh.one_ring(1).tolist()) == [0, 2]
    with pytest.raises(ValueError, match="vertex must be in"):
        mesh.one_ring(5)
