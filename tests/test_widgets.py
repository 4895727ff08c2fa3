"""The widgets' kernel side: what they send to draw is what the library computes.

The browser side (dragging in JupyterLab, latency) is tested in `test_browser.py`.
"""

import gc
import hashlib
import io
import itertools
import os
from pathlib import Path

import numpy as np
import pytest
from helpers import random_curve

import diffnurbs as dn
from diffnurbs.widgets import CurveEditor, MotionEditor, PointsEditor, Raster, SurfaceView

MEMORY_TABLE = (
    Path(__file__).resolve().parents[1] / "build" / "browser" / "memory_motion_editor_kernel.md"
)


def browser_edit(editor, **state):
    """What one message from the browser does: new state and request id, set together."""
    with editor.hold_trait_notifications():
        editor.state = {**editor.state, **state}
        editor.request = editor.request + 1


def unpacked(data):
    """The browser's reading of a binary point buffer: little-endian float64 (x, y) pairs."""
    return np.frombuffer(data, dtype="<f8").reshape(-1, 2)


def parameters(curve, per_span):
    breaks = np.unique(np.asarray(curve.knots)[curve.degree : -curve.degree])
    u = [np.linspace(a, b, per_span, endpoint=False) for a, b in itertools.pairwise(breaks)]
    return np.append(np.concatenate(u), breaks[-1])


def test_drawing_is_the_librarys_curve_comb_and_construction():
    curve = random_curve(np.random.default_rng(4), 3, n_control=9)
    editor = CurveEditor(curve, u=0.3, construction=True, comb=True, samples_per_span=10)
    drawing = editor.drawing
    u = parameters(curve, 10)
    points = np.asarray(curve(u))
    np.testing.assert_allclose(unpacked(drawing["curve"]), points, atol=1e-13)
    # Comb oracle: curvature and unit tangent from the curve's own methods.
    kappa, tangent = np.asarray(curve.curvature(u)), np.asarray(curve.tangent(u))
    left = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    size = np.ptp(np.asarray(curve.control_points), axis=0).max()
    tips = points - 0.2 * size / np.abs(kappa).max() * kappa[:, None] * left
    np.testing.assert_allclose(unpacked(drawing["comb"]), tips, atol=1e-10)
    for level, oracle in zip(drawing["levels"], dn.de_boor_levels(curve, 0.3), strict=True):
        np.testing.assert_allclose(level, oracle, atol=1e-6)
    np.testing.assert_allclose(drawing["point"], curve(0.3), atol=1e-6)


def test_basis_panel_is_the_rational_basis():
    curve = random_curve(np.random.default_rng(5), 2, n_control=7, rational=True)
    editor = CurveEditor(curve)
    basis = editor.drawing["basis"]
    u = np.asarray(basis["u"])
    dense = np.zeros((len(u), 7))
    for i, (first, values) in enumerate(basis["rows"]):
        dense[first : first + len(values), i] = values
    weighted = np.asarray(dn.basis_matrix(curve.knots, 2, u)) * np.asarray(curve.weights)
    np.testing.assert_allclose(dense, weighted / weighted.sum(1, keepdims=True), atol=1e-6)
    np.testing.assert_allclose(dense.sum(1), 1.0, atol=1e-6)


def test_browser_edits_change_the_curve_and_answer_the_request():
    editor = CurveEditor(dn.NURBSCurve(np.eye(5, 2), 3))
    seen = []
    editor.observe(lambda change: seen.append(change["new"]), "curve")
    points = [list(p) for p in editor.state["control_points"]]
    points[2] = [2.0, -1.0]
    browser_edit(editor, control_points=points, weights=[1, 1, 3.0, 1, 1])
    assert editor.drawing["request"] == 1 and editor.drawing["error"] == ""
    np.testing.assert_array_equal(editor.curve.control_points[2], [2.0, -1.0])
    np.testing.assert_array_equal(editor.curve.weights, [1, 1, 3, 1, 1])
    assert len(seen) == 1 and seen[0] is editor.curve
    np.testing.assert_allclose(unpacked(editor.drawing["curve"])[-1], [0.0, 0.0], atol=1e-12)


