"""Benchmark cases for fitting: interpolation and least squares of 10^4 points against
scipy, and seed 003's adaptive approximation of a steep front against uniform knots.

scipy gets the parameters and knots diffnurbs chose (computed outside its timing), so both
solve the same problem and their curves, evaluated at common parameters, must agree.
"""

import jax
import jax.numpy as jnp
import numpy as np
from cases import Case, Impl, clamped_random_knots, parameters
from scipy.interpolate import make_interp_spline, make_lsq_spline

import diffnurbs as dn

POINTS = 10_000
LSQ_CONTROL = 500
TOL = 1e-6
CHECK = np.linspace(0.0, 1.0, 200_001)  # the common grid of the fit_function case
FIT_POINTS = 1000
FIT_CONTROL = 12


def _ready(x):
    return jax.block_until_ready(x)


def _data(rng: np.random.Generator, count: int) -> np.ndarray:
    """A smooth 3D random curve sampled at random steps, with a little noise."""
    t = np.cumsum(rng.uniform(0.5, 1.5, count))
    t = 2 * np.pi * t / t[-1]
    smooth = np.stack([np.cos(3 * t) * (2 + np.cos(5 * t)), np.sin(2 * t), np.sin(7 * t)], -1)
    return smooth + 1e-3 * rng.standard_normal((count, 3))


def _same_problem_case(rng, name, build, scipy_fit, targets) -> Case:
    """A fit of 10^4 noisy points by `build` (jitted, points -> curve) against
    `scipy_fit(u, points, knots)` on the chord parameters and the knots diffnurbs chose."""
    points = jnp.asarray(_data(rng, POINTS))
    build = jax.jit(build)
    curve = build(points)
    u, knots = np.asarray(dn.parametrize(points, "chord")), np.asarray(curve.knots)
    at = jnp.asarray(np.sort(rng.uniform(0.0, 1.0, 2000)))
    host, reference = np.asarray(points), np.asarray(curve(at))
    return Case(
        name,
        {
            "diffnurbs": Impl(lambda: _ready(build(points)), POINTS, reference, lambda c: c(at)),
            "scipy": Impl(
                lambda: scipy_fit(u, host, knots), POINTS, reference, lambda s: s(np.asarray(at))
            ),
            "splipy": "not asked",
            "geomdl": "not asked",
        },
        targets,
    )


def interpolation_case(rng: np.random.Generator) -> Case:
    return _same_problem_case(
        rng,
        f"12. cubic interpolation of {POINTS:.0e} points in 3D (chord, averaged knots)",
        lambda q: dn.interpolate(q, 3, "chord"),
        lambda u, points, knots: make_interp_spline(u, points, k=3, t=knots),
        {"scipy": 1},  # issue 15, item 5
    )


def least_squares_case(rng: np.random.Generator) -> Case:
    return _same_problem_case(
        rng,
        f"13. least squares, {POINTS:.0e} points in 3D, {LSQ_CONTROL} control points",
        lambda q: dn.approximate(q, LSQ_CONTROL, 3, "chord", interpolate_ends=False),
        lambda u, points, knots: make_lsq_spline(u, points, knots, 3),
        # measured 28x (11x per core): scipy 1.17 factors the dense 10^4 x 500 matrix by QR
        {"scipy": 5},
    )


def front(t):
    return jnp.tanh(40 * (t - 0.3))


def _uniform_fit(count: int):
    t = np.linspace(0.0, 1.0, count)
    return make_interp_spline(t, np.tanh(40 * (t - 0.3)), k=3)


def _meets_tol(values: np.ndarray) -> np.ndarray:
    """1 when the values are within TOL of the front on the common grid: the quantity both
    methods must agree on (their curves differ by up to 2 TOL)."""
    return np.asarray([float(np.abs(values - np.tanh(40 * (CHECK - 0.3))).max() <= TOL)])


def fewest_uniform_points() -> int:
    """The smallest count of uniform cubic interpolation points meeting TOL (bisection)."""
    low, high = 10, 4000
    while high - low > 1:
        middle = (low + high) // 2
        if _meets_tol(_uniform_fit(middle)(CHECK))[0]:
            high = middle
        else:
            low = middle
    return high


def fit_function_case() -> Case:
    curve = dn.fit_function(front, 0.0, 1.0, TOL)
    uniform = fewest_uniform_points()
    check = jnp.asarray(CHECK)
    return Case(
        f"14. fit_function tanh(40(t-0.3)) on [0, 1] to {TOL:g}: "
        f"{curve.control_points.shape[0]} control points; uniform-knot cubic interpolation "
        f"(scipy) needs {uniform} (fits/s)",
        {
            "diffnurbs": Impl(
                lambda: dn.fit_function(front, 0.0, 1.0, TOL),
                1,
                np.ones(1),
                lambda c: _meets_tol(np.asarray(c(check))[:, 0]),
            ),
            "scipy": Impl(
                lambda: _uniform_fit(uniform), 1, np.ones(1), lambda s: _meets_tol(s(CHECK))
            ),
            "splipy": "not asked",
            "geomdl": "not asked",
        },
        {},
    )


def _noisy_rational_curve(rng: np.random.Generator) -> np.ndarray:
    """FIT_POINTS samples of a random rational cubic in 3D, with a little noise."""
    knots = clamped_random_knots(rng, FIT_CONTROL, 3)
    control, weights = rng.uniform(-1.0, 1.0, (FIT_CONTROL, 3)), rng.uniform(0.5, 2.0, FIT_CONTROL)
    truth = dn.NURBSCurve(control, 3, knots, weights)
    samples = np.asarray(truth(parameters(rng, FIT_POINTS, ordered=True)))
    return samples + 1e-3 * rng.standard_normal(samples.shape)


