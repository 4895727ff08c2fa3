"""The benchmark cases: the same NURBS evaluated by diffnurbs, scipy, splipy and geomdl.

Every library gets the same float64 geometry and the same parameters (geomdl, pure
Python, a prefix of them), and its result is compared with diffnurbs's, so the timings
are of equal work. Rational geometry goes to scipy and splipy as homogeneous control
points `(w P, w)`, which is how both represent it.
"""

from collections.abc import Callable
from dataclasses import dataclass

import geomdl.NURBS
import jax
import jax.numpy as jnp
import numpy as np
import splipy
from scipy.interpolate import BSpline, NdBSpline

import diffnurbs as dn

LIBRARIES = ("diffnurbs", "scipy", "splipy", "geomdl", "OpenCascade")
"""OpenCascade (through `cadquery-ocp`) is timed only where it does the same job."""


@dataclass
class Impl:
    """One library's way of doing a case."""

    call: Callable[[], object]  # one timed call; returns the library's result
    points: int  # points evaluated by one call
    reference: np.ndarray  # diffnurbs's result for the same parameters
    convert: Callable[[object], np.ndarray] = np.asarray  # result -> reference layout
    wrong: str = ""  # why the library's result is known to be wrong (shown, not compared)


@dataclass
class Case:
    name: str
    impls: dict[str, "Impl | str"]  # a string says why the library is left out
    targets: dict[str, float]  # library -> smallest acceptable diffnurbs / library ratio
    group: str = ""  # cases of one group are also compared with each other (flatness)
    order_axis: int | None = None  # axis of the derivative order, compared order by order
    tolerance: float | None = None  # accepted difference, if not run.py's (approximations)


def discrepancy(result: np.ndarray, reference: np.ndarray, order_axis: int | None) -> float:
    """Largest difference relative to the size of the values (per derivative order)."""
    result, reference = np.asarray(result), np.asarray(reference)
    if result.shape != reference.shape:
        raise ValueError(f"shape {result.shape} differs from diffnurbs's {reference.shape}")
    if order_axis is None:
        return float(np.max(np.abs(result - reference)) / max(1.0, np.max(np.abs(reference))))
    worst = 0.0
    for k in range(reference.shape[order_axis]):
        a, b = np.take(result, k, order_axis), np.take(reference, k, order_axis)
        worst = max(worst, float(np.max(np.abs(a - b)) / max(1.0, np.max(np.abs(b)))))
    return worst


def clamped_random_knots(rng: np.random.Generator, n: int, degree: int) -> np.ndarray:
    """Clamped knots on [0, 1] with random (non-uniform) interior knots."""
    inner = np.sort(rng.uniform(0.0, 1.0, n - degree - 1))
    return np.concatenate([np.zeros(degree + 1), inner, np.ones(degree + 1)])


def parameters(rng: np.random.Generator, count: int, ordered: bool = False) -> np.ndarray:
    """Random parameters in [0, 1], both ends of the domain included.

    Curves get them in increasing order, as when a curve is sampled: scipy's `BSpline`
    then finds each knot span from the previous one in O(1) (on unordered parameters its
    search walks linearly from there, which slows it with many knots).
    """
    u = rng.uniform(0.0, 1.0, count)
    if ordered:
        u.sort()
    u[0], u[-1] = 0.0, 1.0
    return u