def test_invalid_edit_is_refused_with_the_librarys_message():
    curve = dn.NURBSCurve(np.eye(5, 2), 3)
    editor = CurveEditor(curve)
    browser_edit(editor, knots=[0, 0, 0, 0, 0.7, 1, 1, 1, 0.9])
    assert editor.drawing["request"] == 1
    assert "knots must be non-decreasing" in editor.drawing["error"]
    assert editor.curve is curve
    assert editor.state["knots"] == np.asarray(curve.knots).tolist()
    browser_edit(editor, weights=[1, 1, -2.0, 1, 1])
    assert "weights" in editor.drawing["error"] and editor.curve is curve


def test_curve_set_from_python_updates_state_and_drawing():
    editor = CurveEditor(dn.NURBSCurve(np.eye(4, 2), 3))
    circle = dn.circle(2.0)
    editor.curve = circle
    assert editor.state["degree"] == 2 and len(editor.state["control_points"]) == 9
    radius = np.linalg.norm(unpacked(editor.drawing["curve"]), axis=1)
    np.testing.assert_allclose(radius, 2.0, atol=1e-13)


def test_picture_for_static_pages():
    editor = CurveEditor(dn.circle(1.0), construction=True, comb=True)
    data, _ = editor._repr_mimebundle_()
    assert "application/vnd.jupyter.widget-view+json" in data
    assert data["image/png"].startswith(b"\x89PNG")


def test_bad_arguments():
    with pytest.raises(ValueError, match="planar curves, got dim = 3"):
        CurveEditor(dn.NURBSCurve(np.eye(4, 3), 2))
    with pytest.raises(ValueError, match="edits a NURBSCurve, got ndarray"):
        CurveEditor(np.eye(4, 2))
    with pytest.raises(ValueError, match="samples_per_span must be >= 2"):
        CurveEditor(dn.circle(1.0), samples_per_span=1)


def midpoints(points):
    return {"midpoints": (points[1:] + points[:-1]) / 2}


def test_points_editor_draws_what_its_function_returns():
    editor = PointsEditor([[0, 0], [1, 0], [1, 1]], midpoints)
    (line,) = editor.drawing["lines"]
    assert line["label"] == "midpoints"
    np.testing.assert_array_equal(unpacked(line["data"]), [[0.5, 0], [1, 0.5]])
    browser_edit(editor, control_points=[[0, 0], [3, 0], [1, 1]])
    np.testing.assert_array_equal(editor.points[1], [3, 0])
    np.testing.assert_array_equal(
        unpacked(editor.drawing["lines"][0]["data"]), [[1.5, 0], [2, 0.5]]
    )
    assert editor.drawing["request"] == 1 and editor.drawing["error"] == ""


def test_points_editor_refuses_what_its_function_refuses():
    def positive(points):
        if np.any(points[:, 1] < 0):
            raise ValueError("every point must lie above the x axis")
        return {"polygon": points}

    editor = PointsEditor([[0, 1], [1, 2]], positive)
    browser_edit(editor, control_points=[[0, 1], [1, -2]])
    assert editor.drawing["error"] == "every point must lie above the x axis"
    np.testing.assert_array_equal(editor.points, [[0, 1], [1, 2]])
    assert editor.state == {"control_points": [[0.0, 1.0], [1.0, 2.0]]}
    browser_edit(editor, control_points=[[0, 1], [1, 2], [2, 2]])
    assert editor.drawing["error"] == "expected 2 points, got 3"
    data, _ = editor._repr_mimebundle_()
    assert data["image/png"].startswith(b"\x89PNG")


def test_points_editor_bad_arguments():
    with pytest.raises(ValueError, match=r"points must have shape \(count, 2\), got \(3,\)"):
        PointsEditor([1, 2, 3], midpoints)
    with pytest.raises(ValueError, match="draw must be a function"):
        PointsEditor([[0, 0]], None)
    with pytest.raises(ValueError, match="draw must return a dict"):
        PointsEditor([[0, 0]], lambda points: points)
    with pytest.raises(ValueError, match=r"'x' must have shape \(m, 2\), got \(3,\)"):
        PointsEditor([[0, 0]], lambda points: {"x": [1, 2, 3]})


def floats(data):
    """The browser's reading of a 3D buffer: little-endian float32 (x, y, z) triples."""
    return np.frombuffer(data, dtype="<f4").reshape(-1, 3)


