"""Benchmark cases of the geometry toolkit: a surface of revolution evaluated and
tessellated to 10^6 points, a kinematic sweep on a 500 x 500 grid, knot refinement with
10^3 knots, 10^6 parameters at equal arc length.

splipy revolves and refines too and geomdl refines, so those are timed side by side and
their results compared with diffnurbs's; the tessellation (a pyvista mesh) and the
kinematic sweep (rotation-minimising frame) exist in diffnurbs only. OpenCascade (its
Python bindings, `cadquery-ocp`) is timed on what it does too: equal-arc parameters, curve
and surface intersections, knot removal.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import splipy
import splipy.surface_factory
from cases import Case, Impl
from geomdl import helpers
from OCP import GCPnts, Geom2dAPI, GeomAdaptor, GeomAPI, gp
from scipy import integrate, interpolate, optimize

import diffnurbs as dn
from diffnurbs import io

SIDE = 1000  # revolve: SIDE x SIDE points
SWEEP_SIDE = 500
REFINE_KNOTS = 1000
GEOMDL_KNOTS = 100  # pure Python: the first knots only
EQUAL_ARC = 10**6
SCIPY_ARC = 200  # quad inside brentq per parameter: the first ones only
OCC_ARC = 10**5  # OpenCascade: all of a smaller count (its parameters are read one by one)


def _ready(x):
    return jax.block_until_ready(x)


def _profile(rng: np.random.Generator, n: int = 12, p: int = 3) -> dn.NURBSCurve:
    """A cubic profile in the xz half-plane x > 0, with clamped random interior knots."""
    heights = np.sort(rng.uniform(0.0, 3.0, n))
    points = np.stack([rng.uniform(0.5, 2.0, n), np.zeros(n), heights], axis=1)
    interior = np.sort(rng.uniform(0.0, 1.0, n - p - 1))
    return dn.NURBSCurve(points, p, np.r_[[0.0] * (p + 1), interior, [1.0] * (p + 1)])


def revolve_case(rng: np.random.Generator) -> Case:
    profile = _profile(rng)
    us = jnp.linspace(0.0, 1.0, SIDE)
    vs = jnp.linspace(0.0, 1.0, SIDE)
    revolve_grid = jax.jit(
        lambda c: dn.revolve(c, jnp.zeros(3), jnp.asarray([0.0, 0, 1])).grid(us, vs)
    )
    reference = np.asarray(revolve_grid(profile))
    basis = splipy.BSplineBasis(profile.degree + 1, np.asarray(profile.knots))

    def splipy_revolve():
        curve = splipy.Curve(basis, np.asarray(profile.control_points))
        surface = splipy.surface_factory.revolve(curve)
        return surface(np.array(us), 2 * math.pi * np.array(vs))  # splipy snaps in place

    return Case(
        f"7. revolve a cubic profile (12 points) + evaluate {SIDE}x{SIDE} grid",
        {
            "diffnurbs": Impl(lambda: _ready(revolve_grid(profile)), SIDE * SIDE, reference),
            "scipy": "no revolve",
            "splipy": Impl(splipy_revolve, SIDE * SIDE, reference),
            "geomdl": "no revolve",
        },
        {"splipy": 1},
    )


def tessellate_case(rng: np.random.Generator) -> Case:
    surface = dn.revolve(_profile(rng), [0.0, 0, 0], [0.0, 0, 1])

    def mesh_points():
        return np.asarray(io.tessellate(surface, (SIDE, SIDE)).points)

    reference = mesh_points()
    return Case(
        f"8. tessellate a surface of revolution to a {SIDE}x{SIDE} pyvista mesh",
        {
            "diffnurbs": Impl(mesh_points, SIDE * SIDE, reference),
            "scipy": "no meshes",
            "splipy": "no meshes",
            "geomdl": "not asked (pure Python)",
        },
        {},
    )


def kinematic_sweep_case(rng: np.random.Generator) -> Case:
    profile = dn.circle(0.2, center=(0.0, 0.0, 0.0))
    t = np.linspace(0.0, 1.0, 8)
    path_points = np.stack([4 * t, np.sin(2 * math.pi * t), 0.3 * t**2], axis=1)
    path = dn.NURBSCurve(path_points + 0.01 * rng.standard_normal(path_points.shape), 3)
    sweep = dn.KinematicSweep(profile, path, frame="rmf")
    us = jnp.linspace(0.0, 1.0, SWEEP_SIDE)
    vs = jnp.linspace(0.0, 1.0, SWEEP_SIDE)
    grid = jax.jit(lambda s: s.grid(us, vs))
    reference = np.asarray(grid(sweep))
    return Case(
        f"9. kinematic sweep (rotation-minimising frame) on a {SWEEP_SIDE}x{SWEEP_SIDE} grid",
        {
            "diffnurbs": Impl(lambda: _ready(grid(sweep)), SWEEP_SIDE**2, reference),
            "scipy": "no sweeps",
            "splipy": "its sweep uses the Frenet frame (another surface)",
            "geomdl": "no sweeps",
        },
        {},
    )


def refinement_case(rng: np.random.Generator) -> Case:
    """Knots inserted per second; every library's refined control points are compared."""
    profile = _profile(rng, n=50)
    values = np.sort(rng.uniform(0.0, 1.0, REFINE_KNOTS))
    refine = jax.jit(lambda c, v: c.refine(v).control_points)
    values_jax = jnp.asarray(values)
    reference = np.asarray(refine(profile, values_jax))
    knots, points = np.asarray(profile.knots), np.asarray(profile.control_points)
    basis = splipy.BSplineBasis(profile.degree + 1, knots)

    def splipy_refine():
        curve = splipy.Curve(basis, points)
        curve.insert_knot(list(values))
        return curve.controlpoints

    def geomdl_refine():  # A5.1 one knot at a time (its A5.4 inserts knots of its own)
        points_now, knots_now = [list(p) for p in points], knots.tolist()
        for u in values[:GEOMDL_KNOTS]:
            span = helpers.find_span_linear(profile.degree, knots_now, len(points_now), u)
            points_now = helpers.knot_insertion(profile.degree, knots_now, points_now, u, span=span)
            knots_now = helpers.knot_insertion_kv(knots_now, u, span, 1)
        return points_now

    geomdl_reference = np.asarray(refine(profile, values_jax[:GEOMDL_KNOTS]))
    return Case(
        f"10. knot refinement: {REFINE_KNOTS:,} knots into a cubic with 50 control points",
        {
            "diffnurbs": Impl(lambda: _ready(refine(profile, values_jax)), REFINE_KNOTS, reference),
            "scipy": "refines one knot per call (FITPACK insert)",
            "splipy": Impl(splipy_refine, REFINE_KNOTS, reference),
            "geomdl": Impl(geomdl_refine, GEOMDL_KNOTS, geomdl_reference),
        },
        {"splipy": 1, "geomdl": 10},
    )


