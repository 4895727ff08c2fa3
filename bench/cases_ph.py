"""Benchmark case for PH curves: the inverse problem of seed 004, vmapped over point triples.

No other library offers PH curves, so diffnurbs is timed alone; its result is compared with
the closed form of the same problem (`ph.solve_cardinal_closed_form`), so the "max rel. diff"
column checks the optimistix solutions.
"""

import jax
import jax.numpy as jnp
import numpy as np
from cases import Case, Impl

from diffnurbs import ph

TRIPLES = 10_000


def _ready(x):
    return jax.block_until_ready(x)


def _stacked(result) -> np.ndarray:
    """`(coeffs (N, 2, 4), p_next2 (N, 2, 2))` -> one array `(N, 2, 6)`."""
    coeffs, p_next2 = result
    return np.concatenate([np.asarray(coeffs), np.asarray(p_next2)], axis=-1)


def inverse_problem_case(rng: np.random.Generator, count: int = TRIPLES) -> Case:
    """`count` random frames `P_{k-1}, P_k, P_{k+1}` (from random PH cubics, so every one is
    well posed), each solved for both PH cardinal segments in one vmapped call."""
    coeffs = rng.standard_normal((count, 4))
    tension = rng.uniform(-0.5, 0.5, count)
    frames = jax.vmap(ph.cardinal_points)(coeffs, rng.standard_normal((count, 2)), tension)
    args = (frames[:, 0], frames[:, 1], frames[:, 2], jnp.asarray(tension))
    solve = jax.jit(jax.vmap(ph.solve_cardinal))
    closed_form = jax.jit(jax.vmap(ph.solve_cardinal_closed_form))
    reference = _stacked(closed_form(*args))
    return Case(
        f"11. PH inverse problem (seed 004, eq. 8), vmapped, {count:,} triples (solves/s)",
        {
            "diffnurbs": Impl(lambda: _ready(solve(*args)), count, reference, _stacked),
            "scipy": "no PH curves",
            "splipy": "no PH curves",
            "geomdl": "no PH curves",
        },
        {},
    )


def cases(rng: np.random.Generator) -> list[Case]:
    return [inverse_problem_case(rng)]
