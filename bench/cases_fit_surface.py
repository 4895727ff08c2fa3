"""Benchmark cases for `fit_surface`: 10^5 scattered points, a 20 x 20 bicubic net.

The comparable problem: a height field `z(x, y)` sampled at points mirrored in both axes,
so that the cloud's principal directions are exactly the x and y axes and the PCA
parameters are affine in `x` and `y`. Without penalty and parameter correction
`fit_surface` then solves the least-squares problem of scipy's `LSQBivariateSpline` with
the same interior knots (uniform over the cloud's extent, `kx = ky = 3`): their heights
must agree. scipy fits height fields only; the case with parameter correction (a half
cylinder, which its PCA parameters crowd towards the steep sides) has no scipy peer.
"""

import jax
import jax.numpy as jnp
import numpy as np
from cases import Case, Impl
from scipy.interpolate import LSQBivariateSpline

import diffnurbs as dn

POINTS = 100_000
CONTROL = (20, 20)
CORRECTION_POINTS = 10_000
CORRECTION_STEPS = 8


def _ready(surface):
    jax.block_until_ready(surface.control_points)
    return surface


def _height(x, y):
    return 0.5 * np.cos(2 * x) * np.cos(3 * y) + 0.1 * x**2 * y**2


def _mirrored_height_field(rng: np.random.Generator) -> np.ndarray:
    """POINTS points of `_height` over [-1.2, 1.2] x [-1, 1], mirrored in both axes (the
    heights are even in x and y), so the variances of x, y and z differ and the principal
    directions are the axes."""
    quarter = rng.uniform(0.0, 1.0, (POINTS // 4, 2)) * [1.2, 1.0]
    xy = np.concatenate([quarter, quarter * [-1, 1], quarter * [1, -1], -quarter])
    return np.column_stack([xy, _height(xy[:, 0], xy[:, 1])])


def least_squares_case(rng: np.random.Generator) -> Case:
    points = _mirrored_height_field(rng)
    device = jnp.asarray(points)

    def fit():
        return dn.fit_surface(device, CONTROL, penalty=0.0, correct_parameters=False)

    surface = fit()
    # scipy gets the same interior knots: uniform over the cloud's extent (its bounding
    # box, which is also scipy's default).
    lower, upper = points[:, :2].min(axis=0), points[:, :2].max(axis=0)
    interior = [
        lo + (hi - lo) * np.linspace(0.0, 1.0, n - 3 + 1)[1:-1]  # n - p + 1 breaks
        for lo, hi, n in zip(lower, upper, CONTROL, strict=True)
    ]
    check = rng.uniform(0.0, 1.0, (2000, 2))
    fitted = np.asarray(surface(check[:, 0], check[:, 1]))
    x, y = fitted[:, 0], fitted[:, 1]  # affine in the parameters, to rounding
    error = np.abs(fitted[:, 2] - _height(x, y)).max()
    return Case(
        f"fit_surface: {POINTS:.0e} scattered points of a height field, "
        f"{CONTROL[0]} x {CONTROL[1]} bicubic, least squares (no penalty, PCA parameters, "
        f"no correction; largest error {error:.1e})",
        {
            "diffnurbs": Impl(
                lambda: _ready(fit()),
                POINTS,
                fitted[:, 2],
                lambda s: np.asarray(s(check[:, 0], check[:, 1]))[:, 2],
            ),
            "scipy": Impl(
                lambda: LSQBivariateSpline(
                    points[:, 0], points[:, 1], points[:, 2], *interior, kx=3, ky=3
                ),
                POINTS,
                fitted[:, 2],
                lambda s: s.ev(x, y),
            ),
            "splipy": "not asked",
            "geomdl": "no scattered-data surface fitting",
        },
        {},
    )


def correction_case(rng: np.random.Generator) -> Case:
    theta = rng.uniform(np.radians(10), np.radians(170), CORRECTION_POINTS)
    along = rng.uniform(0.0, 2.0, CORRECTION_POINTS)
    points = jnp.asarray(np.column_stack([np.cos(theta), along, np.sin(theta)]))

    def fit(correct):
        return dn.fit_surface(
            points,
            CONTROL,
            correct_parameters=correct,
            max_steps=CORRECTION_STEPS,
            tol=1e-30,
            full_output=True,
        )

    plain, corrected = fit(False)[1], fit(True)
    surface, report = corrected
    check = np.random.default_rng(1).uniform(0.0, 1.0, (2000, 2))
    return Case(
        f"fit_surface: {CORRECTION_POINTS:.0e} points of a half cylinder, {CONTROL[0]} x "
        f"{CONTROL[1]} bicubic, {CORRECTION_STEPS} rounds of parameter correction: rms "
        f"residual {float(plain.rms_residual):.1e} -> {float(report.rms_residual):.1e} "
        "(fits/s x points)",
        {
            "diffnurbs": Impl(
                lambda: _ready(fit(True)[0]),
                CORRECTION_POINTS,
                np.asarray(surface(check[:, 0], check[:, 1])),
                lambda s: s(check[:, 0], check[:, 1]),
            ),
            "scipy": "fits height fields z(x, y) at fixed (x, y) only: no parameter correction",
            "splipy": "not asked",
            "geomdl": "no scattered-data surface fitting",
        },
        {},
    )


def cases(rng: np.random.Generator) -> list[Case]:
    return [least_squares_case(rng), correction_case(rng)]
