"""Timing helper shared by the benchmarks."""

from __future__ import annotations

import time

import jax
import numpy as np


def median_seconds(function, *args, repeats: int = 3) -> float:
    """Median wall time of ``function(*args)`` after one warm-up (compiling) call."""
    jax.block_until_ready(function(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(function(*args))
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def first_and_median(function, *args, repeats: int = 3):
    """(result, first call's seconds, median seconds of ``repeats`` calls after it): what a user waits
    the first time (compilation included), and what the compiled call costs. For functions that
    return host data (NumPy results), so no device synchronisation is needed."""
    start = time.perf_counter()
    result = function(*args)
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = function(*args)
        times.append(time.perf_counter() - start)
    return result, first, float(np.median(times))