def equal_arc_case(rng: np.random.Generator) -> Case:
    """Parameters at equal arc length. No peer has the inverse of the arc length; with scipy
    a user writes it: `brentq` on `quad` of the speed of scipy's B-spline derivative."""
    points = np.cumsum(rng.normal(size=(100, 3)), axis=0)
    curve = dn.NURBSCurve(points, 3)
    equal = jax.jit(lambda c: c.equal_arc_parameters(EQUAL_ARC))
    reference = np.asarray(equal(curve))
    velocity = interpolate.BSpline(np.asarray(curve.knots), points, 3).derivative()
    breaks = np.unique(np.asarray(curve.knots))

    def length(u):
        inside = breaks[(breaks > 0) & (breaks < u)]
        return integrate.quad(lambda t: np.linalg.norm(velocity(t)), 0.0, u,
                              points=inside if len(inside) else None, limit=200)[0]  # fmt: skip

    def scipy_equal():
        total = length(1.0)
        targets = np.arange(SCIPY_ARC) * total / (EQUAL_ARC - 1)
        return [optimize.brentq(lambda u, s=s: length(u) - s, 0.0, 1.0, xtol=1e-14)
                if s > 0 else 0.0 for s in targets]  # fmt: skip

    occ_curve = GeomAdaptor.GeomAdaptor_Curve(dn.io.to_occ(curve))
    occ_reference = np.asarray(jax.jit(lambda c: c.equal_arc_parameters(OCC_ARC))(curve))

    def occ_equal():
        found = GCPnts.GCPnts_UniformAbscissa(occ_curve, OCC_ARC, 1e-12)
        return np.array([found.Parameter(i) for i in range(1, found.NbPoints() + 1)])

    return Case(
        f"19. {EQUAL_ARC:,} parameters at equal arc length, cubic with 100 control points "
        f"(OpenCascade's GCPnts_UniformAbscissa: {OCC_ARC:,} on the same curve)",
        {
            "diffnurbs": Impl(lambda: _ready(equal(curve)), EQUAL_ARC, reference),
            "scipy": Impl(scipy_equal, SCIPY_ARC, reference[:SCIPY_ARC]),
            "splipy": "no inverse arc length",
            "geomdl": "no inverse arc length",
            "OpenCascade": Impl(occ_equal, OCC_ARC, occ_reference),
        },
        {"scipy": 1},
    )


