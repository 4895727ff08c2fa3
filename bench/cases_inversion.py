"""Benchmark cases for point inversion: the closest point of a cubic curve to 10^5 query
points, and of a bicubic surface to 10^4.

Neither scipy, splipy nor geomdl inverts points. The curve case gives scipy the method a
scipy user would write: a k-d tree of dense samples for the start, then Newton steps on
`BSpline` derivatives, vectorised in numpy (built outside the timing: the tree and the
spline). Both answers are compared as distances from the query points, which do not depend
on how a tie between equally near points is broken.
"""

import jax
import jax.numpy as jnp
import numpy as np
from cases import Case, Impl, clamped_random_knots
from scipy.interpolate import BSpline
from scipy.spatial import cKDTree

import diffnurbs as dn

QUERIES = 100_000
SURFACE_QUERIES = 10_000  # the start search compares each query with ~10^4 grid segments
TREE_SAMPLES = 100_001
NEWTON_STEPS = 12


def _ready(x):
    return jax.block_until_ready(x)


def _curve(rng: np.random.Generator) -> dn.NURBSCurve:
    """A non-rational cubic space curve with 30 control points on random knots."""
    count = 30
    points = np.cumsum(rng.standard_normal((count, 3)), axis=0)
    return dn.NURBSCurve(jnp.asarray(points), 3, jnp.asarray(clamped_random_knots(rng, count, 3)))


def _near(rng: np.random.Generator, points: np.ndarray, count: int = QUERIES) -> jnp.ndarray:
    """`count` query points scattered around the given points."""
    picks = points[rng.integers(0, len(points), count)]
    return jnp.asarray(picks + 0.5 * rng.standard_normal(picks.shape))


def scipy_closest(spline: BSpline, tree: cKDTree, samples: np.ndarray, queries: np.ndarray):
    """Nearest of the dense samples, then Newton steps on |C(u) - P|^2, clamped to the
    domain, each kept only where it brings the curve nearer."""
    u = samples[tree.query(queries)[1]]
    first, second = spline.derivative(1), spline.derivative(2)
    distance = np.sum((spline(u) - queries) ** 2, -1)
    for _ in range(NEWTON_STEPS):
        residual, d1, d2 = spline(u) - queries, first(u), second(u)
        gradient = np.sum(d1 * residual, -1)
        hessian = np.sum(d1 * d1, -1) + np.sum(d2 * residual, -1)
        hessian = np.where(hessian > 0, hessian, np.sum(d1 * d1, -1))  # Gauss-Newton
        trial = np.clip(u - gradient / hessian, 0.0, 1.0)
        trial_distance = np.sum((spline(trial) - queries) ** 2, -1)
        better = trial_distance <= distance
        u, distance = np.where(better, trial, u), np.where(better, trial_distance, distance)
    return u


def curve_case(rng: np.random.Generator) -> Case:
    curve = _curve(rng)
    queries = _near(rng, np.asarray(curve(jnp.linspace(0.0, 1.0, 1000))))
    invert = jax.jit(lambda c, q: c.closest_point(q))
    host = np.asarray(queries)

    def distances(u):
        return np.linalg.norm(np.asarray(curve(jnp.asarray(u))) - host, axis=-1)

    spline = BSpline(np.asarray(curve.knots), np.asarray(curve.control_points), 3)
    samples = np.linspace(0.0, 1.0, TREE_SAMPLES)
    tree = cKDTree(spline(samples))
    reference = distances(invert(curve, queries))
    return Case(
        f"17. closest point on a cubic space curve (30 control points), {QUERIES:.0e} queries",
        {
            "diffnurbs": Impl(
                lambda: _ready(invert(curve, queries)), QUERIES, reference, distances
            ),
            "scipy": Impl(
                lambda: scipy_closest(spline, tree, samples, host), QUERIES, reference, distances
            ),
            "splipy": "no point inversion",
            "geomdl": "no point inversion",
        },
        {},
    )


def surface_case(rng: np.random.Generator) -> Case:
    count = 10
    knots = tuple(jnp.asarray(clamped_random_knots(rng, count, 3)) for _ in range(2))
    grid = np.stack(np.meshgrid(np.arange(count), np.arange(count), indexing="ij"), -1)
    height = 0.6 * rng.standard_normal((count, count, 1))
    surface = dn.NURBSSurface(jnp.asarray(np.concatenate([grid, height], -1)), (3, 3), knots)
    net = surface.grid(jnp.linspace(0, 1, 50), jnp.linspace(0, 1, 50))
    queries = _near(rng, np.asarray(net).reshape(-1, 3), SURFACE_QUERIES)
    invert = jax.jit(lambda s, q: jnp.stack(s.closest_point(q), -1))
    host = np.asarray(queries)

    def distances(uv):
        uv = jnp.asarray(uv)
        return np.linalg.norm(np.asarray(surface(uv[:, 0], uv[:, 1])) - host, axis=-1)

    return Case(
        f"18. closest point on a bicubic surface (10 x 10 control points), "
        f"{SURFACE_QUERIES:.0e} queries",
        {
            "diffnurbs": Impl(
                lambda: _ready(invert(surface, queries)),
                SURFACE_QUERIES,
                distances(invert(surface, queries)),
                distances,
            ),
            "scipy": "no point inversion",
            "splipy": "no point inversion",
            "geomdl": "no point inversion",
        },
        {},
    )


def cases(rng: np.random.Generator) -> list[Case]:
    return [curve_case(rng), surface_case(rng)]