def homogeneous(points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    return np.concatenate([points * weights[..., None], weights[..., None]], axis=-1)


def _ready(x):
    return jax.block_until_ready(x)


def _project(h: np.ndarray) -> np.ndarray:
    return h[..., :-1] / h[..., -1:]


def _quotient_rule(a0, a1, a2):
    """`C, C', C''` of `C = A / w` from the homogeneous `(A, w)` and its derivatives."""
    w0, w1, w2 = a0[:, -1:], a1[:, -1:], a2[:, -1:]
    c0 = a0[:, :-1] / w0
    c1 = (a1[:, :-1] - w1 * c0) / w0
    c2 = (a2[:, :-1] - 2 * w1 * c1 - w2 * c0) / w0
    return np.stack([c0, c1, c2], axis=1)


def _geomdl_curve(hw: np.ndarray, knots: np.ndarray, degree: int):
    curve = geomdl.NURBS.Curve()
    curve.degree = degree
    curve.ctrlptsw = hw.tolist()
    curve.knotvector = knots.tolist()
    return curve


def _geomdl_surface(hw: np.ndarray, knots_u, knots_v, degree: int):
    surface = geomdl.NURBS.Surface()
    surface.degree_u = surface.degree_v = degree
    surface.ctrlpts_size_u, surface.ctrlpts_size_v = hw.shape[:2]
    surface.ctrlptsw = hw.reshape(-1, hw.shape[-1]).tolist()  # v runs fastest
    surface.knotvector_u, surface.knotvector_v = knots_u.tolist(), knots_v.tolist()
    return surface


def _splipy_surface(hw: np.ndarray, knots_u, knots_v, degree: int):
    # splipy lists control points with the first parameter direction running fastest.
    flat = hw.transpose(1, 0, 2).reshape(-1, hw.shape[-1])
    basis_u = splipy.BSplineBasis(degree + 1, knots_u)
    basis_v = splipy.BSplineBasis(degree + 1, knots_v)
    return splipy.Surface(basis_u, basis_v, flat, rational=True)


@dataclass
class RationalCurve:
    """A cubic rational curve in 3D as each library holds it."""

    diffnurbs: dn.NURBSCurve
    scipy: BSpline
    splipy: splipy.Curve
    geomdl: geomdl.NURBS.Curve


def rational_curve(rng: np.random.Generator, n: int = 100, p: int = 3) -> RationalCurve:
    points = rng.standard_normal((n, 3))
    weights = rng.uniform(0.5, 2.0, n)
    knots = clamped_random_knots(rng, n, p)
    hw = homogeneous(points, weights)
    return RationalCurve(
        dn.NURBSCurve(points, p, knots, weights),
        BSpline(knots, hw, p),
        splipy.Curve(splipy.BSplineBasis(p + 1, knots), hw, rational=True),
        _geomdl_curve(hw, knots, p),
    )


def curve_points_case(curve: RationalCurve, u: np.ndarray, m: int, m_splipy: int) -> Case:
    """Case 1: points of the rational curve; geomdl gets the first `m` parameters and
    splipy the first `m_splipy` (it builds a sparse matrix of the basis, slowly)."""
    u_jax = jnp.asarray(u)
    evaluate = jax.jit(lambda c, u: c(u))
    ref = np.asarray(evaluate(curve.diffnurbs, u_jax))
    u_splipy = u[:m_splipy].copy()  # splipy snaps parameters near a knot, in place
    return Case(
        f"1. NURBS curve p=3, n=100, 3D: points ({len(u):.0e} u)",
        {
            "diffnurbs": Impl(lambda: _ready(evaluate(curve.diffnurbs, u_jax)), len(u), ref),
            "scipy": Impl(lambda: curve.scipy(u), len(u), ref, _project),
            "splipy": Impl(lambda: curve.splipy(u_splipy), m_splipy, ref[:m_splipy]),
            "geomdl": Impl(lambda: curve.geomdl.evaluate_list(u[:m].tolist()), m, ref[:m]),
        },
        {"scipy": 4, "geomdl": 100},  # issue 15, item 5
    )


def curve_derivatives_case(curve: RationalCurve, u: np.ndarray, m: int) -> Case:
    """Case 2: `C, C', C''` of the rational curve; geomdl gets the first `m` parameters."""
    u_jax = jnp.asarray(u)
    derivatives = jax.jit(lambda c, u: c.derivatives(u, 2))
    ref = np.asarray(derivatives(curve.diffnurbs, u_jax))
    u_splipy = u.copy()  # splipy snaps parameters near a knot onto it, in place
    return Case(
        f"2. same curve: C, C', C'' ({len(u):.0e} u)",
        {
            "diffnurbs": Impl(lambda: _ready(derivatives(curve.diffnurbs, u_jax)), len(u), ref),
            "scipy": Impl(
                lambda: _quotient_rule(*(curve.scipy(u, nu=k) for k in range(3))), len(u), ref
            ),
            "splipy": Impl(
                lambda: [
                    curve.splipy(u_splipy),
                    *(curve.splipy.derivative(u_splipy, d=k) for k in (1, 2)),
                ],
                len(u),
                ref,
                lambda r: np.stack(r, axis=1),
            ),
            "geomdl": Impl(
                lambda: [curve.geomdl.derivatives(t, order=2) for t in u[:m].tolist()],
                m,
                ref[:m],
            ),
        },
        {"scipy": 3, "geomdl": 100},
        order_axis=1,
    )


@dataclass
class RationalSurface:
    """A bicubic rational surface in 3D as each library holds it."""

    diffnurbs: dn.NURBSSurface
    scipy: NdBSpline
    splipy: splipy.Surface
    geomdl: geomdl.NURBS.Surface


def rational_surface(rng: np.random.Generator, n: int = 20, p: int = 3) -> RationalSurface:
    points = rng.standard_normal((n, n, 3))
    weights = rng.uniform(0.5, 2.0, (n, n))
    knots_u, knots_v = clamped_random_knots(rng, n, p), clamped_random_knots(rng, n, p)
    hw = homogeneous(points, weights)
    return RationalSurface(
        dn.NURBSSurface(points, (p, p), knots=(knots_u, knots_v), weights=weights),
        NdBSpline((knots_u, knots_v), hw, p),
        _splipy_surface(hw, knots_u, knots_v, p),
        _geomdl_surface(hw, knots_u, knots_v, p),
    )


def surface_grid_case(surface: RationalSurface, side: int, m: int) -> Case:
    """Case 3: a `side x side` grid; geomdl gets the first rows (about `m` points)."""
    us = np.linspace(0.0, 1.0, side)
    vs = np.linspace(0.0, 1.0, side)
    us_jax, vs_jax = jnp.asarray(us), jnp.asarray(vs)
    grid = jax.jit(lambda s, us, vs: s.grid(us, vs))
    ref = np.asarray(grid(surface.diffnurbs, us_jax, vs_jax))
    # scipy has no grid path: NdBSpline at every grid point, built outside the timing.
    mesh = np.stack(np.meshgrid(us, vs, indexing="ij"), axis=-1).reshape(-1, 2)
    rows = max(1, m // side)
    geomdl_mesh = [tuple(x) for x in mesh[: rows * side].tolist()]
    splipy_uv = us.copy(), vs.copy()  # splipy snaps parameters near a knot, in place
    return Case(
        f"3. NURBS surface 3x3, 20x20, 3D: {side}x{side} grid",
        {
            "diffnurbs": Impl(
                lambda: _ready(grid(surface.diffnurbs, us_jax, vs_jax)), side * side, ref
            ),
            "scipy": Impl(
                lambda: surface.scipy(mesh),
                side * side,
                ref,
                lambda r: _project(r).reshape(side, side, -1),
            ),
            "splipy": Impl(lambda: surface.splipy(*splipy_uv), side * side, ref),
            "geomdl": Impl(
                lambda: surface.geomdl.evaluate_list(geomdl_mesh),
                rows * side,
                ref[:rows],
                lambda r: np.asarray(r).reshape(rows, side, -1),
            ),
        },
        {"splipy": 10, "geomdl": 100},
    )


def surface_points_case(surface: RationalSurface, u: np.ndarray, v: np.ndarray, m: int) -> Case:
    """Case 4: scattered `(u, v)` pairs; geomdl gets the first `m`."""
    u_jax, v_jax = jnp.asarray(u), jnp.asarray(v)
    uv = np.stack([u, v], axis=-1)
    scattered = jax.jit(lambda s, u, v: s(u, v))
    ref = np.asarray(scattered(surface.diffnurbs, u_jax, v_jax))
    geomdl_pairs = [tuple(x) for x in uv[:m].tolist()]
    splipy_uv = u.copy(), v.copy()  # splipy snaps parameters near a knot, in place
    return Case(
        f"4. same surface: {len(u):,} scattered (u, v)",
        {
            "diffnurbs": Impl(
                lambda: _ready(scattered(surface.diffnurbs, u_jax, v_jax)), len(u), ref
            ),
            "scipy": Impl(lambda: surface.scipy(uv), len(u), ref, _project),
            "splipy": Impl(lambda: surface.splipy.evaluate(*splipy_uv, tensor=False), len(u), ref),
            "geomdl": Impl(lambda: surface.geomdl.evaluate_list(geomdl_pairs), m, ref[:m]),
        },
        {"scipy": 2, "geomdl": 100},
    )


def scaling_cases(rng: np.random.Generator, sizes: dict) -> list[Case]:
    """Case 5: a cubic non-rational curve with 10 ... 10^4 control points."""
    p = 3
    u = parameters(rng, sizes["scaling"], ordered=True)
    u_jax = jnp.asarray(u)
    evaluate = jax.jit(lambda c, u: c(u))
    cases = []
    for n in sizes["scaling_controls"]:
        points = rng.standard_normal((n, 3))
        knots = clamped_random_knots(rng, n, p)
        curve = dn.NURBSCurve(points, p, knots)
        scipy_curve = BSpline(knots, points, p)
        ref = np.asarray(evaluate(curve, u_jax))
        cases.append(
            Case(
                f"5. B-spline curve p=3, n={n:,} ({len(u):.0e} u)",
                {
                    "diffnurbs": Impl(lambda c=curve: _ready(evaluate(c, u_jax)), len(u), ref),
                    "scipy": Impl(lambda b=scipy_curve: b(u), len(u), ref),
                    "splipy": "not asked",
                    "geomdl": "not asked",
                },
                {"scipy": 4},  # issue 15, item 5: at every n, and flat in n (run.py)
                group="scaling",
            )
        )
    return cases


def all_cases(seed: int, sizes: dict) -> list[Case]:
    rng = np.random.default_rng(seed)
    curve = rational_curve(rng)
    surface = rational_surface(rng)
    return [
        curve_points_case(
            curve,
            parameters(rng, sizes["curve"], ordered=True),
            sizes["geomdl_curve"],
            sizes["splipy_curve"],
        ),
        curve_derivatives_case(
            curve, parameters(rng, sizes["derivatives"], ordered=True), sizes["geomdl_derivatives"]
        ),
        surface_grid_case(surface, sizes["grid_side"], sizes["geomdl_surface"]),
        surface_points_case(
            surface,
            parameters(rng, sizes["scattered"]),
            parameters(rng, sizes["scattered"]),
            sizes["geomdl_surface"],
        ),
        *scaling_cases(rng, sizes),
    ]