def _plane_curve(curve: dn.NURBSCurve):
    """A planar curve as OpenCascade's `Geom2d_BSplineCurve` (exact: same poles and knots)."""
    plane = gp.gp_Pln(gp.gp_Pnt(0.0, 0.0, 0.0), gp.gp_Dir(0.0, 0.0, 1.0))
    return GeomAPI.GeomAPI.To2d_s(dn.io.to_occ(curve), plane)


def _nearest(points: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """For each point, the nearest of `candidates`."""
    distances = np.linalg.norm(points[:, None] - candidates[None], axis=-1)
    return candidates[np.argmin(distances, axis=1)]


def intersections_case(rng: np.random.Generator) -> Case:
    """All intersections of two random planar cubics with 50 control points each. Only
    OpenCascade intersects NURBS curves (`Geom2dAPI_InterCurveCurve`): its points are
    compared with the nearest of diffnurbs's, and the counts are in the row's name."""
    a = dn.NURBSCurve(rng.normal(size=(50, 2)), 3)
    b = dn.NURBSCurve(rng.normal(size=(50, 2)), 3)
    u1, u2 = dn.curve_intersections(a, b)
    points = np.asarray(a(u1))
    residual = float(np.abs(points - np.asarray(b(u2))).max())
    occ_a, occ_b = _plane_curve(a), _plane_curve(b)

    def intersect():
        return np.asarray(dn.curve_intersections(a, b)[0])

    def occ_intersect():
        found = Geom2dAPI.Geom2dAPI_InterCurveCurve(occ_a, occ_b, 1e-12)
        return np.array([[found.Point(i).X(), found.Point(i).Y()]
                         for i in range(1, found.NbPoints() + 1)])  # fmt: skip

    occ_points = occ_intersect()
    missed = len(points) - len(occ_points)
    return Case(
        f"20. all intersections of two planar cubics, 50 control points each: diffnurbs finds "
        f"{len(u1)} (largest distance between C1(u1) and C2(u2) {residual:.1e}), OpenCascade "
        f"{len(occ_points)} ({missed} missed; each of its points is one of diffnurbs's) "
        "(intersections/s)",
        {
            "diffnurbs": Impl(intersect, len(u1), np.asarray(u1)),
            "scipy": "no curve intersections",
            "splipy": "no curve intersections",
            "geomdl": "no curve intersections",
            "OpenCascade": Impl(
                occ_intersect, len(occ_points), occ_points, lambda p: _nearest(p, points)
            ),
        },
        {},
    )


def simplify_case(rng: np.random.Generator) -> Case:
    """Knot removal: a cubic with 1,000 inserted knots simplified back (knots removed per
    second); geomdl's remove_knot, one knot at a time, on the first 100."""
    curve = _profile(rng, n=20)
    values = np.sort(rng.uniform(0.0, 1.0, REFINE_KNOTS))
    refined = curve.refine(values)
    reference = np.asarray(refined.simplify(1e-9).control_points)

    def geomdl_spline():
        from geomdl import BSpline, operations

        spline = BSpline.Curve()
        spline.degree = refined.degree
        spline.ctrlpts = np.asarray(refined.control_points).tolist()
        spline.knotvector = np.asarray(refined.knots).tolist()
        for u in values[:GEOMDL_KNOTS]:
            operations.remove_knot(spline, [u], [1])
        return spline

    # The same 100 knots removed one at a time by diffnurbs: what geomdl should return.
    partial = refined
    for u in values[:GEOMDL_KNOTS]:
        partial = partial.remove_knot(float(u))[0]

    # Removing inserted knots must leave the curve as it was: geomdl's result is checked
    # against the original curve (its remove_knot has open bugs, geomdl #135 and #136).
    spline = geomdl_spline()
    knots, p = np.asarray(spline.knotvector), refined.degree
    if (knots[p], knots[-p - 1]) != (0.0, 1.0):
        geomdl_wrong = f"its domain is [{knots[p]:.3g}, {knots[-p - 1]:.3g}], not [0, 1]"
    else:
        u = np.linspace(0.0, 1.0, 2001)
        geomdl_curve = dn.NURBSCurve(np.asarray(spline.ctrlpts), p, knots)
        off = float(np.abs(np.asarray(geomdl_curve(u)) - np.asarray(curve(u))).max())
        geomdl_wrong = f"its curve is {off:.2g} away from the original" if off > 1e-9 else ""

    def occ_remove():
        # Geom_BSplineCurve.RemoveKnot(index, multiplicity left, tolerance), in place.
        spline = dn.io.to_occ(refined)
        for u in values:
            index = next(i for i in range(1, spline.NbKnots() + 1) if spline.Knot(i) == u)
            spline.RemoveKnot(index, 0, 1e-9)
        poles = spline.Poles()
        return np.array([[poles.Value(i).Coord(k) for k in (1, 2, 3)]
                         for i in range(1, poles.Length() + 1)])  # fmt: skip

    return Case(
        f"21. simplify: {REFINE_KNOTS:,} inserted knots removed from a cubic with 20 control "
        "points (knots/s)",
        {
            "diffnurbs": Impl(
                lambda: np.asarray(refined.simplify(1e-9).control_points), REFINE_KNOTS, reference
            ),
            "scipy": "no knot removal",
            "splipy": "no knot removal",
            "geomdl": Impl(
                lambda: np.asarray(geomdl_spline().ctrlpts),
                GEOMDL_KNOTS,
                np.asarray(partial.control_points),
                wrong=geomdl_wrong,
            ),
            "OpenCascade": Impl(occ_remove, REFINE_KNOTS, reference),
        },
        {},
    )


def _height_field(rng: np.random.Generator, n: int = 10) -> dn.NURBSSurface:
    """A bicubic surface z = f(x, y) over the unit square, `n x n` random heights."""
    x = np.linspace(0.0, 1.0, n)
    grid = np.stack(np.meshgrid(x, x, indexing="ij"), axis=-1)
    heights = rng.normal(scale=0.2, size=(n, n, 1))
    return dn.NURBSSurface(np.concatenate([grid, heights], axis=-1), (3, 3))


def _project(point: np.ndarray, curves) -> np.ndarray:
    """The nearest point of OpenCascade curves to `point`."""
    best, nearest = np.inf, None
    for curve in curves:
        projection = GeomAPI.GeomAPI_ProjectPointOnCurve(gp.gp_Pnt(*map(float, point)), curve)
        if projection.NbPoints() and projection.LowerDistance() < best:
            best, found = projection.LowerDistance(), projection.NearestPoint()
            nearest = np.array([found.X(), found.Y(), found.Z()])
    return nearest


def surface_intersection_case(rng: np.random.Generator) -> Case:
    """The intersection curves of two random bicubic height fields with 10 x 10 control
    points. OpenCascade: `GeomAPI_IntSS`; its curves are compared with points of
    diffnurbs's (the nearest point of OpenCascade's curves to each). Both fit the curves
    within a tolerance, so they agree to about that, not to rounding."""
    s1, s2 = _height_field(rng), _height_field(rng)
    branches = dn.surface_intersections(s1, s2)
    w = np.linspace(0.0, 1.0, 101)
    points = np.concatenate([np.asarray(b.curve(w)) for b in branches])
    occ_1, occ_2 = dn.io.to_occ(s1), dn.io.to_occ(s2)

    def intersect():
        return [b.curve for b in dn.surface_intersections(s1, s2)]

    def occ_intersect():
        found = GeomAPI.GeomAPI_IntSS(occ_1, occ_2, 1e-7)
        return [found.Line(i) for i in range(1, found.NbLines() + 1)]

    count = len(occ_intersect())
    return Case(
        f"22. intersection curves of two bicubic surfaces, 10 x 10 control points each: "
        f"diffnurbs {len(branches)} branches, OpenCascade {count} curves (surface pairs/s)",
        {
            "diffnurbs": Impl(intersect, 1, points, lambda c: np.concatenate([x(w) for x in c])),
            "scipy": "no surface intersections",
            "splipy": "no surface intersections",
            "geomdl": "no surface intersections",
            "OpenCascade": Impl(
                occ_intersect, 1, points, lambda c: np.array([_project(p, c) for p in points])
            ),
        },
        {},
        tolerance=1e-5,
    )


def cases(rng: np.random.Generator) -> list[Case]:
    return [
        revolve_case(rng),
        tessellate_case(rng),
        kinematic_sweep_case(rng),
        refinement_case(rng),
        equal_arc_case(rng),
        intersections_case(rng),
        simplify_case(rng),
        surface_intersection_case(rng),
    ]
