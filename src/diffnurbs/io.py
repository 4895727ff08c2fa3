"""Files: Bezier patch files (`.bpt`: a patch count, then per patch its degrees `p q` and
the `(p + 1)(q + 1)` control points `x y z`, row by row, the format of the Utah teapot file),
meshes (`tessellate`, `export_mesh`), and CAD exchange (`write_cad`, `read_cad`: STEP and
`.3dm`, see `_cad`)."""

from importlib import resources
from pathlib import Path

import numpy as np

from ._cad import read_cad as read_cad, to_occ as to_occ, write_cad as write_cad
from ._halfedge import merge_labels
from ._sampling import even_grid, import_pyvista
from ._surface import AbstractSurface, NURBSSurface

_MESH_SUFFIXES = (".stl", ".obj", ".vtk", ".vtp", ".ply")


def _numbers(path):
    try:
        return Path(path).read_text().split()
    except OSError as error:
        raise ValueError(f"cannot read the Bezier patch file {path}: {error}") from error


def load_object(name: str) -> list[NURBSSurface]:
    """The Bezier patches of an object shipped with diffnurbs ("vase", "cup", "bell").

    The files in `diffnurbs/data` are written by `tools/make_objects.py` from the profiles
    in `diffnurbs._objects`; a test keeps them in sync.
    """
    path = resources.files("diffnurbs") / "data" / f"{name}.bpt"
    if not path.is_file():
        shipped = sorted(p.name for p in (resources.files("diffnurbs") / "data").iterdir())
        raise ValueError(f"no object {name!r}; shipped: {shipped}")
    return read_bpt(path)


def read_bpt(path) -> list[NURBSSurface]:
    """Read the Bezier patches of a `.bpt` file.

    **Arguments:**

    - `path`: the file.

    **Returns:**

    One non-rational `NURBSSurface` per patch, control points of shape `(p + 1, q + 1, 3)`.
    """
    tokens, position = _numbers(path), 0

    def take(count, what):
        nonlocal position
        if position + count > len(tokens):
            raise ValueError(f"{path}: the file ends inside {what} (expected {count} more numbers)")
        chunk = tokens[position : position + count]
        position += count
        try:
            return np.asarray(chunk, dtype=float)
        except ValueError as error:
            raise ValueError(f"{path}: {what} must be numbers, got {chunk}") from error

    count = take(1, "the patch count")[0]
    if count != int(count) or count < 0:
        raise ValueError(f"{path}: the patch count must be a non-negative integer, got {count}")
    patches = []
    for k in range(int(count)):
        p, q = take(2, f"the degrees of patch {k}").astype(int)
        points = take(3 * (p + 1) * (q + 1), f"the control points of patch {k}")
        patches.append(NURBSSurface(points.reshape(p + 1, q + 1, 3), (int(p), int(q))))
    if position != len(tokens):
        raise ValueError(
            f"{path}: {len(tokens) - position} numbers left after the {int(count)} patches "
            "the file announces"
        )
    return patches


def write_bpt(path, patches) -> None:
    """Write non-rational Bezier patches (3D, default knots) to a `.bpt` file.

    **Arguments:**

    - `path`: the file to write.
    - `patches`: `NURBSSurface` objects, each a single Bezier patch.
    """
    lines = [str(len(patches))]
    for k, patch in enumerate(patches):
        p, q = patch.degree
        points = np.asarray(patch.control_points)
        if patch.rational or points.shape != (p + 1, q + 1, 3):
            raise ValueError(
                f"patch {k} must be a non-rational Bezier patch in 3D with (p + 1, q + 1) = "
                f"{(p + 1, q + 1)} control points, got shape {points.shape}"
            )
        lines.append(f"{p} {q}")
        lines.extend(" ".join(repr(float(x)) for x in point) for point in points.reshape(-1, 3))
    Path(path).write_text("\n".join(lines) + "\n")


def _grid_triangles(rows: int, cols: int) -> np.ndarray:
    """The two triangles of every cell of a `rows x cols` point grid (row-major indices)."""
    index = np.arange(rows * cols).reshape(rows, cols)
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return np.concatenate([np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)])


def _weld(points: np.ndarray, triangles: np.ndarray, tolerance: float):
    """Merge points closer than `tolerance` times the bounding-box diagonal; drop the
    triangles that collapse and the points no triangle uses (vectorised: see
    `HalfEdgeMesh`'s `weld_vertices` for general polygons)."""
    radius = tolerance * max(float(np.linalg.norm(np.ptp(points, axis=0))), 1e-300)
    triangles = merge_labels(points, radius)[triangles]
    distinct = (
        (triangles[:, 0] != triangles[:, 1])
        & (triangles[:, 1] != triangles[:, 2])
        & (triangles[:, 0] != triangles[:, 2])
    )
    triangles = triangles[distinct]
    used = np.zeros(len(points), dtype=bool)
    used[triangles] = True
    renumber = np.cumsum(used) - 1
    return points[used], renumber[triangles]


def tessellate(surfaces, samples=(24, 24)):
    """One triangle mesh (`pyvista.PolyData`) sampling every surface on an even grid.

    Neighbouring patches evaluate their shared border separately, and closed surfaces
    repeat their seam and collapse rows at poles, so copies agree only to rounding: points
    closer than 1e-9 of the mesh's bounding-box diagonal are merged and triangles that
    collapse are dropped. Vectorised (a k-d tree finds the pairs): a million points take
    about a second.

    **Arguments:**

    - `surfaces`: a surface (`NURBSSurface`, `CoonsPatch`, `KinematicSweep`) of
      dimension <= 3 or a list of them (e.g. the patches of an object).
    - `samples`: grid points per patch along `u` and `v`.

    **Returns:**

    The welded triangle mesh.
    """
    surfaces = [surfaces] if isinstance(surfaces, AbstractSurface) else list(surfaces)
    if not surfaces:
        raise ValueError("tessellate needs at least one surface")
    cell_triangles = _grid_triangles(*samples)
    points, triangles = [], []
    for surface in surfaces:
        triangles.append(cell_triangles + sum(len(p) for p in points))
        points.append(even_grid(surface, samples)[2].reshape(-1, 3))
    points, triangles = _weld(np.concatenate(points), np.concatenate(triangles), 1e-9)
    faces = np.hstack([np.full((len(triangles), 1), 3), triangles]).ravel()
    return import_pyvista().PolyData(points, faces)


def export_mesh(path, surfaces, samples=(24, 24)) -> None:
    """Write the tessellated surfaces as STL, OBJ, VTK, VTP or PLY (chosen by the suffix).

    **Arguments:**

    - `path`: the file to write; its suffix picks the format.
    - `surfaces`: a surface or a list of them.
    - `samples`: grid points per patch along `u` and `v`.
    """
    suffix = Path(path).suffix.lower()
    if suffix not in _MESH_SUFFIXES:
        raise ValueError(f"mesh format {suffix!r} not supported, expected one of {_MESH_SUFFIXES}")
    tessellate(surfaces, samples).save(str(path))
