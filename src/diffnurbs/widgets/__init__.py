"""Jupyter widgets for direct manipulation (anywidget; `dn.widgets` is imported on first use).

- `CurveEditor`: drag the control points, weights and knots of a planar `NURBSCurve`.
- `PointsEditor`: drag points and see what a Python function draws from them (lines, and a
  `Raster` image under them).
- `SurfaceView`: a 3D view of surfaces, curves and points, updated in place.
- `MotionEditor`: sketch a profile and extrude, revolve or sweep it, live in 3D.

The browser draws and reports edits; the kernel evaluates every curve and surface with the
library, so what a widget shows is exactly what its Python value computes. Displayed where
no widget can run (nbconvert, a static site), each shows a picture of its state.
"""

from ._editors import (
    CurveEditor as CurveEditor,
    PointsEditor as PointsEditor,
    Raster as Raster,
)
from ._motion_editor import MotionEditor as MotionEditor
from ._view import SurfaceView as SurfaceView
