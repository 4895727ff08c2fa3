"""Benchmark cases for smoothing splines: `smooth` of 10^5 noisy samples of y(x) against
scipy's `make_smoothing_spline`, which solves the same problem (knots at every abscissa,
the integral of y''^2 as penalty) with the same `lam`, and with `lam` chosen by GCV.

Both curves are evaluated at common abscissae, so the discrepancy compares the fits.
"""

import jax
import jax.numpy as jnp
import numpy as np
from cases import Case, Impl
from scipy.interpolate import make_smoothing_spline

import diffnurbs as dn

POINTS = 100_000
GCV_POINTS = 10_000  # also compared with scipy's GCV, which fails at 10^5 (below)
LAM = 1e-4
# With abscissae 1e-4 apart the penalty matrix R has entries ~ 1e12: scipy's normal
# equations lose eps lam |R| ~ 1 of accuracy at this lam; `smooth` keeps the polynomial
# part of the fit apart from R (see `_smooth._change_variables`).
LARGE_LAM = 1e4
SCIPY_GCV_FAILS = (
    'its GCV fails at 10^5 points ("the problem is ill-posed": its search over lam in '
    "[0, m] meets normal equations that are not numerically positive definite)"
)


def _ready(x):
    return jax.block_until_ready(x)


def _data(rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray]:
    # Samples about evenly spaced (jittered by up to a third of the spacing): random
    # abscissae 1e-9 apart would make the penalty, ~ 1 / spacing^3, swamp float64 in both.
    x = np.linspace(0.0, 10.0, count) + rng.uniform(-1, 1, count) * 10 / count / 3
    return x, np.sin(x) * np.exp(-x / 5) + 0.05 * rng.standard_normal(count)


def _case(name: str, x: np.ndarray, y: np.ndarray, lam: float | None, at) -> Case:
    if lam is None:  # GCV: lam is chosen on concrete data, outside jit

        def build():
            return dn.smooth(y_jax, x=x_jax)
    else:
        jitted = jax.jit(lambda y, x: dn.smooth(y, x=x, penalty=lam))

        def build():
            return jitted(y_jax, x_jax)

    x_jax, y_jax = jnp.asarray(x), jnp.asarray(y)
    reference = np.asarray(build()(at))[:, 0]
    if lam is None and len(x) > GCV_POINTS:
        scipy = SCIPY_GCV_FAILS
    else:
        scipy = Impl(
            lambda: make_smoothing_spline(x, y, lam=lam),
            len(x),
            reference,
            lambda s: s(np.asarray(at)),
            wrong="rounding in its normal equations, eps lam |R| ~ 1, swamps the fit"
            if lam == LARGE_LAM
            else "",
        )
    return Case(
        name,
        {
            "diffnurbs": Impl(
                lambda: _ready(build()), len(x), reference, lambda c: np.asarray(c(at))[:, 0]
            ),
            "scipy": scipy,
            "splipy": "no smoothing splines",
            "geomdl": "no smoothing splines",
        },
        {},
        # GCV: both stop Brent's method at their own tolerances on lam
        tolerance=1e-6 if lam else 1e-4,
    )


def cases(rng: np.random.Generator) -> list[Case]:
    result = []
    for count, lam in ((POINTS, LAM), (POINTS, LARGE_LAM), (GCV_POINTS, None), (POINTS, None)):
        x, y = _data(rng, count)
        at = jnp.asarray(np.sort(rng.uniform(x[0], x[-1], 2000)))
        how = f"lam = {lam:g}" if lam else "lam by GCV"
        name = f"smooth: cubic smoothing spline of {count:.0e} noisy y(x), {how}"
        result.append(_case(name, x, y, lam, at))
    return result
