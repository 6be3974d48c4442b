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
    result, first, times = first_and_repeated(lambda: function(*args), repeats=repeats)
    return result, first, float(np.median(times))


def first_and_repeated(function, *, repeats: int = 3, min_seconds: float = 0.0, between=None, parts: int = 5):
    """(result, first call's seconds, seconds of each timed call after it) for functions that return
    host data. The calls after the first are at least ``repeats`` and at least ``min_seconds`` in
    all (their count is set from the second call's time), so that short calls are timed often enough
    for a stable median on a shared, noisy machine. ``between(parts)``, if given, runs untimed
    ``parts`` times, spread evenly over the timed calls: a baseline split into that many parts and
    interleaved with them, so that a burst of load hits both alike (most calls still follow each
    other, as in a loop of fits, rather than a baseline that has just refilled the caches)."""
    start = time.perf_counter()
    result = function()
    first = time.perf_counter() - start
    times = []
    count, done_parts = repeats, 0
    while len(times) < count:
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
        if len(times) == 1:
            count = max(repeats, int(np.ceil(min_seconds / max(times[0], 1e-9))))
        while between is not None and done_parts < parts and done_parts * count < parts * len(times):
            between(parts)
            done_parts += 1
    return result, first, times
