"""`MotionEditor`: seed 000's surfaces of motion, made live (a profile editor beside a 3D view)."""

import html
import math
import pathlib
import typing

import ipywidgets
import numpy as np
import traitlets

from .._curve import NURBSCurve
from .._frames import KinematicSweep
from .._motion import extrude, revolve, sweep
from .._surface import AbstractSurface, NURBSSurface
from ._editors import CurveEditor, Pictured
from ._view import SurfaceView

OPERATIONS = ("extrude", "revolve", "sweep", "kinematic sweep")
FORMATS = ("stl", "obj", "vtk")


def _upright(curve: NURBSCurve) -> NURBSCurve:
    """The sketch `(x, y)` placed upright in space, in the plane y = 0: `(x, 0, y)`."""
    points = np.asarray(curve.control_points)
    space = np.stack([points[:, 0], np.zeros(len(points)), points[:, 1]], axis=1)
    return NURBSCurve(space, curve.degree, curve.knots, curve.weights)


def _default_path() -> NURBSCurve:
    """A cubic that leaves the sketch plane and bends in two directions."""
    net = [[0.0, 0.0, 0.0], [0.3, 1.5, 0.4], [-1.2, 2.8, 1.0], [0.2, 4.2, 1.6], [1.2, 5.0, 0.8]]
    return NURBSCurve(np.asarray(net), 3)


def _slider(description, value, low, high, step):
    return ipywidgets.FloatSlider(
        value=value, min=low, max=high, step=step, description=description,
        continuous_update=True, style={"description_width": "initial"},
    )  # fmt: skip


