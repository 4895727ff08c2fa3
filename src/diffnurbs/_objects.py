"""Objects made of bicubic Bezier patches: surfaces of revolution in the `.bpt` style.

A `.bpt` patch has no weights, so circles are approximated the way the Utah teapot does
it: each quarter circle is the cubic Bezier with handles of length `k r`,
`k = 4/3 tan(pi/8)`, whose radius is exact at the ends and the middle and off by at most
2.7e-4 r in between.
"""

import math

import jax.numpy as jnp
import numpy as np

from ._curve import NURBSCurve
from ._surface import NURBSSurface

QUARTER_HANDLE = 4.0 / 3.0 * math.tan(math.pi / 8)

# Profiles (distance from the z axis, height) of the objects shipped in diffnurbs/data,
# as control points of clamped uniform cubic B-splines.
PROFILES = {
    "vase": [
        (0.0, 0.0),
        (0.9, 0.0),
        (1.0, 0.1),
        (1.3, 0.8),
        (0.5, 1.8),
        (0.45, 2.4),
        (0.7, 2.9),
        (0.75, 3.0),
    ],
    "cup": [(0.0, 0.0), (0.8, 0.0), (0.85, 0.05), (0.95, 0.6), (1.05, 1.4), (1.1, 1.6)],
    "bell": [
        (0.0, 2.2),
        (0.35, 2.2),
        (0.45, 1.9),
        (0.55, 1.0),
        (0.9, 0.4),
        (1.3, 0.05),
        (1.35, 0.0),
    ],
}


def _unit_quarters():
    """Control points of the four cubic quarter circles of radius 1, shape (4, 4, 2)."""
    quarters = []
    for k in range(4):
        start, end = k * math.pi / 2, (k + 1) * math.pi / 2
        a = np.array([math.cos(start), math.sin(start)])
        b = np.array([math.cos(end), math.sin(end)])
        turn = np.array([[0.0, -1.0], [1.0, 0.0]])  # a quarter turn: the tangent direction
        quarters.append([a, a + QUARTER_HANDLE * turn @ a, b - QUARTER_HANDLE * turn @ b, b])
    return np.array(quarters)


def revolution_patches(profile: NURBSCurve) -> list[NURBSSurface]:
    """Bicubic Bezier patches approximating the revolution of a profile about the z axis.

    **Arguments:**

    - `profile`: a non-rational cubic curve of points `(r, z)`, `r >= 0` the distance from
      the axis.

    **Returns:**

    Four patches (one per quarter turn) for every Bezier piece of the profile; `u` runs
    along the profile, `v` around the axis.
    """
    if profile.degree != 3 or profile.rational or profile.dim != 2:
        raise ValueError(
            "revolution_patches needs a non-rational cubic profile of points (r, z), got "
            f"degree {profile.degree}, rational = {profile.rational}, dim = {profile.dim}"
        )
    quarters = jnp.asarray(_unit_quarters(), dtype=profile.control_points.dtype)
    patches = []
    for piece in profile.decompose():
        radius, height = piece.control_points[:, 0], piece.control_points[:, 1]
        for quarter in quarters:
            xy = radius[:, None, None] * quarter[None, :, :]
            z = jnp.broadcast_to(height[:, None, None], (4, 4, 1))
            patches.append(NURBSSurface(jnp.concatenate([xy, z], axis=-1), (3, 3)))
    return patches


def design_object(name: str) -> list[NURBSSurface]:
    """The patches of one of the course's objects: "vase", "cup" or "bell"."""
    if name not in PROFILES:
        raise ValueError(f"unknown object {name!r}, expected one of {sorted(PROFILES)}")
    return revolution_patches(NURBSCurve(np.array(PROFILES[name]), 3))
