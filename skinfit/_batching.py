"""Fixed-size batches over rows: bounded memory, and one compilation per batch size."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np


def pad_size(n: int, chunk_size: int) -> int:
    """Batch size for n items: the chunk size, or the next power of two below it (few compilations)."""
    return bucket_size(n, chunk_size, smallest=1, factor=2)


def bucket_size(n: int, chunk_size: int, smallest: int = 256, factor: int = 8) -> int:
    """Batch size for n items from few buckets (``smallest`` times powers of ``factor``, then the
    chunk size): for cheap per-item programs called at many counts (an image's pixel subsets),
    where tracing a program for a new size (~0.3 s) costs more than computing padding."""
    size = smallest
    while size < min(n, chunk_size):
        size *= factor
    return min(size, chunk_size)


def padded_rows(rows: np.ndarray, size: int) -> np.ndarray:
    """``rows`` (n, ...) padded to ``size`` rows by repeating the last (one program shape for
    every count up to ``size``); as they are when n >= size."""
    if len(rows) >= size:
        return rows
    return np.concatenate([rows, np.repeat(rows[-1:], size - len(rows), axis=0)])


def chunks(items: np.ndarray, size: int, progress, desc: str):
    """(start, stop, padded chunk) over ``items`` in fixed-size chunks; the last is padded by repetition."""
    n = len(items)
    starts = range(0, n, size)
    if progress is None:
        progress = len(starts) > 1
    if progress:
        from tqdm.auto import tqdm

        starts = tqdm(starts, desc=desc, unit="chunk")
    for start in starts:
        stop = min(start + size, n)
        yield start, stop, padded_rows(items[start:stop], size)


def map_batches(function, arrays, size: int, progress=False, desc: str = "") -> list[np.ndarray]:
    """``function(*row_chunks)`` over fixed-size chunks of the rows of ``arrays`` (a varying row
    count does not recompile: the last chunk is padded); its outputs as NumPy arrays over all rows,
    with their dtypes."""
    n = len(arrays[0])
    outputs = None
    for start, stop, rows in chunks(np.arange(n), size, progress, desc):
        out = function(*(jnp.asarray(a[rows]) for a in arrays))
        if outputs is None:
            outputs = [np.zeros((n, *np.shape(v)[1:]), np.asarray(v).dtype) for v in out]
        for full, part in zip(outputs, out):
            full[start:stop] = np.asarray(part)[: stop - start]
    return outputs