@typing.final
class MotionEditor(Pictured, ipywidgets.VBox):
    """Sketch a profile and move it through space: the surface of motion follows live (the
    editor of seed 000, chapter 3).

    On the left, the profile: a planar `NURBSCurve` in a `CurveEditor` (drag, add and
    delete points, weights, knots). It stands upright in space, `(x, y) -> (x, 0, y)`,
    except for the kinematic sweep. On the right, the surface it makes, in a
    `SurfaceView` that keeps its camera between updates. The motions:

    - *extrude*: along the y axis tilted by `tilt` degrees towards x, by `length`
      (`extrude`, exact);
    - *revolve*: about the vertical axis through `(offset, 0, 0)` (drawn in black), by
      `angle` degrees (`revolve`, exact);
    - *sweep*: the profile translated along `path`, keeping its orientation (`sweep`,
      exact: seed eq. 2.4);
    - *kinematic sweep*: the profile carried by the path's rotation-minimising or Frenet
      frame, its `(x, y)` coordinates in the normal plane (`KinematicSweep`, seed eq. 2.8;
      not a NURBS surface).

    Below, *export* writes the surface's triangle mesh as STL, OBJ or VTK (`export`).
    The current surface is `editor.surface`, a trait you can `observe`; the profile's
    editor is `editor.profile`, the 3D view `editor.view`.
    """

    surface = traitlets.Instance(AbstractSurface)

    def __init__(
        self,
        profile: NURBSCurve,
        *,
        operation: str = "revolve",
        path: NURBSCurve | None = None,
        samples: tuple[int, int] = (48, 48),
    ):
        """**Arguments:**

        - `profile`: the planar `NURBSCurve` to start from.
        - `operation`: one of `"extrude"`, `"revolve"`, `"sweep"`, `"kinematic sweep"`.
        - `path`: the 3D `NURBSCurve` of the two sweeps (default: a bending cubic).
        - `samples`: grid points of the drawn surface along `u` and `v`.
        """
        if operation not in OPERATIONS:
            raise ValueError(f"operation must be one of {OPERATIONS}, got {operation!r}")
        path = _default_path() if path is None else path
        if not isinstance(path, NURBSCurve) or path.dim != 3:
            raise ValueError("path must be a NURBSCurve in 3D")
        self.path, self.samples = path, tuple(samples)
        # Side by side in a notebook's width; on a narrower page the view goes below.
        self.profile = CurveEditor(profile, basis=False, width=400, height=380)
        self.view = SurfaceView(width=430, height=440)
        self.profile.layout.width, self.view.layout.width = "410px", "440px"
        self.choice = ipywidgets.ToggleButtons(options=OPERATIONS, value=operation)
        self.parameters = {
            "extrude": [_slider("length", 2.0, 0.2, 5.0, 0.1), _slider("tilt°", 0, -60, 60, 1)],
            "revolve": [_slider("angle°", 360, 5, 360, 5), _slider("offset", 0, -2, 2, 0.05)],
            "sweep": [],
            "kinematic sweep": [ipywidgets.ToggleButtons(options=("rmf", "frenet"))],
        }
        self.message = ipywidgets.HTML()
        self.file_format = ipywidgets.Dropdown(options=FORMATS, layout={"width": "6em"})
        self.file_name = ipywidgets.Text(
            "surface", description="export as", layout={"width": "16em"}
        )
        save = ipywidgets.Button(description="export", icon="download")
        save.on_click(lambda _: self._export_clicked())
        self.controls = ipywidgets.HBox()
        super().__init__(
            [
                self.choice,
                self.controls,
                ipywidgets.HBox([self.profile, self.view], layout={"flex_flow": "row wrap"}),
                ipywidgets.HBox([self.file_name, self.file_format, save]),
                self.message,
            ]
        )
        self.choice.observe(lambda _: self._operation_changed(), "value")
        for control in (c for controls in self.parameters.values() for c in controls):
            control.observe(lambda _: self._update(), "value")
        self.profile.observe(lambda _: self._update(), "curve")
        self._operation_changed()

    def _operation_changed(self):
        self.controls.children = self.parameters[self.choice.value]
        self._update()
        self.view.fit()

    def _values(self):
        return [control.value for control in self.parameters[self.choice.value]]

    def make(self, operation: str, values: list) -> AbstractSurface:
        """The surface of `operation` with its controls at `values` (as listed in
        `editor.parameters[operation]`), from the current profile."""
        curve = self.profile.curve
        if operation == "extrude":
            length, tilt = values
            tilt = math.radians(tilt)
            return extrude(_upright(curve), np.array([math.sin(tilt), math.cos(tilt), 0.0]), length)
        if operation == "revolve":
            angle, offset = values
            axis_point, up = np.array([offset, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
            return revolve(_upright(curve), axis_point, up, math.radians(angle))
        if operation == "sweep":
            return sweep(_upright(curve), self.path)
        return KinematicSweep(curve, self.path, values[0])

    def _update(self):
        operation = self.choice.value
        try:
            surface = self.make(operation, self._values())
        except ValueError as error:
            self.message.value = f"<span style='color:#b03a2e'>{html.escape(str(error))}</span>"
            return
        self.message.value = ""
        with self.view.hold_sync():
            self.view.caption = self._caption(operation, surface)
            nurbs = isinstance(surface, NURBSSurface)
            self.view.surface("surface", surface, samples=self.samples, opacity=0.9, net=nurbs)
            self.view.curve("profile", _start_of(surface), color="#c0392b")
            if operation in ("sweep", "kinematic sweep"):
                self.view.curve("path", self.path, color="#2c3e50")
            else:
                self.view.remove("path")
            if operation == "revolve":  # the axis, a little longer than the profile is high
                heights = np.asarray(self.profile.curve.control_points)[:, 1]
                ends = [heights.min() - 0.3, heights.max() + 0.3]
                offset = self._values()[1]
                self.view.curve("axis", [[offset, 0.0, z] for z in ends], color="#000000")
            else:
                self.view.remove("axis")
        self.surface = surface

    @staticmethod
    def _caption(operation, surface):
        if isinstance(surface, NURBSSurface):
            rows, columns = surface.control_points.shape[:2]
            return (
                f"{operation}: an exact NURBS surface, {rows} x {columns} control points, "
                f"degree {tuple(surface.degree)}"
            )
        return f"kinematic sweep ({surface.frame} frame): not a NURBS surface, evaluated pointwise"

    def picture(self) -> bytes:
        """The 3D view's picture (the profile is drawn in it), for pages where the editor
        cannot run."""
        return self.view.picture()

    def export(self, path: str | pathlib.Path) -> pathlib.Path:
        """Write the current surface's triangle mesh (`io.tessellate` at `samples`) to
        `path`; its suffix picks the format: `.stl`, `.obj` or `.vtk`. Returns the path."""
        from .. import io

        path = pathlib.Path(path)
        if path.suffix.lstrip(".") not in FORMATS:
            raise ValueError(f"export writes {', '.join(FORMATS)} files, got {path.name!r}")
        io.tessellate([self.surface], samples=self.samples).save(path)
        return path

    def _export_clicked(self):
        try:
            path = self.export(f"{self.file_name.value}.{self.file_format.value}")
        except (ValueError, OSError) as error:
            self.message.value = f"<span style='color:#b03a2e'>{html.escape(str(error))}</span>"
            return
        self.message.value = f"wrote <code>{html.escape(str(path.resolve()))}</code>"


def _start_of(surface: AbstractSurface) -> np.ndarray:
    """The profile where the motion starts, `S(u, v_min)`, as 200 points."""
    (u0, u1), (v0, _) = surface.domain
    return np.asarray(surface.grid(np.linspace(u0, u1, 200), np.asarray([v0])))[:, 0]
