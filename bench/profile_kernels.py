"""Current kernels against the prototypes of bench/prototypes.py, and the pieces of each.

`.venv/bin/python bench/profile_kernels.py` prints one markdown table: nanoseconds per point in
wall-clock and in CPU time (all threads) for each case of bench/run.py, with the fastest
other library as the yardstick. Not part of `make bench`.
"""

import jax

jax.config.update("jax_enable_x64", True)

import sys  # noqa: E402

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import prototypes as proto  # noqa: E402
from cases import (  # noqa: E402
    clamped_random_knots,
    discrepancy,
    parameters,
    rational_curve,
    rational_surface,
)
from scipy.interpolate import BSpline  # noqa: E402
from timing import best_times  # noqa: E402

import diffnurbs as dn  # noqa: E402

BUDGET = 4.0


def ready(x):
    return jax.block_until_ready(x)


def rows_for(title, points, calls, reference, order_axis=None):
    """Time `calls` (name -> (fn, converter)) and check each against `reference`.

    A converter of None marks a piece of a kernel: timed, not compared.
    """
    worst = {
        name: discrepancy(convert(fn()), reference, order_axis) if convert else None
        for name, (fn, convert) in calls.items()
    }
    times = best_times({name: fn for name, (fn, _) in calls.items()}, BUDGET, warmup=False)
    base_wall, base_cpu = next(iter(times.values()))
    out = []
    for name, (wall, cpu) in times.items():
        out.append(
            f"| {title} | {name} | {wall / points * 1e9:.1f} | {cpu / points * 1e9:.1f} | "
            f"{base_wall / wall:.2f}× | {base_cpu / cpu:.2f}× | "
            + ("—" if worst[name] is None else f"{worst[name]:.0e}")
            + " |"
        )
    print("\n".join(out), flush=True)
    return out


def curve_rows(rng):
    curve = rational_curve(rng)
    c = curve.diffnurbs
    u = parameters(rng, 10**6, ordered=True)
    uj = jnp.asarray(u)
    current = jax.jit(lambda c, u: c(u))
    new = jax.jit(proto.curve_points)
    search_current = jax.jit(lambda c, u: dn.find_span(c.knots, c.degree, u))
    search_new = jax.jit(lambda c, u: proto.find_span(c.knots, c.degree, u))
    basis_current = jax.jit(lambda c, u: dn.basis_funs(c.knots, c.degree, u))
    ref = np.asarray(current(c, uj))
    rows = rows_for(
        "1. NURBS curve, 1e6 u",
        u.size,
        {
            "scipy BSpline": (lambda: curve.scipy(u), lambda h: h[:, :-1] / h[:, -1:]),
            "diffnurbs now": (lambda: ready(current(c, uj)), np.asarray),
            "prototype (loop span + power basis)": (lambda: ready(new(c, uj)), np.asarray),
            "piece: find_span now (searchsorted)": (lambda: ready(search_current(c, uj)), None),
            "piece: find_span loop bisection": (lambda: ready(search_new(c, uj)), None),
            "piece: basis_funs now (span + A2.2)": (lambda: ready(basis_current(c, uj)), None),
        },
        ref,
    )
    u = parameters(rng, 10**5, ordered=True)
    uj = jnp.asarray(u)
    current = jax.jit(lambda c, u: c.derivatives(u, 2))
    new = jax.jit(lambda c, u: proto.curve_derivatives(c, u, 2))
    ref = np.asarray(current(c, uj))

    def scipy_derivatives():
        a0, a1, a2 = (curve.scipy(u, nu=k) for k in range(3))
        w0, w1, w2 = a0[:, -1:], a1[:, -1:], a2[:, -1:]
        c0 = a0[:, :-1] / w0
        c1 = (a1[:, :-1] - w1 * c0) / w0
        return np.stack([c0, c1, (a2[:, :-1] - 2 * w1 * c1 - w2 * c0) / w0], axis=1)

    rows += rows_for(
        "2. C, C', C'', 1e5 u",
        u.size,
        {
            "scipy BSpline": (scipy_derivatives, np.asarray),
            "diffnurbs now": (lambda: ready(current(c, uj)), np.asarray),
            "prototype (loop span + power basis)": (lambda: ready(new(c, uj)), np.asarray),
        },
        ref,
        order_axis=1,
    )
    return rows