def test_surface_view_sends_the_librarys_samples():
    surface = dn.NURBSSurface(np.random.default_rng(0).normal(size=(5, 4, 3)), (3, 2))
    view = SurfaceView(caption="a patch")
    view.surface("patch", surface, samples=(7, 5), net=True)
    item = view.items["patch"]
    assert item["shape"] == [7, 5]
    expected = np.asarray(surface.grid(np.linspace(0, 1, 7), np.linspace(0, 1, 5))).reshape(-1, 3)
    np.testing.assert_allclose(floats(item["positions"]), expected, rtol=1e-6, atol=1e-6)
    net = view.items["patch net"]
    assert net["shape"] == [5, 4]
    np.testing.assert_allclose(floats(net["positions"]), surface.control_points.reshape(-1, 3))
    # A planar curve lies in z = 0; a polyline is drawn as given.
    curve = random_curve(np.random.default_rng(1), 3, n_control=6)
    view.curve("c", curve, samples=9)
    drawn = floats(view.items["c"]["positions"])
    np.testing.assert_allclose(drawn[:, :2], np.asarray(curve(np.linspace(0, 1, 9))), atol=1e-6)
    assert not drawn[:, 2].any()
    view.curve("line", [[0, 0, 0], [1, 2, 3]])
    view.points("dots", np.eye(3))
    assert view.items["dots"]["count"] == 3
    view.remove("c", "line")
    assert set(view.items) == {"patch", "patch net", "dots"}
    assert view.picture().startswith(b"\x89PNG")


def test_surface_view_bad_arguments():
    view = SurfaceView()
    surface = dn.NURBSSurface(np.zeros((3, 3, 3)), (2, 2))
    with pytest.raises(ValueError, match="AbstractSurface"):
        view.surface("s", np.zeros((3, 3, 3)))
    with pytest.raises(ValueError, match="at least"):
        view.surface("s", surface, samples=(1, 5))
    corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    sides = [(0, 1), (2, 3), (0, 2), (1, 3)]  # c0, c1, d0, d1 of a unit square
    coons = dn.CoonsPatch(*(dn.NURBSCurve(corners[list(side)], 1) for side in sides))
    with pytest.raises(ValueError, match="control net"):
        view.surface("s", coons, net=True)
    with pytest.raises(ValueError, match="2D or 3D"):
        view.points("p", np.zeros((4, 4)))
    with pytest.raises(ValueError, match="count >= 2"):
        view.curve("c", np.zeros((1, 3)))
    with pytest.raises(ValueError, match="non-zero 3-vector"):
        SurfaceView(direction=(0, 0, 0))


VASE = dn.NURBSCurve(np.array([[0.9, 0.0], [1.4, 0.4], [1.5, 1.2], [0.7, 1.8], [1.1, 3.0]]), 3)


def upright(curve):
    points = np.asarray(curve.control_points)
    space = np.column_stack([points[:, 0], np.zeros(len(points)), points[:, 1]])
    return dn.NURBSCurve(space, curve.degree, curve.knots, curve.weights)


