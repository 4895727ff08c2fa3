"""Random splines with repeated interior knots, and naive oracles, shared by the tests."""

import functools

import jax
import numpy as np

import diffnurbs as dn


def random_knots(rng, n_control, degree, domain=(0.0, 1.0)):
    """Clamped knots with random interior knots, some repeated (multiplicity <= degree)."""
    n_interior = n_control - degree - 1
    distinct = np.sort(rng.uniform(*domain, size=n_interior))
    knots = []
    for value in distinct:
        if knots and rng.random() < 0.4 and knots.count(knots[-1]) < degree:
            knots.append(knots[-1])  # repeat the previous knot instead of a new one
        else:
            knots.append(value)
    a, b = domain
    return np.array([a] * (degree + 1) + knots + [b] * (degree + 1))


def random_curve(rng, degree, n_control=None, dim=2, rational=True, domain=(0.0, 1.0)):
    n_control = n_control or degree + 1 + int(rng.integers(0, 6))
    points = rng.normal(size=(n_control, dim))
    weights = rng.uniform(0.3, 3.0, size=n_control) if rational else None
    knots = random_knots(rng, n_control, degree, domain)
    return dn.NURBSCurve(points, degree, knots, weights)


def random_surface(rng, degrees, counts=None, dim=3, rational=True):
    counts = counts or tuple(d + 1 + int(rng.integers(0, 4)) for d in degrees)
    points = rng.normal(size=(*counts, dim))
    weights = rng.uniform(0.3, 3.0, size=counts) if rational else None
    knots = tuple(random_knots(rng, n, d) for n, d in zip(counts, degrees, strict=True))
    return dn.NURBSSurface(points, degrees, knots, weights)


def sample_parameters(rng, knots, degree, count=40):
    """Random parameters plus every distinct knot of the domain, both ends included."""
    knots = np.asarray(knots)
    lower, upper = knots[degree], knots[-degree - 1]
    inside = knots[(knots >= lower) & (knots <= upper)]
    return np.concatenate([np.unique(inside), rng.uniform(lower, upper, size=count)])


@functools.partial(jax.jit, static_argnums=1)
def _cox_de_boor_all(shifted, degree, u):
    """`cox_de_boor(shifted[i], degree, 0, u)` for every row `i`, stacked on the last axis."""
    return jax.vmap(lambda knots: dn.cox_de_boor(knots, degree, 0, u), out_axes=-1)(shifted)


def naive_basis(knots, degree, u):
    """All `N_{i,p}(u)` by the Cox-de Boor recursion, shape `u.shape + (n + 1,)`.

    `N_{i,p}` on `knots` is `N_{0,p}` on `knots[i:]` padded back to full length with copies
    of the last knot: the recursion reads `knots[i:]` only (the degree-0 end test compares
    a tail with its first knot, and the copies of the last knot change no such test). So
    every function is one row of a batch, and the recursion, unrolled into `2^p` terms,
    compiles once per degree and shape instead of once per index `i`.
    """
    knots = np.asarray(knots, float)
    count = len(knots) - degree - 1
    shifted = np.stack([np.r_[knots[i:], np.full(i, knots[-1])] for i in range(count)])
    return np.asarray(_cox_de_boor_all(shifted, degree, u))


def naive_curve(curve, u):
    basis = naive_basis(np.asarray(curve.knots), curve.degree, u)
    points = np.asarray(curve.control_points)
    weights = np.ones(len(points)) if curve.weights is None else np.asarray(curve.weights)
    return (basis * weights) @ points / (basis @ weights)[..., None]


def naive_surface(surface, u, v):
    (knots_u, knots_v), (p, q) = surface.knots, surface.degree
    bu = naive_basis(np.asarray(knots_u), p, u)
    bv = naive_basis(np.asarray(knots_v), q, v)
    points = np.asarray(surface.control_points)
    weights = np.ones(points.shape[:2]) if surface.weights is None else np.asarray(surface.weights)
    numerator = np.einsum("...i,...j,ij,ijd->...d", bu, bv, weights, points)
    return numerator / np.einsum("...i,...j,ij->...", bu, bv, weights)[..., None]


def nine_point_circle(radius=1.0, center=(0.0, 0.0)):
    """The seed's circle: square vertices and edge midpoints, weights 1 and sqrt(2)/2."""
    square = [(1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0)]
    points = radius * np.array(square, dtype=float) + np.asarray(center)
    weights = np.where(np.arange(9) % 2 == 0, 1.0, np.sqrt(2) / 2)
    knots = [0, 0, 0, 0.25, 0.25, 0.5, 0.5, 0.75, 0.75, 1, 1, 1]
    return dn.NURBSCurve(points, 2, knots, weights)


def partial_derivative(function, argnum=0):
    """`d function / d args[argnum]` at a scalar argument, by forward-mode autodiff.

    `jax.jvp` with a unit tangent: what `jax.jacfwd` gives at a scalar argument, without
    its batching over a one-element basis, so nested derivatives compile to about half
    the program.
    """

    def derivative(*args):
        def along(x):
            return function(*args[:argnum], x, *args[argnum + 1 :])

        x = args[argnum]
        return jax.jvp(along, (x,), (jax.numpy.ones_like(x),))[1]

    return derivative


def central_difference(function, x, h=1e-6):
    """The gradient of a scalar `function` at `x` (any shape) by central differences: the
    oracle for gradients that autodiff computes."""
    x = np.asarray(x, dtype=float)
    grad = np.zeros_like(x)
    for index in np.ndindex(x.shape):
        step = np.zeros_like(x)
        step[index] = h
        grad[index] = (function(x + step) - function(x - step)) / (2 * h)
    return grad