def surface_rows(rng):
    surface = rational_surface(rng)
    s = surface.diffnurbs
    us = np.linspace(0.0, 1.0, 500)
    usj = jnp.asarray(us)
    current = jax.jit(lambda s, us, vs: s.grid(us, vs))
    new = jax.jit(proto.surface_grid)
    ref = np.asarray(current(s, usj, usj))
    splipy_uv = us.copy(), us.copy()
    rows = rows_for(
        "3. 500x500 grid",
        us.size**2,
        {
            "splipy Surface": (lambda: surface.splipy(*splipy_uv), np.asarray),
            "diffnurbs now": (lambda: ready(current(s, usj, usj)), np.asarray),
            "prototype (dense basis matrices)": (lambda: ready(new(s, usj, usj)), np.asarray),
        },
        ref,
    )
    u, v = parameters(rng, 250_000), parameters(rng, 250_000)
    uj, vj = jnp.asarray(u), jnp.asarray(v)
    uv = np.stack([u, v], axis=-1)
    current = jax.jit(lambda s, u, v: s(u, v))
    chunked_now = jax.jit(
        lambda s, u, v: jax.lax.map(lambda x: s(*x), (u.reshape(-1, 2500), v.reshape(-1, 2500)))
    )
    new = jax.jit(proto.surface_points)
    ref = np.asarray(current(s, uj, vj))
    rows += rows_for(
        "4. 250,000 scattered (u, v)",
        u.size,
        {
            "scipy NdBSpline": (lambda: surface.scipy(uv), lambda h: h[:, :-1] / h[:, -1:]),
            "diffnurbs now": (lambda: ready(current(s, uj, vj)), np.asarray),
            "diffnurbs now, lax.map chunks of 2500": (
                lambda: ready(chunked_now(s, uj, vj)),
                lambda r: np.asarray(r).reshape(-1, 3),
            ),
            "prototype (loop span, chunks of 2048)": (
                lambda: ready(new(s, uj, vj)),
                np.asarray,
            ),
        },
        ref,
    )
    return rows


def scaling_rows(rng):
    u = parameters(rng, 10**5, ordered=True)
    uj = jnp.asarray(u)
    current = jax.jit(lambda c, u: c(u))
    new = jax.jit(proto.curve_points)
    rows = []
    for n in (10, 100, 1000, 10**4):
        points = rng.standard_normal((n, 3))
        knots = clamped_random_knots(rng, n, 3)
        c = dn.NURBSCurve(points, 3, knots)
        b = BSpline(knots, points, 3)
        ref = np.asarray(current(c, uj))
        rows += rows_for(
            f"5. B-spline n={n}, 1e5 u",
            u.size,
            {
                "scipy BSpline": (lambda b=b: b(u), np.asarray),
                "diffnurbs now": (lambda c=c: ready(current(c, uj)), np.asarray),
                "prototype (loop span + power basis)": (
                    lambda c=c: ready(new(c, uj)),
                    np.asarray,
                ),
            },
            ref,
        )
    return rows


def main() -> int:
    header = [
        "| case | implementation | wall ns/pt | CPU ns/pt | speed-up wall | speed-up CPU "
        "| rel. diff |",
        "|---|---|---|---|---|---|---|",
    ]
    print("\n".join(header), flush=True)
    rng = np.random.default_rng(1)
    curve_rows(rng)
    surface_rows(rng)
    scaling_rows(rng)
    print(
        "\nspeed-up: against the first row of the case (the other library); CPU time "
        "counts all threads. 'piece' rows time one stage of the current kernel alone."
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
