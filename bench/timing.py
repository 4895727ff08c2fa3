"""Best-of-several timing, interleaved between libraries.

The machine may be shared with other work, so the calls of one case run in rounds (each
library once per round) and each library keeps its fastest call: a burst of load then
slows every library of the case alike instead of one of them. Besides wall-clock time
the process's CPU time (all threads) is kept: it hardly moves with the load of other
processes, and compares the libraries per core.
"""

import time
from collections.abc import Callable


def best_times(
    calls: dict[str, Callable[[], object]],
    budget: float,
    min_rounds: int = 3,
    max_rounds: int = 200,
    warmup: bool = True,
) -> dict[str, tuple[float, float]]:
    """`(wall, cpu)`: the fastest wall-clock and CPU times in seconds of each call.

    With `warmup`, every call first runs once untimed (JIT compilation, caches). Then
    the calls run in rounds until `budget` seconds have passed and at least `min_rounds`
    rounds have run.
    """
    if warmup:
        for call in calls.values():
            call()
    wall = dict.fromkeys(calls, float("inf"))
    cpu = dict.fromkeys(calls, float("inf"))
    start = time.perf_counter()
    for done in range(1, max_rounds + 1):
        for name, call in calls.items():
            c0, t0 = time.process_time(), time.perf_counter()
            call()
            wall[name] = min(wall[name], time.perf_counter() - t0)
            cpu[name] = min(cpu[name], time.process_time() - c0)
        if done >= min_rounds and time.perf_counter() - start > budget:
            break
    return {name: (wall[name], cpu[name]) for name in calls}
