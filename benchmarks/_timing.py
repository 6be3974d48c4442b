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
