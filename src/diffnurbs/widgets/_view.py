"""`SurfaceView`: a 3D scene in the browser (three.js) whose contents the kernel evaluates."""

import typing

import anywidget
import numpy as np
import traitlets
from jaxtyping import ArrayLike

from .._curve import NURBSCurve
from .._surface import AbstractSurface, NURBSSurface
from ._editors import STATIC, Pictured, figure_of, png


def _space(points) -> np.ndarray:
    """Points `(..., 2)` or `(..., 3)` as `(..., 3)`: planar ones in the plane z = 0."""
    points = np.asarray(points, dtype=float)
    if points.shape[-1] == 2:
        points = np.concatenate([points, np.zeros((*points.shape[:-1], 1))], axis=-1)
    if points.shape[-1] != 3:
        raise ValueError(f"SurfaceView draws points in 2D or 3D, got shape {points.shape}")
    return points


def _floats(points) -> bytes:
    """Coordinates as raw little-endian float32: a binary buffer, what WebGL draws."""
    return np.ascontiguousarray(points, dtype="<f4").tobytes()


@typing.final
class SurfaceView(Pictured, anywidget.AnyWidget):
    """A 3D view of surfaces, curves and points: drag to turn it, scroll to zoom,
    right-drag to pan.

    Add or replace what it shows by name (`surface`, `curve`, `points`) and remove it
    (`remove`); several changes inside `with view.hold_sync():` reach the browser as one
    update. The view draws into one scene for its whole life: an update replaces the
    numbers in place, so memory stays flat however often it is updated, and the camera
    stays where the user turned it (`fit()` frames everything again). The caption is
    plain text above the view.
    """

    _esm = STATIC / "surface_view.js"
    _css = STATIC / "surface_view.css"

    items = traitlets.Dict().tag(sync=True)
    caption = traitlets.Unicode("").tag(sync=True)
    width = traitlets.Int(640).tag(sync=True)
    height = traitlets.Int(420).tag(sync=True)
    direction = traitlets.List(traitlets.Float(), [1.0, -1.0, 0.8]).tag(sync=True)
    reframe = traitlets.Int(0).tag(sync=True)

    def __init__(
        self,
        *,
        caption: str = "",
        width: int = 640,
        height: int = 420,
        direction: ArrayLike = (1.0, -1.0, 0.8),
        **kwargs,
    ):
        """**Arguments:**

        - `caption`: text shown above the view.
        - `width`, `height`: size of the view in pixels.
        - `direction`: from the centre of the scene towards the camera, at first
          (z points up).
        - `kwargs`: passed to `anywidget.AnyWidget`.
        """
        direction = np.asarray(direction, dtype=float)
        if direction.shape != (3,) or not np.any(direction):
            raise ValueError(f"direction must be a non-zero 3-vector, got {direction}")
        super().__init__(
            caption=caption, width=width, height=height, direction=direction.tolist(), **kwargs
        )

    def _set(self, name: str, item: dict) -> None:
        self.items = {**self.items, str(name): item}

    def surface(
        self,
        name: str,
        surface: AbstractSurface,
        *,
        samples: tuple[int, int] = (41, 41),
        color: str = "#8fb3d9",
        opacity: float = 1.0,
        net: bool = False,
    ) -> None:
        """Show `surface` (any `AbstractSurface` in 2D or 3D) as a shaded grid of samples.

        **Arguments:**

        - `name`: its name in the view (a new surface of that name replaces it).
        - `surface`: the surface.
        - `samples`: grid points along `u` and `v`, at least 2 each.
        - `color`, `opacity`: how it is drawn (a CSS colour, 0 to 1).
        - `net`: also draw the control net (a `NURBSSurface` only), named `name + " net"`
          (without it, a net drawn with an earlier surface of that name goes).
        """
        if not isinstance(surface, AbstractSurface):
            raise ValueError(f"surface must be an AbstractSurface, got {type(surface).__name__}")
        rows, columns = (int(s) for s in samples)
        if rows < 2 or columns < 2:
            raise ValueError(f"samples must be at least (2, 2), got {samples}")
        if net and not isinstance(surface, NURBSSurface):
            raise ValueError(f"only a NURBSSurface has a control net, got {type(surface).__name__}")
        (u0, u1), (v0, v1) = surface.domain
        grid = surface.grid(np.linspace(u0, u1, rows), np.linspace(v0, v1, columns))
        item = {"kind": "surface", "shape": [rows, columns], "positions": _floats(_space(grid))}
        with self.hold_sync():
            self._set(name, {**item, "color": color, "opacity": float(opacity)})
            if not net:
                self.remove(f"{name} net")
            else:
                points = _space(surface.control_points)
                self._set(
                    f"{name} net",
                    {
                        "kind": "net",
                        "shape": list(points.shape[:2]),
                        "positions": _floats(points),
                        "color": "#555555",
                    },
                )

    def curve(
        self,
        name: str,
        curve: NURBSCurve | ArrayLike,
        *,
        samples: int = 200,
        color: str = "#222222",
    ) -> None:
        """Show a `NURBSCurve` as a polyline of `samples` points, or a polyline given by
        its points `(count, 2)` or `(count, 3)`; 2D ones lie in the plane z = 0."""
        if isinstance(curve, NURBSCurve):
            if samples < 2:
                raise ValueError(f"samples must be >= 2, got {samples}")
            lower, upper = (float(x) for x in curve.domain)
            curve = curve(np.linspace(lower, upper, samples))
        points = _space(curve)
        if points.ndim != 2 or len(points) < 2:
            raise ValueError(f"a polyline needs points (count >= 2, 3), got {points.shape}")
        item = {"kind": "curve", "count": len(points), "positions": _floats(points)}
        self._set(name, {**item, "color": color})

    def points(self, name: str, points: ArrayLike, *, color: str = "#c0392b") -> None:
        """Show points `(count, 2)` or `(count, 3)` as dots."""
        points = _space(points).reshape(-1, 3)
        item = {"kind": "points", "count": len(points), "positions": _floats(points)}
        self._set(name, {**item, "color": color})

    def remove(self, *names: str) -> None:
        """Take the named items out of the view (unknown names are ignored)."""
        kept = {key: item for key, item in self.items.items() if key not in names}
        if len(kept) < len(self.items):
            self.items = kept

    def fit(self) -> None:
        """Frame everything shown (the camera keeps its place otherwise)."""
        self.reframe += 1

    def picture(self) -> bytes:
        """A PNG of the scene (matplotlib's 3D axes), for pages where the view cannot run."""
        figure = figure_of((self.width / 80, self.height / 80))
        ax = figure.add_subplot(projection="3d")
        for item in self.items.values():
            points = np.frombuffer(item["positions"], dtype="<f4").reshape(-1, 3)
            if item["kind"] in ("surface", "net"):
                x, y, z = points.reshape(*item["shape"], 3).transpose(2, 0, 1)
                if item["kind"] == "surface":
                    ax.plot_surface(x, y, z, color=item["color"], alpha=item["opacity"], lw=0)
                else:
                    ax.plot_wireframe(x, y, z, color=item["color"], lw=0.6)
            elif item["kind"] == "curve":
                ax.plot(*points.T, color=item["color"], lw=1.5)
            else:
                ax.scatter(*points.T, color=item["color"], s=12)
        x, y, z = self.direction
        ax.view_init(np.degrees(np.arctan2(z, np.hypot(x, y))), np.degrees(np.arctan2(y, x)))
        ax.set_aspect("equal")
        ax.set_axis_off()
        title = f"{self.caption}\n(3D view: live in JupyterLab)" if self.caption else ""
        ax.set_title(title or "3D view: live in JupyterLab", fontsize=9)
        return png(figure)
