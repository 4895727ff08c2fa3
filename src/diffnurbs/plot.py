"""Matplotlib helpers for the course figures."""

import matplotlib.pyplot as plt
import numpy as np

from ._basis import cox_de_boor


def _samples(lower, upper, count):
    return np.linspace(float(lower), float(upper), count)


def plot_curve(curve, ax=None, samples=400, control_polygon=True, label=None, **style):
    """Draw a 2D curve and, optionally, its control polygon.

    **Arguments:**

    - `curve`: a `NURBSCurve` of dimension 2.
    - `ax`: matplotlib axes; a new figure when None.
    - `samples`: number of parameters, evenly spaced over the domain.
    - `control_polygon`: also draw the control points and the polygon through them.
    - `label`, `style`: passed to `ax.plot` for the curve.

    **Returns:**

    The axes.
    """
    if curve.dim != 2:
        raise ValueError(f"plot_curve draws planar curves, got dim = {curve.dim}")
    ax = plt.subplots()[1] if ax is None else ax
    points = np.asarray(curve(_samples(*curve.domain, samples)))
    ax.plot(points[:, 0], points[:, 1], label=label, **style)
    if control_polygon:
        net = np.asarray(curve.control_points)
        ax.plot(net[:, 0], net[:, 1], "o--", color="0.6", lw=1, ms=4, zorder=1)
    ax.set_aspect("equal", adjustable="datalim")
    return ax


def plot_basis(knots, degree, ax=None, samples=400):
    """Draw every B-spline basis function `N_{i,p}` of a knot vector, with the knots marked.

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
    ax.plot(knots, np.zeros_like(knots), "k|", ms=12)
    ax.set_xlabel("$u$")
    return ax
