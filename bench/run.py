"""`make bench`: points per second of diffnurbs next to scipy, splipy and geomdl.

Prints one markdown table (also written to bench/results/latest.md): for each case the
best-of-several wall-clock rate of every library, the ratio diffnurbs / library, the
issue's targets and whether they are met, and the largest difference between each
library's result and diffnurbs's. Everything runs in float64.
"""

import jax

jax.config.update("jax_enable_x64", True)  # before any array exists: compare in float64

import os  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from importlib.metadata import version  # noqa: E402
from pathlib import Path  # noqa: E402

import cases_fit  # noqa: E402
import cases_fit_surface  # noqa: E402
import cases_geometry  # noqa: E402
import cases_inversion  # noqa: E402
import cases_ph  # noqa: E402
import cases_smooth  # noqa: E402
import numpy as np  # noqa: E402
from cases import LIBRARIES, Case, Impl, all_cases, discrepancy  # noqa: E402
from timing import best_times  # noqa: E402

SEED = 0
BUDGET = 3.0  # seconds of timing rounds per case
TOLERANCE = 1e-9  # largest accepted difference from diffnurbs, relative to the values
# The slowest size of a scaling group must keep this share of the fastest (issue 15: the cost at
# n = 10^4 within 1.3x of the cost at n = 10).
FLATNESS = 1 / 1.3
SIZES = {
    "curve": 10**6,
    "derivatives": 10**5,
    "grid_side": 500,
    "scattered": 250_000,
    "scaling": 10**5,
    "scaling_controls": (10, 100, 1000, 10**4),
    # geomdl is pure Python and splipy slow on a million points: a prefix of the parameters.
    "splipy_curve": 200_000,
    "geomdl_curve": 2000,
    "geomdl_derivatives": 1000,
    "geomdl_surface": 1000,
}
# Cases of the later issues: geometry toolkit (7-10, 19-22), PH curves (11), fitting (12-16, 23-26,
# smoothing, scattered surfaces), point inversion (17-18).
TOPIC_CASES = (
    cases_geometry,
    cases_ph,
    cases_fit,
    cases_smooth,
    cases_fit_surface,
    cases_inversion,
)
RESULTS = Path(__file__).parent / "results" / "latest.md"


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def environment() -> list[str]:
    packages = ["diffnurbs", "jax", "jaxlib", "numpy", "scipy", "splipy", "geomdl", "cadquery-ocp"]
    load = " / ".join(f"{x:.2f}" for x in os.getloadavg())
    return [
        f"- versions: python {platform.python_version()}, "
        + ", ".join(f"{name} {version(name)}" for name in packages),
        f"- CPU: {cpu_model()}, {os.cpu_count()} cores; "
        f"JAX devices: {', '.join(str(d) for d in jax.devices())}",
        f"- load average at start (1 / 5 / 15 min): {load}",
    ]


def rate(points_per_second: float) -> str:
    for scale, unit in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if points_per_second >= scale:
            return f"{points_per_second / scale:.3g} {unit}"
    return f"{points_per_second:.3g}"


def measure(case: Case) -> tuple[dict[str, tuple[float, float]], float]:
    """`(wall, cpu)` points per second of every library, and the worst discrepancy."""
    impls = {name: impl for name, impl in case.impls.items() if isinstance(impl, Impl)}
    worst = max(
        discrepancy(impl.convert(impl.call()), impl.reference, case.order_axis)
        for impl in impls.values()
        if not impl.wrong
    )
    times = best_times({name: impl.call for name, impl in impls.items()}, BUDGET, warmup=False)
    rates = {
        name: (impls[name].points / wall, impls[name].points / max(cpu, 1e-9))
        for name, (wall, cpu) in times.items()
    }
    return rates, worst


def targets_cell(case: Case, ratios: dict[str, float]) -> tuple[str, bool]:
    parts, met = [], True
    for library, target in case.targets.items():
        ok = ratios[library] >= target
        met &= ok
        parts.append(f"{library} ≥ {target}× {'✓' if ok else '✗'}")
    return ", ".join(parts), met


