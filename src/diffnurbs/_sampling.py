"""Even samples of curves and surfaces for drawing and meshing, and the optional pyvista."""

import numpy as np


def import_pyvista():
    """pyvista, imported on first use (the optional "viz" extra)."""
    try:
        import pyvista
    except ImportError as error:
        raise ImportError("diffnurbs.viz needs pyvista: pip install 'diffnurbs[viz]'") from error
    return pyvista


def lift_to_3d(points) -> np.ndarray:
    """Points of dimension <= 3 as NumPy points in 3D (missing coordinates zero)."""
    points = np.asarray(points, dtype=float)
    if points.shape[-1] > 3:
        raise ValueError(f"pyvista draws points of dimension <= 3, got {points.shape[-1]}")
    pad = [(0, 0)] * (points.ndim - 1) + [(0, 3 - points.shape[-1])]
    return np.pad(points, pad)


def even_grid(surface, samples) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`(us, vs, points)`: an even `samples[0] x samples[1]` grid over the surface's
    domain and the surface's points on it, lifted to 3D, shape `(len(us), len(vs), 3)`."""
    (u0, u1), (v0, v1) = surface.domain
    us = np.linspace(float(u0), float(u1), samples[0])
    vs = np.linspace(float(v0), float(v1), samples[1])
    return us, vs, lift_to_3d(surface.grid(us, vs))
