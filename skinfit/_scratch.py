"""Full-size arrays of a large image's fit, out of core.

A 48 MP photo's input and maps take 2.5 GB in memory. Above ``OUT_OF_CORE_PIXELS`` they live in
unnamed temporary files mapped into memory instead (``image_array``): the fit reads and writes
them a band of rows at a time, as it does in memory, and gives the pages it touched back to the
operating system after each band (``release_pages``), so that what the process holds is set by a
band, not by the photo. The files' pages stay in the operating system's page cache, which it
writes out and reclaims under memory pressure; the files vanish with the last array that maps
them (or with the process). The folder is ``$SKINFIT_SCRATCH_DIR``, else skinfit's cache folder
(``~/.cache/skinfit/scratch``: on disk, where ``/tmp`` may be memory).
"""

from __future__ import annotations

import mmap
import os
import tempfile
import weakref
from pathlib import Path

import numpy as np

from ._compilation_cache import cache_root

#: Pixels from which ``image_array(..., out_of_core=None)`` maps its arrays from disk (8 MP: an
#: image's input and maps then take over 400 MB in memory).
OUT_OF_CORE_PIXELS = 8 * 2**20

#: The live mappings, so that ``release_pages`` reaches every array without being handed them.
_MAPPINGS: weakref.WeakSet = weakref.WeakSet()


def out_of_core(pixels: int, requested: bool | None = None) -> bool:
    """Whether an image of ``pixels`` keeps its full-size arrays on disk: ``requested`` if given,
    else ``$SKINFIT_OUT_OF_CORE`` (``1``/``0``) if set, else from ``OUT_OF_CORE_PIXELS`` on."""
    if requested is not None:
        return bool(requested)
    setting = os.environ.get("SKINFIT_OUT_OF_CORE")
    if setting is not None:
        return setting.strip().lower() not in ("0", "false", "no", "off", "")
    return pixels >= OUT_OF_CORE_PIXELS


def scratch_folder() -> Path:
    """Where out-of-core arrays are mapped from (see the module's docstring); made if missing."""
    folder = Path(os.environ.get("SKINFIT_SCRATCH_DIR") or cache_root() / "scratch")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def image_array(shape: tuple[int, ...], dtype, on_disk: bool) -> np.ndarray:
    """A zeroed array of ``shape``: in memory, or (``on_disk``) mapped from an unnamed temporary
    file in ``scratch_folder()`` (a file of zeros costs no writes until it is written)."""
    dtype = np.dtype(dtype)
    if not on_disk:
        return np.zeros(shape, dtype)
    size = max(int(np.prod(shape, dtype=np.int64)) * dtype.itemsize, 1)
    with tempfile.TemporaryFile(dir=scratch_folder()) as file:  # unnamed where the system allows
        file.truncate(size)
        mapping = mmap.mmap(file.fileno(), size)  # holds its own descriptor: the file lives on with it
    _MAPPINGS.add(mapping)
    return np.frombuffer(mapping, dtype, count=int(np.prod(shape, dtype=np.int64))).reshape(shape)


def like(array: np.ndarray, dtype=None, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """A zeroed array of ``array``'s shape (or ``shape``) and dtype (or ``dtype``), on disk where
    ``array`` is (``is_on_disk``)."""
    return image_array(array.shape if shape is None else shape, array.dtype if dtype is None else dtype, is_on_disk(array))


def is_on_disk(array: np.ndarray) -> bool:
    """Whether ``array`` (or the array it views) is mapped by ``image_array`` from disk."""
    while isinstance(array, np.ndarray):
        base = array.base
        if isinstance(base, memoryview):  # np.frombuffer's: a view of the mapping
            return isinstance(base.obj, mmap.mmap)
        if isinstance(base, mmap.mmap):
            return True
        array = base
    return False


def release_pages(trim_heap: bool = False) -> None:
    """Give back to the operating system the pages of every out-of-core array that the process
    holds (their values stay in the file and come back on the next access); nothing in memory
    changes. Call it after each band of work on full-size arrays. ``trim_heap``: also return the
    C heap's free memory (glibc keeps what a stage's temporaries freed, in arenas per thread,
    and the process's resident memory would stay at the largest stage's)."""
    advice = getattr(mmap, "MADV_DONTNEED", None)
    if advice is not None:  # no madvise (Windows): the system trims the working set itself
        for mapping in list(_MAPPINGS):
            try:
                mapping.madvise(advice)
            except (OSError, ValueError):  # closed meanwhile
                pass
    if trim_heap and _MALLOC_TRIM is not None:
        _MALLOC_TRIM(0)


def _malloc_trim():
    """glibc's ``malloc_trim``, or None (another C library, another system)."""
    try:
        import ctypes

        return ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None


_MALLOC_TRIM = _malloc_trim()


def row_bands(height: int, width: int, pixels: int = 1 << 18):
    """Slices of at most ``pixels`` pixels' rows (at least one row) covering ``height`` rows of
    ``width``; after each band's work, its out-of-core pages are given back (``release_pages``)."""
    rows = max(1, pixels // max(width, 1))
    for top in range(0, height, rows):
        yield slice(top, min(top + rows, height))
        release_pages()


class Rows:
    """A full-size image (``shape``) computed a band of rows at a time: ``image[rows]`` is
    ``rows_of(rows)``, so that functions that read an image by bands of rows (``smooth_field``,
    the writers) take an expression of full-size maps without its full-size temporaries."""

    def __init__(self, shape: tuple[int, ...], rows_of):
        self.shape, self._rows_of = tuple(shape), rows_of

    def __getitem__(self, rows: slice) -> np.ndarray:
        return self._rows_of(rows)
