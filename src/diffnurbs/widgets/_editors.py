"""The 2D editors: the browser draws and reports edits; the kernel evaluates every curve
with the library, so what the widget shows is exactly what `editor.curve` computes."""

import abc
import dataclasses
import io
import pathlib
import time
import typing
from collections.abc import Callable

import anywidget
import equinox as eqx
import jax.numpy as jnp
import numpy as np
import traitlets
from jaxtyping import ArrayLike

from .._basis import basis_matrix
from .._curve import NURBSCurve
from .._deboor import de_boor_levels
from .._misc import safe_divide

STATIC = pathlib.Path(__file__).parents[1] / "_static"
# Curve points drawn: enough for a smooth curve on screen, few enough to send at every move.
_SAMPLES = 1200
# Digits sent to the browser: a thousandth of a pixel on any sensible view.
_DIGITS = 7


def _listed(array) -> list:
    """What is only drawn, rounded for a shorter message."""
    return np.round(np.asarray(array, dtype=float), _DIGITS).tolist()


def _exact(array) -> list:
    """What is edited, in full: the curve rebuilt from the state is the curve."""
    return np.asarray(array, dtype=float).tolist()


def _packed(points) -> bytes:
    """Points as raw little-endian float64 pairs: sent as a binary buffer, not JSON text
    (the curve and the comb are most of each message)."""
    return np.ascontiguousarray(points, dtype="<f8").tobytes()


def _unpacked(data: bytes) -> np.ndarray:
    return np.frombuffer(data, dtype="<f8").reshape(-1, 2)


def _state_of(curve: NURBSCurve) -> dict:
    if curve.dim != 2:
        raise ValueError(f"CurveEditor edits planar curves, got dim = {curve.dim}")
    weights = None if curve.weights is None else _exact(curve.weights)
    return {
        "control_points": _exact(curve.control_points),
        "weights": weights,
        "knots": _exact(curve.knots),
        "degree": curve.degree,
    }


def _curve_of(state: dict) -> NURBSCurve:
    weights = state.get("weights")
    return NURBSCurve(
        np.asarray(state["control_points"], float),
        int(state["degree"]),
        np.asarray(state["knots"], float),
        None if weights is None else np.asarray(weights, float),
    )


def _parameters(curve: NURBSCurve, per_span: int) -> np.ndarray:
    """Even parameters on every non-empty knot span, the knots themselves included."""
    breaks = np.unique(np.asarray(curve.knots)[curve.degree : -curve.degree])
    steps = np.linspace(0.0, 1.0, per_span, endpoint=False)
    inside = (breaks[:-1, None] + steps * np.diff(breaks)[:, None]).ravel()
    return np.append(inside, breaks[-1])


@eqx.filter_jit
def _evaluate(curve: NURBSCurve, params, u):
    """Curve points, curvature-comb tips and de Boor's levels at `u`, in one compiled call
    (its shapes stay the same while points, weights and knots are dragged)."""
    ders = curve.derivatives(params, 2)
    points, d1, d2 = ders[:, 0], ders[:, 1], ders[:, 2]
    speed = jnp.linalg.norm(d1, axis=1)
    kappa = safe_divide(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0], speed**3)
    left = safe_divide(jnp.stack([-d1[:, 1], d1[:, 0]], axis=1), speed[:, None])
    net = curve.control_points
    size = jnp.max(jnp.max(net, axis=0) - jnp.min(net, axis=0))
    # The longest tooth is a fifth of the net's size: the comb's shape is what it shows.
    scale = safe_divide(0.2 * size, jnp.max(jnp.abs(kappa)))
    # Teeth point away from the centre of curvature, which lies along `kappa * left`.
    comb = points - scale * kappa[:, None] * left
    return points, comb, de_boor_levels(curve, u)


def _basis_rows(curve: NURBSCurve, u: np.ndarray) -> list:
    """`[first, values]` per function: the samples where `R_{i,p}` is not zero, in order."""
    basis = np.asarray(basis_matrix(curve.knots, curve.degree, u))
    if curve.weights is not None:
        weighted = basis * np.asarray(curve.weights)
        basis = weighted / weighted.sum(axis=1, keepdims=True)
    rows = []
    for column in basis.T:
        support = np.flatnonzero(column > 0)
        first, last = (support[0], support[-1] + 1) if support.size else (0, 0)
        # One sample either side, so that each bump is drawn down to zero.
        first, last = max(first - 1, 0), min(last + 1, len(u))
        rows.append([int(first), _listed(column[first:last])])
    return rows