def _rms(curve, u, points) -> float:
    return float(np.sqrt(np.mean(np.sum((np.asarray(curve(u)) - points) ** 2, axis=-1))))


def fit_curve_cases(rng: np.random.Generator) -> list[Case]:
    """fit_curve of a noisy rational curve, with fixed centripetal parameters. Non-rational,
    it is plain least squares: scipy's make_lsq_spline with the same parameters and knots
    solves the same problem. Nothing else fits weights (the rational row's parameters are
    held with `correct_parameters=False`; `correction_cases` times the correction)."""
    points = jnp.asarray(_noisy_rational_curve(rng))
    host = np.asarray(points)
    u = np.asarray(dn.parametrize(points))
    at = jnp.asarray(np.sort(rng.uniform(0.0, 1.0, 2000)))
    result = []
    for rational in (False, True):
        curve, report = dn.fit_curve(
            points, FIT_CONTROL, 3, rational=rational, correct_parameters=False, full_output=True
        )
        name = (
            f"{15 + rational}. fit_curve, {FIT_POINTS} noisy points of a rational cubic, "
            f"{FIT_CONTROL} control points, {'rational' if rational else 'non-rational'}: "
            f"rms residual {float(report.rms_residual):.2e} in {int(report.steps)} steps"
        )
        if rational:
            scipy_impl = "no rational fitting"
        else:
            knots = np.asarray(curve.knots)
            scipy_rms = _rms(make_lsq_spline(u, host, knots, 3), u, host)
            name += f" (scipy make_lsq_spline {scipy_rms:.2e})"
            scipy_impl = Impl(
                lambda knots=knots: make_lsq_spline(u, host, knots, 3),
                FIT_POINTS,
                np.asarray(curve(at)),
                lambda s: s(np.asarray(at)),
            )
        result.append(
            Case(
                name,
                {
                    "diffnurbs": Impl(
                        lambda rational=rational: _ready(
                            dn.fit_curve(
                                points, FIT_CONTROL, 3, rational=rational, correct_parameters=False
                            )
                        ),
                        FIT_POINTS,
                        np.asarray(curve(at)),
                        lambda c: c(at),
                    ),
                    "scipy": scipy_impl,
                    "splipy": "not asked",
                    "geomdl": "approximate_curve interpolates the ends (A9.7): another problem",
                },
                {},
            )
        )
    return result


CORRECTION_POINTS = (1000, 10_000)


def _correction_data(rng: np.random.Generator, kind: str, count: int):
    """`(points, n_control, degree, rational, truth)`: a quarter circle at random angles
    (truth: the radius) or a random cubic B-spline with noise 1e-3 at random parameters,
    fitted with its own knots (truth: the curve)."""
    if kind == "circle":
        angle = np.sort(np.r_[0.0, np.pi / 2, rng.uniform(0.0, np.pi / 2, count - 2)])
        return np.column_stack([np.cos(angle), np.sin(angle)]), 3, 2, True, None
    knots = clamped_random_knots(rng, FIT_CONTROL, 3)
    truth = dn.NURBSCurve(rng.uniform(-1.0, 1.0, (FIT_CONTROL, 3)), 3, knots)
    samples = np.asarray(truth(parameters(rng, count, ordered=True)))
    return samples + 1e-3 * rng.standard_normal(samples.shape), FIT_CONTROL, 3, False, truth


def correction_cases(rng: np.random.Generator) -> list[Case]:
    """fit_curve with parameter correction, 10^3 and 10^4 points: a step eliminates the m
    parameters point by point (O(m)). No library here corrects parameters (scipy,
    splipy and geomdl fit on fixed parameters), so the rows have no peer; each reports
    its steps and how well the known answer is met."""
    result = []
    for kind in ("circle", "noisy cubic"):
        for count in CORRECTION_POINTS:
            points, n_control, degree, rational, truth = _correction_data(rng, kind, count)
            knots = None if truth is None else np.asarray(truth.knots)

            def fit(
                points=points, n_control=n_control, degree=degree, rational=rational, knots=knots
            ):
                return dn.fit_curve(
                    points,
                    n_control,
                    degree,
                    rational=rational,
                    correct_parameters=True,
                    knots=knots,
                    full_output=True,
                )

            curve, report = fit()
            at = np.linspace(0.0, 1.0, 2001)
            if truth is None:
                quality = np.abs(np.linalg.norm(np.asarray(curve(at)), axis=1) - 1).max()
                what = f"radius error {quality:.1e}"
                title = "rational quadratic, quarter circle at random angles"
            else:
                quality = np.abs(np.asarray(curve(at)) - np.asarray(truth(at))).max()
                what = f"rms residual {float(report.rms_residual):.2e}, off the truth {quality:.1e}"
                title = f"cubic, random B-spline + noise 1e-3, {n_control} control points"
            result.append(
                Case(
                    f"{23 + len(result)}. fit_curve with parameter correction, {count:.0e} "
                    f"points, {title}: {int(report.steps)} steps, {what}",
                    {
                        "diffnurbs": Impl(
                            lambda fit=fit: _ready(fit()[0].control_points),
                            count,
                            np.asarray(curve.control_points),
                        ),
                        "scipy": "no parameter correction",
                        "splipy": "no parameter correction",
                        "geomdl": "no parameter correction",
                    },
                    {},
                )
            )
    return result


def cases(rng: np.random.Generator) -> list[Case]:
    return [
        interpolation_case(rng),
        least_squares_case(rng),
        fit_function_case(),
        *fit_curve_cases(rng),
        *correction_cases(rng),
    ]
