from pathlib import Path

import numpy as np
import pytest

import diffnurbs as dn
from diffnurbs import io

TEAPOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "teapot.bpt"


@pytest.mark.skipif(not TEAPOT.exists(), reason="the teapot lives in ../shared, outside the repo")
def test_teapot_patches_read_and_round_trip(tmp_path):
    patches = io.read_bpt(TEAPOT)
    assert len(patches) == 32 and all(p.degree == (3, 3) for p in patches)
    first = np.asarray(patches[0].control_points)
    np.testing.assert_allclose(first[0, 0], [1.4, 0.0, 2.4])
    np.testing.assert_allclose(first[3, 3], [0.0, -1.5, 2.4])
    # A patch evaluates as its Bezier form: corners are control points.
    np.testing.assert_allclose(patches[0](1.0, 1.0), first[3, 3])
    io.write_bpt(tmp_path / "copy.bpt", patches)
    again = io.read_bpt(tmp_path / "copy.bpt")
    for a, b in zip(patches, again, strict=True):
        np.testing.assert_array_equal(a.control_points, b.control_points)


def test_round_trip_of_mixed_degrees(tmp_path):
    rng = np.random.default_rng(0)
    patches = [
        dn.NURBSSurface(rng.normal(size=(p + 1, q + 1, 3)), (p, q)) for p, q in [(1, 2), (3, 3)]
    ]
    io.write_bpt(tmp_path / "x.bpt", patches)
    for a, b in zip(patches, io.read_bpt(tmp_path / "x.bpt"), strict=True):
        assert a.degree == b.degree
        np.testing.assert_array_equal(a.control_points, b.control_points)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("2\n1 1\n" + "0 0 0\n" * 4, "ends inside the degrees of patch 1"),
        ("1\n1 1\n" + "0 0 0\n" * 3, "ends inside the control points of patch 0"),
        ("1\n1 1\n" + "0 0 0\n" * 5, "3 numbers left after the 1 patches"),
        ("1.5\n", "non-negative integer"),
        ("1\n1 1\n" + "0 0 x\n" * 4, "must be numbers"),
    ],
)
def test_bad_files(tmp_path, text, message):
    path = tmp_path / "bad.bpt"
    path.write_text(text)
    with pytest.raises(ValueError, match=message):
        io.read_bpt(path)


def test_write_rejects_rational_patches(tmp_path):
    patch = dn.NURBSSurface(np.zeros((2, 2, 3)), (1, 1), weights=np.ones((2, 2)))
    with pytest.raises(ValueError, match="non-rational Bezier patch"):
        io.write_bpt(tmp_path / "r.bpt", [patch])


@pytest.mark.parametrize("suffix", [".stl", ".obj", ".vtk"])
def test_mesh_export_round_trip(tmp_path, suffix):
    pv = pytest.importorskip("pyvista")
    sphere = dn.revolve(
        dn.arc(2.0, -np.pi / 2, np.pi / 2, center=(0.0, 0.0, 0.0)), (0, 0, 0), (0, 1, 0)
    )
    path = tmp_path / f"sphere{suffix}"
    io.export_mesh(path, sphere, samples=(20, 30))
    mesh = pv.read(path)
    assert mesh.n_points > 100 and mesh.n_cells > 100
    np.testing.assert_allclose(np.linalg.norm(mesh.points, axis=-1), 2.0, atol=1e-5)


@pytest.mark.parametrize("name", ["vase", "cup", "bell"])
def test_tessellated_objects_are_open_only_at_the_rim(name):
    pytest.importorskip("pyvista")
    patches = io.load_object(name)
    mesh = io.tessellate(patches, (6, 6))
    open_edges = mesh.extract_feature_edges(
        boundary_edges=True, feature_edges=False, manifold_edges=False, non_manifold_edges=False
    )
    # Each profile starts on the axis; its free end sweeps the rim, the one open edge loop.
    rim_height = np.asarray(patches[-1].control_points)[-1, 0, 2]
    np.testing.assert_allclose(open_edges.points[:, 2], rim_height, atol=1e-12)
    assert open_edges.n_cells == 4 * 5  # four quarter patches, 5 segments each


def test_mesh_export_rejects_unknown_formats(tmp_path):
    with pytest.raises(ValueError, match="not supported"):
        io.export_mesh(tmp_path / "x.step", dn.NURBSSurface(np.zeros((2, 2, 3)), (1, 1)))