class _WidgetMeta(type(anywidget.AnyWidget), abc.ABCMeta):
    """traitlets' metaclass with abstract methods enforced."""


class Pictured(metaclass=_WidgetMeta):
    """Mixin of a widget that shows a picture of its state where it cannot run (nbconvert,
    a static site): its display carries a PNG beside the widget view. Put it first among
    the bases, before the widget class."""

    @abc.abstractmethod
    def picture(self) -> bytes:
        """A PNG of what the widget draws now, for pages where it cannot run."""

    def _repr_mimebundle_(self, **kwargs):
        bundle = super()._repr_mimebundle_(**kwargs)
        data, metadata = bundle if isinstance(bundle, tuple) else (bundle, {})
        return {**data, "image/png": self.picture()}, metadata


class _AbstractEditor(Pictured, anywidget.AnyWidget):
    """What the editors share: the browser edits `state` and numbers each edit (`request`);
    the kernel accepts or refuses it (`_accept`) and answers with one `drawing` per edit."""

    _esm = STATIC / "curve_editor.js"
    _css = STATIC / "curve_editor.css"

    # Synchronised with the browser: what it edits ...
    mode = traitlets.Unicode("curve").tag(sync=True)
    width = traitlets.Int(560).tag(sync=True)  # of the plot, in pixels
    height = traitlets.Int(400).tag(sync=True)
    state = traitlets.Dict().tag(sync=True)
    u = traitlets.Float(0.5).tag(sync=True)
    show = traitlets.Dict().tag(sync=True)
    request = traitlets.Int(0).tag(sync=True)
    # ... and what the kernel computes for it to draw.
    drawing = traitlets.Dict().tag(sync=True)

    @abc.abstractmethod
    def _accept(self, state: dict) -> None:
        """Take the browser's `state` (raise `ValueError` to refuse it with a message)."""

    @abc.abstractmethod
    def _draw(self) -> None:
        """Evaluate what the browser draws and set `drawing`, once per state."""

    @traitlets.observe("state", "request", "u", "show")
    def _browser_changed(self, change):
        # One browser message may set several of these traits; every notification lands
        # here after all of them are set, and `_draw` draws each state once.
        self._started = time.perf_counter()
        if self.state != self._accepted:
            try:
                self._accept(self.state)
            except (ValueError, KeyError, TypeError) as error:
                # Back to the last state the kernel accepted; the browser reverts with it.
                self.state = self._accepted
                self.drawing = {**self.drawing, "request": self.request, "error": str(error)}
                return
        self._draw()

    def _publish(self, drawing: dict) -> None:
        # The kernel's share of the latency, from the browser's message to this drawing.
        drawing["kernel_ms"] = 1e3 * (time.perf_counter() - self._started)
        self.drawing = drawing


def png(figure) -> bytes:
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    return buffer.getvalue()


def figure_of(size):
    """A matplotlib figure outside pyplot: drawing it leaves the notebook's backend alone
    (switching pyplot to Agg would make every later `plt.show()` draw nothing)."""
    from matplotlib.figure import Figure

    return Figure(figsize=size, dpi=80)