def table_row(case: Case, rates: dict[str, tuple[float, float]], worst: float):
    """Markdown cells of one case and whether its targets are met."""
    wall = {name: r[0] for name, r in rates.items()}
    cpu = {name: r[1] for name, r in rates.items()}
    ratios = {name: wall["diffnurbs"] / wall[name] for name in rates}
    cells = [case.name, rate(wall["diffnurbs"])]
    for library in LIBRARIES[1:]:
        impl = case.impls.get(library)
        if impl is None:  # not a job this library does (OpenCascade outside geometry)
            cells += ["", ""]
        elif isinstance(impl, str):
            cells += [f"n/a: {impl}", ""]
        else:
            per_core = cpu["diffnurbs"] / cpu[library]
            wrong = f"; **wrong result**: {impl.wrong}" if impl.wrong else ""
            cells += [rate(wall[library]), f"{ratios[library]:.3g}× ({per_core:.3g}×){wrong}"]
    targets, met = targets_cell(case, ratios)
    agree = "" if worst <= (case.tolerance or TOLERANCE) else " ✗"
    cells += [targets, "yes" if met else "**no**", f"{worst:.1e}{agree}"]
    return "| " + " | ".join(cells) + " |", met


NOTES = [
    "- Rates: points per wall-clock second, best of interleaved rounds (~{budget:g} s per "
    "case) after a warm-up call (JIT compilation). In brackets, the same ratio in CPU "
    "time (all threads of the process): XLA spreads large loops over every core, scipy, "
    "splipy and geomdl evaluate on one thread (splipy's dense products go through BLAS), "
    "so the bracket compares the libraries per core, and it hardly moves when other "
    "processes load the machine.",
    "- diffnurbs calls are `jax.jit`-ed with the curve or surface as an argument "
    "(`jax.jit(lambda c, u: c(u))`) and end with `block_until_ready()`.",
    "- Curve parameters are random and sorted (scipy's span search is then O(1) per "
    "point); surface scattered points are random and unsorted; the grid is "
    "`linspace(0, 1, {side})` in both directions.",
    "- Rational geometry goes to scipy and splipy as homogeneous control points "
    "(w P, w), then divided by w (derivatives: quotient rule). scipy has no grid path: "
    "case 3 evaluates `NdBSpline` at all grid points (built outside the timing). "
    "splipy's scattered points: `evaluate(u, v, tensor=False)` (dense basis matrices).",
    "- geomdl (pure Python) gets the first {geomdl_curve} curve parameters, "
    "{geomdl_derivatives} for derivatives, ~{geomdl_surface} surface points, and splipy "
    "the first {splipy_curve:,} parameters of case 1; rates are per point all the same.",
    "- max rel. diff: largest |other − diffnurbs| over the libraries, divided by the "
    "largest |value| (per derivative order); accepted up to {tolerance:g}.",
]


def main() -> int:
    header = ["# diffnurbs benchmark", "", *environment(), ""]
    print("\n".join(header), flush=True)
    started = time.perf_counter()
    cases = all_cases(SEED, SIZES)
    for module in TOPIC_CASES:
        cases += module.cases(np.random.default_rng(SEED))

    columns = ["case", "diffnurbs pts/s"]
    for library in LIBRARIES[1:]:
        columns += [f"{library} pts/s", f"dn/{library} (per core)"]
    columns += ["target (dn/other)", "met", "max rel. diff"]
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    all_met, all_agree = True, True
    groups: dict[str, list[float]] = {}
    for case in cases:
        rates, worst = measure(case)
        line, met = table_row(case, rates, worst)
        lines.append(line)
        all_met &= met
        all_agree &= worst <= (case.tolerance or TOLERANCE)
        if case.group:
            groups.setdefault(case.group, []).append(rates["diffnurbs"][0])
        print(f"  measured {case.name} ({time.perf_counter() - started:.0f} s)", flush=True)

    notes = [""]
    for group, group_rates in groups.items():
        share = min(group_rates) / max(group_rates)
        flat = share >= FLATNESS
        all_met &= flat
        notes.append(
            f"- {group}: diffnurbs's slowest size runs at {share:.2f} of its fastest "
            f"(target ≥ {FLATNESS:.2f}: {'met' if flat else '**not met**'})."
        )
    values = dict(SIZES, budget=BUDGET, side=SIZES["grid_side"], tolerance=TOLERANCE)
    notes += [note.format(**values) for note in NOTES]
    load = os.getloadavg()[0]
    notes.append(
        f"- total time {time.perf_counter() - started:.0f} s; load average at the end: "
        + " / ".join(f"{x:.2f}" for x in os.getloadavg())
    )
    if load > (os.cpu_count() or 1) / 2:
        notes.append(
            "- **The machine was busy with other work**: wall-clock rates are disturbed; "
            "the per-core ratios in brackets are the steadier figures."
        )
    report = "\n".join([*header, *lines, *notes]) + "\n"
    print("\n" + "\n".join(lines + notes))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(report)
    print(f"\nall targets met: {'yes' if all_met else 'no'}; written to {RESULTS}")
    if not all_agree:
        print("error: a library's result differs from diffnurbs's", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
