"""The curve editor's kernel side: what it sends to draw is what the library computes.

The browser side (dragging in JupyterLab, latency) is tested in `test_browser.py`.
"""

import itertools

import numpy as np
import pytest
from helpers import random_curve

import diffnurbs as dn
from diffnurbs.widgets import CurveEditor, PointsEditor


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