@typing.final
class CurveEditor(_AbstractEditor):
    """Edit a planar `NURBSCurve` by hand: drag, add and delete control points, change
    weights, drag knots, and watch de Boor's construction, the curvature comb and the
    basis functions follow.

    In the plot: drag a point to move it; double-click on empty space to add a point to
    the nearest leg of the control polygon (the knots become uniform again); right-click
    a point to delete it; turn the mouse wheel over a point to scale its weight (or type
    the weight of the selected point). Under the plot, drag an interior knot along the
    knot strip, or the triangle that sets the parameter of the construction.

    The edited curve is `editor.curve`, a trait you can `observe`; assigning a new curve to
    it updates the drawing. Displayed outside a live Jupyter front end (nbconvert, a
    static site), the widget shows a picture of its state.
    """

    curve = traitlets.Instance(NURBSCurve)

    def __init__(
        self,
        curve: NURBSCurve,
        *,
        u: float | None = None,
        polygon: bool = True,
        construction: bool = False,
        comb: bool = False,
        basis: bool = True,
        samples_per_span: int | None = None,
        **kwargs,
    ):
        """**Arguments:**

        - `curve`: the planar `NURBSCurve` to start from.
        - `u`: the parameter of the construction (default: the middle of the domain).
        - `polygon`, `construction`, `comb`, `basis`: what is drawn at first (each can be
          switched in the widget).
        - `samples_per_span`: curve points per knot span; None gives 24, fewer on long
          curves (about 1200 points in all, at least 4 per span).
        - `kwargs`: passed to `anywidget.AnyWidget`; `width` and `height` size the plot
          (pixels, default 560 x 400).
        """
        if not isinstance(curve, NURBSCurve):
            raise ValueError(f"CurveEditor edits a NURBSCurve, got {type(curve).__name__}")
        if samples_per_span is not None and samples_per_span < 2:
            raise ValueError(f"samples_per_span must be >= 2, got {samples_per_span}")
        self._per_span = samples_per_span
        self._basis_key = self._basis_cache = self._drawn = None
        self._started = time.perf_counter()
        self._accepted = _state_of(curve)
        self._from_browser = None
        lower, upper = (float(x) for x in curve.domain)
        super().__init__(
            curve=curve,
            state=self._accepted,
            u=0.5 * (lower + upper) if u is None else float(u),
            show={"polygon": polygon, "construction": construction, "comb": comb, "basis": basis},
            **kwargs,
        )
        self._draw()

    def _accept(self, state):
        curve = _curve_of(state)
        self._accepted = state
        self._from_browser = curve
        self.curve = curve

    @traitlets.observe("curve")
    def _curve_changed(self, change):
        if change["new"] is not self._from_browser:  # a curve assigned from Python
            self._accepted = _state_of(change["new"])
            self.state = self._accepted
        self._draw()

    def _draw(self):
        """Evaluate what the browser draws, and send it in one message."""
        curve = self.curve
        key = (self.request, id(curve), self.u, tuple(sorted(self.show.items())))
        if key == self._drawn:
            return
        self._drawn = key
        lower, upper = (float(x) for x in curve.domain)
        u = min(max(self.u, lower), upper)
        spans = len(np.unique(np.asarray(curve.knots)[curve.degree : -curve.degree])) - 1
        per_span = self._per_span or max(4, min(24, _SAMPLES // spans))
        # `u` as an array: filter_jit would compile again for every new Python float.
        points, comb, levels = _evaluate(curve, _parameters(curve, per_span), jnp.asarray(u))
        drawing = {"request": self.request, "error": "", "curve": _packed(points)}
        # Samples per non-empty knot span: the browser finds the part of the curve that the
        # selected control point acts on from it.
        drawing["per_span"] = per_span
        if self.show.get("construction"):
            drawing["levels"] = [_listed(level) for level in levels]
            drawing["point"] = _listed(levels[-1][0])
        if self.show.get("comb"):
            drawing["comb"] = _packed(comb)
        if self.show.get("basis"):
            drawing["basis"] = self._basis(curve, lower, upper)
        self._publish(drawing)

    def _basis(self, curve, lower, upper):
        key = (tuple(self._accepted["knots"]), curve.degree, str(self._accepted["weights"]))
        if key != self._basis_key:
            u = np.linspace(lower, upper, 241)
            revision = self._basis_cache["revision"] + 1 if self._basis_cache else 0
            self._basis_cache = {
                "u": _listed(u),
                "rows": _basis_rows(curve, u),
                "revision": revision,
            }
            self._basis_key = key
        return self._basis_cache

    def picture(self) -> bytes:
        """A PNG of what the widget draws now (control polygon, curve, construction,
        comb, basis functions), for pages where the widget cannot run."""
        from matplotlib.collections import LineCollection

        drawing, show = self.drawing, self.show
        rows = 2 if show.get("basis") else 1
        figure = figure_of((6, 5.2 if rows == 2 else 4))
        grid = figure.add_gridspec(rows, 1, height_ratios=[3, 1][:rows])
        ax = figure.add_subplot(grid[0])
        curve = _unpacked(drawing["curve"])
        net = np.asarray(self.curve.control_points)
        if show.get("comb"):
            tips = _unpacked(drawing["comb"])
            teeth = np.stack([curve, tips], axis=1)
            ax.add_collection(LineCollection(teeth, colors="#c9a0dc", linewidths=0.6))
            ax.plot(tips[:, 0], tips[:, 1], color="#8e44ad", lw=0.8)
        if show.get("polygon"):
            ax.plot(net[:, 0], net[:, 1], "o--", color="0.55", lw=1, ms=5)
        ax.plot(curve[:, 0], curve[:, 1], color="#1f6fb4", lw=2)
        if show.get("construction"):
            for level in drawing["levels"][1:]:
                level = np.asarray(level)
                ax.plot(level[:, 0], level[:, 1], "o-", color="#e67e22", lw=1, ms=3)
            ax.plot(*drawing["point"], "o", color="#c0392b", ms=7)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title("interactive in JupyterLab: drag the points", fontsize=9)
        if show.get("basis"):
            panel = figure.add_subplot(grid[1])
            u = np.asarray(drawing["basis"]["u"])
            for first, values in drawing["basis"]["rows"]:
                panel.plot(u[first : first + len(values)], values, lw=1)
            knots = np.asarray(self.curve.knots)
            panel.plot(knots, np.zeros_like(knots), "k|", ms=10)
            panel.set_xlabel("$u$")
        return png(figure)


@typing.final
@dataclasses.dataclass(frozen=True)
class Raster:
    """An image that a `PointsEditor`'s function draws under its lines.

    **Arguments:**

    - `pixels`: `(rows, columns)` grey or `(rows, columns, 3 or 4)` RGB(A) values in
      [0, 1]; row 0 is the top of the image.
    - `extent`: `(x_min, x_max, y_min, y_max)`, where the image lies in the editor's
      coordinates (y up).
    """

    pixels: np.ndarray
    extent: tuple[float, float, float, float] = (0.0, 1.0, 0.0, 1.0)

    def __post_init__(self):
        pixels = np.asarray(self.pixels, dtype=float)
        if pixels.ndim not in (2, 3) or (pixels.ndim == 3 and pixels.shape[2] not in (3, 4)):
            raise ValueError(f"a Raster has (rows, columns[, 3 or 4]) pixels, got {pixels.shape}")
        if len(self.extent) != 4:
            raise ValueError(f"extent must be (x_min, x_max, y_min, y_max), got {self.extent}")
        object.__setattr__(self, "pixels", pixels)

    def png(self) -> bytes:
        """The pixels as PNG bytes (what the browser shows)."""
        from PIL import Image

        rgb = np.round(255 * np.clip(np.nan_to_num(self.pixels), 0.0, 1.0)).astype(np.uint8)
        buffer = io.BytesIO()
        Image.fromarray(rgb).save(buffer, format="PNG", compress_level=1)  # fast, not small
        return buffer.getvalue()


@typing.final
class PointsEditor(_AbstractEditor):
    """Drag points and see what a Python function draws from them: for constructions that
    are not a single NURBS curve (a PH curve through three points, a chain of segments).

    `draw(points)` gets the points as an array `(count, 2)` and returns a dict from a label
    to the points `(m, 2)` of a polyline to draw (the labels make the legend); one value may
    instead be a `Raster`, an image drawn under the lines (a picture being deformed). A
    `ValueError` it raises is shown as the message and the drag is refused.

    With `weights`, every point carries a weight (the mouse wheel over a point, or the
    weight box) and `draw(points, weights)` gets both. With `min_points`, the student may
    add points (double-click: into the nearest leg of the polygon through the points) and
    delete them (right-click), down to `min_points`. The current points and weights are
    `editor.points` and `editor.weights`, traits you can `observe`; after a change that
    `draw` depends on (a setting outside the editor), call `editor.redraw()`.
    """

    points = traitlets.Instance(np.ndarray)
    weights = traitlets.Instance(np.ndarray, allow_none=True)
    min_points = traitlets.Int(0).tag(sync=True)

    def __init__(
        self,
        points: ArrayLike,
        draw: Callable[..., dict],
        *,
        weights: ArrayLike | None = None,
        min_points: int | None = None,
        **kwargs,
    ):
        """**Arguments:**

        - `points`: the starting points, shape `(count, 2)`.
        - `draw`: the function from points (and weights) to labelled polylines (see the
          class).
        - `weights`: positive weights of the points, shape `(count,)`, or None (no weights).
        - `min_points`: None (the count is fixed) or the fewest points that may remain.
        - `kwargs`: passed to `anywidget.AnyWidget`; `width` and `height` size the plot
          (pixels, default 560 x 400).
        """
        points = np.array(points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 2 or len(points) == 0:
            raise ValueError(f"points must have shape (count, 2), got {points.shape}")
        if not callable(draw):
            raise ValueError(f"draw must be a function of the points, got {draw!r}")
        if min_points is not None and not 1 <= min_points <= len(points):
            raise ValueError(f"min_points must lie in [1, {len(points)}], got {min_points}")
        self._function = draw
        self._drawn = None
        self._started = time.perf_counter()
        self._accepted = {"control_points": _exact(points)}
        if weights is not None:
            self._accepted["weights"] = _exact(weights)
        self._min_points = min_points
        # A bad start raises here, before any display.
        points, weights, self._lines = self._checked(self._accepted, len(points))
        super().__init__(
            mode="points",
            points=points,
            weights=weights,
            min_points=min_points or 0,
            state=self._accepted,
            show={},
            **kwargs,
        )
        self._draw()

    def _checked(self, state, count):
        """`(points, weights, lines)` of a state, or `ValueError` saying what is wrong."""
        points = np.asarray(state["control_points"], dtype=float)
        weights = state.get("weights")
        if self._min_points is None and len(points) != count:
            raise ValueError(f"expected {count} points, got {len(points)}")
        if self._min_points is not None and len(points) < self._min_points:
            raise ValueError(f"at least {self._min_points} points stay, got {len(points)}")
        if weights is None:
            return points, None, self._lines_of(points)
        weights = np.asarray(weights, dtype=float)
        if weights.shape != (len(points),) or not np.all(weights > 0):
            raise ValueError(f"expected {len(points)} positive weights, got {weights}")
        return points, weights, self._lines_of(points, weights)

    def redraw(self) -> None:
        """Draw again from the current points: after a change `draw` depends on."""
        self._started = time.perf_counter()
        try:
            self._lines = self._lines_of(self.points, self.weights)
        except ValueError as error:
            self.drawing = {**self.drawing, "error": str(error)}
            return
        self._drawn = None
        self._draw()

    def _lines_of(self, points, weights=None):
        lines = self._function(points) if weights is None else self._function(points, weights)
        if not isinstance(lines, dict):
            raise ValueError(f"draw must return a dict of label -> (m, 2) points, got {lines!r}")
        if sum(isinstance(line, Raster) for line in lines.values()) > 1:
            raise ValueError("draw may return one Raster at most")
        checked = {}
        for label, line in lines.items():
            if isinstance(line, Raster):
                checked[str(label)] = line
                continue
            line = np.asarray(line, dtype=float)
            if line.ndim != 2 or line.shape[1] != 2:
                raise ValueError(f"draw's {label!r} must have shape (m, 2), got {line.shape}")
            checked[str(label)] = line
        return checked

    def _accept(self, state):
        points, weights, self._lines = self._checked(state, len(self.points))
        self._accepted = state
        with self.hold_trait_notifications():
            self.points, self.weights = points, weights

    def _draw(self):
        key = (self.request, id(self._lines))
        if key == self._drawn:
            return
        self._drawn = key
        drawing = {"request": self.request, "error": "", "lines": []}
        for label, line in self._lines.items():
            if isinstance(line, Raster):
                drawing["image"] = {"png": line.png(), "extent": [float(x) for x in line.extent]}
            else:
                drawing["lines"].append({"label": label, "data": _packed(line)})
        self._publish(drawing)

    def picture(self) -> bytes:
        figure = figure_of((6, 4.5))
        ax = figure.add_subplot()
        points = np.asarray(self.points)
        for label, line in self._lines.items():
            if isinstance(line, Raster):
                ax.imshow(np.clip(line.pixels, 0, 1), extent=line.extent, origin="upper")
            else:
                ax.plot(line[:, 0], line[:, 1], lw=2, label=label)
        ax.plot(points[:, 0], points[:, 1], "o", color="0.3", ms=7, label="points (drag them)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(fontsize=8)
        ax.set_title("interactive in JupyterLab: drag the points", fontsize=9)
        return png(figure)
