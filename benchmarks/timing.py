"""Timing helpers shared by the benchmark scripts (imported as `timing` when a script runs from benchmarks/)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable


def per_call(fn: Callable[[], object], budget: float = 0.3, repeats: int = 5) -> float:
    """Seconds per call of fn: best of `repeats` runs of about budget / repeats seconds each."""
    fn()
    t0 = time.perf_counter()
    fn()
    once = max(time.perf_counter() - t0, 1e-7)
    n = max(1, int(budget / repeats / once))
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return best