@pytest.mark.parametrize(
    "operation, values",
    [
        ("extrude", [1.5, 20.0]),
        ("revolve", [270.0, 0.3]),
        ("sweep", []),
        ("kinematic sweep", ["rmf"]),
    ],
)
def test_motion_editor_shows_the_librarys_surface(operation, values):
    editor = MotionEditor(VASE, operation=operation, samples=(9, 8))
    for control, value in zip(editor.parameters[operation], values, strict=True):
        control.value = value
    tilt = np.radians(20.0)
    expected = {
        "extrude": lambda: dn.extrude(upright(VASE), [np.sin(tilt), np.cos(tilt), 0.0], 1.5),
        "revolve": lambda: dn.revolve(upright(VASE), [0.3, 0, 0], [0, 0, 1], np.radians(270)),
        "sweep": lambda: dn.sweep(upright(VASE), editor.path),
        "kinematic sweep": lambda: dn.KinematicSweep(VASE, editor.path, "rmf"),
    }[operation]()
    uv = np.linspace(0.0, 1.0, 5)
    np.testing.assert_array_equal(editor.surface.grid(uv, uv), expected.grid(uv, uv))
    (u0, u1), (v0, v1) = expected.domain
    grid = expected.grid(np.linspace(u0, u1, 9), np.linspace(v0, v1, 8))
    drawn = floats(editor.view.items["surface"]["positions"])
    np.testing.assert_allclose(drawn, np.asarray(grid).reshape(-1, 3), rtol=1e-6, atol=1e-6)
    # The profile drawn is where the motion starts, S(u, v_min).
    start = np.asarray(expected.grid(np.linspace(u0, u1, 200), np.asarray([v0])))[:, 0]
    np.testing.assert_allclose(floats(editor.view.items["profile"]["positions"]), start, atol=1e-6)
    assert ("path" in editor.view.items) == ("sweep" in operation)
    assert ("axis" in editor.view.items) == (operation == "revolve")
    # The control net is drawn for the exact NURBS surfaces, and goes when the surface is not one.
    assert ("surface net" in editor.view.items) == (operation != "kinematic sweep")
    editor.choice.value = "revolve" if operation == "kinematic sweep" else "kinematic sweep"
    assert ("surface net" in editor.view.items) == (operation == "kinematic sweep")


def test_motion_editor_follows_the_profile_and_exports(tmp_path):
    editor = MotionEditor(VASE, samples=(9, 8))
    items = editor.view.items
    moved = np.asarray(VASE.control_points).copy()
    moved[2, 0] += 0.25
    editor.profile.curve = dn.NURBSCurve(moved, 3)
    assert editor.view.items["surface"] is not items["surface"]
    expected = dn.revolve(upright(editor.profile.curve), [0, 0, 0], [0, 0, 1])
    uv = np.linspace(0.0, 1.0, 5)
    np.testing.assert_array_equal(editor.surface.grid(uv, uv), expected.grid(uv, uv))
    pv = pytest.importorskip("pyvista")
    mesh = dn.io.tessellate([editor.surface], samples=(9, 8))
    for suffix in ("stl", "obj", "vtk"):
        written = pv.read(editor.export(tmp_path / f"vase.{suffix}"))
        assert written.n_cells == mesh.n_cells
        np.testing.assert_allclose(written.bounds, mesh.bounds, rtol=1e-6)
    with pytest.raises(ValueError, match="stl, obj, vtk"):
        editor.export(tmp_path / "vase.step")


def test_motion_editor_bad_arguments():
    with pytest.raises(ValueError, match="operation must be one of"):
        MotionEditor(VASE, operation="loft")
    with pytest.raises(ValueError, match="path must be a NURBSCurve in 3D"):
        MotionEditor(VASE, path=VASE)
    with pytest.raises(ValueError, match="CurveEditor edits planar curves"):
        MotionEditor(upright(VASE))


def resident_megabytes() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def test_motion_editor_memory_stays_flat_over_200_updates():
    # The pyvista tools this editor replaces kept a new plotter per update (~39 MB each).
    editor = MotionEditor(VASE)
    rng = np.random.default_rng(2)

    def update():
        points = np.asarray(VASE.control_points) + 0.05 * rng.normal(size=(5, 2))
        editor.profile.curve = dn.NURBSCurve(points, 3)

    for _ in range(20):  # compiled programs and caches settle first
        update()
    gc.collect()
    before = resident_megabytes()
    for _ in range(200):
        update()
    gc.collect()
    after = resident_megabytes()
    MEMORY_TABLE.parent.mkdir(parents=True, exist_ok=True)
    MEMORY_TABLE.write_text(
        "| MotionEditor, kernel | resident MB |\n|---|---|\n"
        f"| after 20 updates | {before:.0f} |\n| after 200 more | {after:.0f} |\n"
    )
    assert after - before < 20, (before, after)


def test_3d_front_end_bundle_is_built_from_its_source():
    # `make widgets` bundles tools/widgets/surface_view.js with three.js and records the
    # source's hash in the bundle's first line: an edit without a rebuild fails here.
    root = Path(__file__).resolve().parents[1]
    source = (root / "tools" / "widgets" / "surface_view.js").read_bytes()
    bundle = root / "src" / "diffnurbs" / "_static" / "surface_view.js"
    first_line = bundle.read_text().splitlines()[0]
    assert f"sha256 {hashlib.sha256(source).hexdigest()}" in first_line, "run `make widgets`"


