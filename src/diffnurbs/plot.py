"""Matplotlib helpers for the course figures, in one course style.

`use_course_style` sets the style every chapter starts with; `plot_curve` and `plot_basis`
draw the two pictures the course draws most; `knot_ticks`, `span_samples` and `label_points`
are the pieces several chapters need: knots marked with their multiplicity, parameters that
break a line where a derivative jumps, and point labels placed off the lines.
"""

import itertools

import matplotlib as mpl
import matplotlib.pyplot as plt
import numpy as np

from ._basis import cox_de_boor

COURSE_STYLE = {
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.titlesize": 11,
    "lines.linewidth": 1.8,
    "legend.fontsize": 9,
    "legend.framealpha": 0.9,
    "image.cmap": "viridis",
    "savefig.bbox": "tight",
}
"""The course's matplotlib settings: no box around the data, lines that read at 100 % zoom,
legends that let the data show through a little; sizes stay matplotlib's."""


def use_course_style() -> None:
    """Apply `COURSE_STYLE` to matplotlib (every chapter's set-up cell calls it)."""
    mpl.rcParams.update(COURSE_STYLE)


def _samples(lower, upper, count):
    return np.linspace(float(lower), float(upper), count)


def plot_curve(
    curve,
    ax=None,
    samples=400,
    control_polygon=True,
    label=None,
    point_labels=False,
    **style,
):
    """Draw a 2D curve and, optionally, its control polygon, with equal axes.

    **Arguments:**

    - `curve`: a `NURBSCurve` of dimension 2.
    - `ax`: matplotlib axes; a new figure when None.
    - `samples`: number of parameters, evenly spaced over the domain.
    - `control_polygon`: also draw the control points and the polygon through them.
    - `label`, `style`: passed to `ax.plot` for the curve.
    - `point_labels`: name the control points `P_0, P_1, ...` (placed by `label_points`).

    **Returns:**

    The axes.
    """
    if curve.dim != 2:
        raise ValueError(f"plot_curve draws planar curves, got dim = {curve.dim}")
    ax = plt.subplots()[1] if ax is None else ax
    points = np.asarray(curve(_samples(*curve.domain, samples)))
    ax.plot(points[:, 0], points[:, 1], label=label, **style)
    net = np.asarray(curve.control_points)
    if control_polygon:
        ax.plot(net[:, 0], net[:, 1], "o--", color="0.6", lw=1, ms=4, zorder=1)
    ax.set_aspect("equal", adjustable="datalim")
    if point_labels:
        label_points(ax, net, [f"$P_{{{i}}}$" for i in range(len(net))])
    return ax


def plot_basis(knots, degree, ax=None, samples=400):
    """Draw every B-spline basis function `N_{i,p}` of a knot vector, with the knots marked
    by `knot_ticks` (a repeated knot with its multiplicity).

    **Arguments:**

    - `knots`: knot vector.
    - `degree`: the degree `p`.
    - `ax`: matplotlib axes; a new figure when None.
    - `samples`: number of parameters between the first and last knot.

    **Returns:**

    The axes.
    """
    knots = np.asarray(knots, dtype=float)
    ax = plt.subplots()[1] if ax is None else ax
    u = _samples(knots[0], knots[-1], samples)
    for i in range(len(knots) - degree - 1):
        ax.plot(u, np.asarray(cox_de_boor(knots, degree, i, u)), label=f"$N_{{{i},{degree}}}$")
    knot_ticks(ax, knots)
    ax.set_xlabel("$u$")
    return ax


def knot_ticks(ax, knots):
    """Put the x ticks of `ax` at the distinct knots, a repeated knot labelled with its
    multiplicity (`0.5` over `×2`), with light vertical grid lines.

    **Arguments:**

    - `ax`: matplotlib axes whose x axis is the parameter.
    - `knots`: knot vector.

    **Returns:**

    The axes.
    """
    values, counts = np.unique(np.asarray(knots, dtype=float), return_counts=True)
    labels = [
        f"{v:.4g}" + (f"\n×{c}" if c > 1 else "") for v, c in zip(values, counts, strict=True)
    ]
    ax.set_xticks(values, labels)
    ax.grid(axis="x", color="0.85", lw=0.8)
    return ax


def span_samples(knots, per_span=100):
    """Parameters span by span, each span stopping just before its end knot, with a NaN
    between spans: a line drawn through them breaks at every knot, so a derivative that
    jumps there is not drawn as a vertical segment.

    **Arguments:**

    - `knots`: knot vector.
    - `per_span`: parameters per non-empty span.

    **Returns:**

    A 1D array (NaN where a line must break).
    """
    if per_span < 2:
        raise ValueError(f"per_span must be at least 2, got {per_span}")
    breaks = np.unique(np.asarray(knots, dtype=float))
    spans = [
        np.append(np.linspace(a, b - 1e-9 * (b - a), per_span), np.nan)
        for a, b in itertools.pairwise(breaks)
    ]
    return np.concatenate(spans)[:-1]


def label_points(ax, points, names, color="0.2", distance=14):
    """Write each name next to its point, on the side farthest from the lines and texts
    already drawn (one of 8 directions), so that labels do not sit on the curves.

    **Arguments:**

    - `ax`: matplotlib axes with the lines drawn (call it last).
    - `points`: array of shape `(n, 2)`.
    - `names`: `n` strings.
    - `color`: text colour.
    - `distance`: from the point to the label's centre, in pixels.

    **Returns:**

    The axes.
    """
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 2 or len(points) != len(names):
        raise ValueError(
            f"points must have shape (n, 2) with one name each, got {points.shape} points "
            f"and {len(names)} names"
        )
    ax.figure.canvas.draw()  # the final limits and aspect, and every text's size
    to_pixels = ax.transData.transform
    drawn = [to_pixels(line.get_xydata()) for line in ax.get_lines() if len(line.get_xydata())]
    drawn += [np.asarray(text.get_window_extent()) for text in ax.texts]
    # Points along every segment, not only its ends: a label must avoid the whole line.
    cloud = np.concatenate(
        [np.linspace(a, b, 12) for xy in drawn for a, b in itertools.pairwise(xy)]
        + drawn
        + [[[0, 0]]]
    )
    cloud = cloud[np.all(np.isfinite(cloud), axis=1)]
    angles = np.arange(8) * np.pi / 4
    directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    for name, point in zip(names, points, strict=True):
        at = to_pixels(point)
        gaps = [np.linalg.norm(cloud - at - 1.15 * distance * d, axis=1).min() for d in directions]
        best = directions[int(np.argmax(gaps))]
        ax.annotate(
            name,
            point,
            xytext=distance * best,
            textcoords="offset pixels",
            ha="center",
            va="center",
            color=color,
        )
        cloud = np.vstack([cloud, at + 1.15 * distance * best, at + 1.9 * distance * best])
    return ax
