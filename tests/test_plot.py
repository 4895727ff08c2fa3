"""The course's matplotlib helpers: knots with their multiplicity, lines that break at knots,
labels off the lines, one style."""

import matplotlib

matplotlib.use("Agg")

import matplotlib as mpl
import matplotlib.pyplot as plt
import numpy as np
import pytest

import diffnurbs as dn
from diffnurbs import plot


def test_knot_ticks_show_each_knot_once_with_its_multiplicity():
    ax = plt.subplots()[1]
    plot.knot_ticks(ax, [0, 0, 0, 0.25, 0.5, 0.5, 1, 1, 1])
    assert list(ax.get_xticks()) == [0, 0.25, 0.5, 1]
    labels = [t.get_text() for t in ax.get_xticklabels()]
    assert labels == ["0\n×3", "0.25", "0.5\n×2", "1\n×3"]
    plt.close("all")


def test_span_samples_break_between_spans_and_stay_inside_them():
    knots = [0, 0, 0, 0.3, 0.3, 0.7, 1, 1, 1]
    u = plot.span_samples(knots, per_span=50)
    pieces = np.split(u, np.flatnonzero(np.isnan(u)))
    pieces = [piece[np.isfinite(piece)] for piece in pieces]
    assert len(pieces) == 3  # spans [0, 0.3), [0.3, 0.7), [0.7, 1]
    for piece, (a, b) in zip(pieces, [(0, 0.3), (0.3, 0.7), (0.7, 1)], strict=True):
        assert len(piece) == 50 and piece[0] == a and a <= piece.min() and piece.max() < b
    with pytest.raises(ValueError, match="per_span"):
        plot.span_samples(knots, per_span=1)


def test_labels_keep_off_the_lines():
    # A zigzag through the points and a curve past them: no label's box may touch either.
    ax = plt.subplots(figsize=(6, 3))[1]
    points = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 0.0], [3.0, 1.0], [4.0, 0.0]])
    t = np.linspace(0, 4, 200)
    ax.plot(*points.T, "o-")
    ax.plot(t, 0.5 + 0.4 * np.sin(2 * t))
    ax.set(xlim=(-1, 5), ylim=(-1, 2))
    plot.label_points(ax, points, [f"P{i}" for i in range(5)])
    ax.figure.canvas.draw()
    lines = np.concatenate(
        [
            np.linspace(a, b, 50)
            for line in ax.get_lines()
            for a, b in zip(line.get_xydata()[:-1], line.get_xydata()[1:], strict=True)
        ]
    )
    pixels = ax.transData.transform(lines)
    for text in ax.texts:
        box = text.get_window_extent()
        inside = (
            (pixels[:, 0] > box.x0)
            & (pixels[:, 0] < box.x1)
            & (pixels[:, 1] > box.y0)
            & (pixels[:, 1] < box.y1)
        )
        assert not inside.any(), f"{text.get_text()} sits on a line"
    with pytest.raises(ValueError, match="one name each"):
        plot.label_points(ax, points, ["P0"])
    plt.close("all")


def test_plot_curve_names_its_control_points():
    curve = dn.NURBSCurve(np.array([[0.0, 0.0], [1.0, 2.0], [3.0, 2.0], [4.0, 0.0]]), 3)
    ax = plot.plot_curve(curve, point_labels=True)
    assert [t.get_text() for t in ax.texts] == [f"$P_{{{i}}}$" for i in range(4)]
    plt.close("all")


def test_plot_basis_marks_repeated_knots():
    ax = plot.plot_basis([0, 0, 0, 0.5, 0.5, 1, 1, 1], 2)
    assert len(ax.get_lines()) == 5  # N_0..N_4
    assert [t.get_text() for t in ax.get_xticklabels()] == ["0\n×3", "0.5\n×2", "1\n×3"]
    plt.close("all")


def test_the_course_style_is_applied():
    with mpl.rc_context():
        plot.use_course_style()
        assert all(mpl.rcParams[key] == value for key, value in plot.COURSE_STYLE.items())