def test_points_editor_draws_a_raster_under_its_lines():
    from PIL import Image

    pixels = np.random.default_rng(5).uniform(size=(6, 8, 3))

    def draw(points):
        return {"image": Raster(pixels * points[0, 0], (0, 2, 0, 1)), "polygon": points}

    editor = PointsEditor([[1.0, 0.0], [0.5, 0.5]], draw)
    image = editor.drawing["image"]
    assert image["extent"] == [0.0, 2.0, 0.0, 1.0]
    assert [line["label"] for line in editor.drawing["lines"]] == ["polygon"]
    decoded = np.asarray(Image.open(io.BytesIO(image["png"])))
    np.testing.assert_array_equal(decoded, np.round(255 * pixels).astype(np.uint8))
    browser_edit(editor, control_points=[[0.5, 0.0], [0.5, 0.5]])
    decoded = np.asarray(Image.open(io.BytesIO(editor.drawing["image"]["png"])))
    np.testing.assert_array_equal(decoded, np.round(255 * 0.5 * pixels).astype(np.uint8))
    assert editor.picture().startswith(b"\x89PNG")


def test_raster_bad_arguments():
    with pytest.raises(ValueError, match="pixels"):
        Raster(np.zeros((4, 4, 2)))
    with pytest.raises(ValueError, match="extent"):
        Raster(np.zeros((4, 4)), (0, 1))
    with pytest.raises(ValueError, match="one Raster at most"):
        PointsEditor(
            np.zeros((2, 2)),
            lambda p: {"a": Raster(np.zeros((2, 2))), "b": Raster(np.zeros((2, 2)))},
        )


def test_points_editor_with_weights_and_a_variable_count():
    def draw(points, weights):
        return {"weighted": points * weights[:, None]}

    editor = PointsEditor(np.eye(3, 2), draw, weights=[1.0, 2.0, 3.0], min_points=2)
    np.testing.assert_array_equal(
        unpacked(editor.drawing["lines"][0]["data"]), np.eye(3, 2) * [[1], [2], [3]]
    )
    # The browser adds a point with its weight, changes a weight, deletes points.
    browser_edit(editor, control_points=[[0, 0], [1, 0], [0.5, 0.5], [0, 1]], weights=[1, 2, 5, 3])
    assert editor.points.shape == (4, 2) and editor.weights.tolist() == [1, 2, 5, 3]
    np.testing.assert_array_equal(unpacked(editor.drawing["lines"][0]["data"])[2], [2.5, 2.5])
    for state, message in [
        ({"control_points": [[0, 0]], "weights": [1]}, "at least 2 points stay"),
        ({"control_points": [[0, 0], [1, 1]], "weights": [1, -1]}, "positive weights"),
    ]:
        browser_edit(editor, **state)
        assert message in editor.drawing["error"]
        assert editor.points.shape == (4, 2)
    # A setting outside the editor changes what draw returns: redraw() draws it again.
    scale = [1.0]
    fixed = PointsEditor(np.eye(2), lambda p: {"line": scale[0] * p})
    scale[0] = 3.0
    fixed.redraw()
    np.testing.assert_array_equal(unpacked(fixed.drawing["lines"][0]["data"]), 3 * np.eye(2))
    browser_edit(fixed, control_points=[[0, 0]])
    assert "expected 2 points" in fixed.drawing["error"]
    with pytest.raises(ValueError, match="min_points"):
        PointsEditor(np.eye(2), lambda p: {}, min_points=3)


def test_pictures_leave_the_notebooks_plotting_backend_alone():
    # In a notebook pyplot draws inline; an editor's picture once switched it to Agg, after
    # which every `plt.show()` of the chapter drew nothing.
    import matplotlib

    before = matplotlib.get_backend()
    inline = "module://matplotlib_inline.backend_inline"
    matplotlib.use(inline)
    try:
        CurveEditor(random_curve(np.random.default_rng(0), 3))._repr_mimebundle_()
        MotionEditor(VASE)._repr_mimebundle_()
        assert matplotlib.get_backend() == inline
    finally:
        matplotlib.use(before)
