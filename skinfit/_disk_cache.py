"""Arrays that take seconds to compute, kept on disk between processes (colour tables).

A fit's colour tables (a 129 x 129 spline of the model's colour and its inverse, per blend) take
seconds each to build on a small CPU, and a photo with per-face blends builds several: most of a
first fit in a fresh process. They are a deterministic function of their key, the model's values
and the code that computes them, so a later process loads them instead (milliseconds).

- The folder is ``$SKINFIT_CACHE_DIR/<name>`` (else under ``$XDG_CACHE_HOME/skinfit`` or
  ``~/.cache/skinfit``), private to the user as the compilation cache's is; a folder that is not
  private, or a read-only home, means no disk cache, never an error.
- The file name is a digest of the key, the model (``skinfit.model.cache_key``), the versions of
  JAX and NumPy and the source of the modules that compute the arrays: any change of the code
  makes new files, and a stale file is never read.
- Files are plain ``.npz`` read without pickles, written to a temporary name and renamed (two
  processes writing at once leave one whole file); one that cannot be read is rebuilt. Each cache
  is kept under ``MAX_BYTES`` (the least recently used files go first; a colour table is ~4 MB).

The same store keeps the traced programs of the pixel solver (``skinfit._exported``, cache
``programs``). Opt out with ``SKINFIT_DISK_CACHE=0`` (tests do, so that they exercise the builds).
"""

from __future__ import annotations

import functools
import hashlib
import os
import tempfile
import zipfile
from pathlib import Path

import jax
import numpy as np

from ._compilation_cache import _private_folder, cache_root

OPT_OUT_VARIABLE = "SKINFIT_DISK_CACHE"
MAX_BYTES = 512 * 1024**2

#: Subpackages whose source decides the cached arrays (the model's physics and the colour tables).
_SOURCES = ("model", "colorimetry")


def enabled() -> bool:
    return os.environ.get(OPT_OUT_VARIABLE, "1").strip().lower() not in ("0", "off", "false", "no")


@functools.lru_cache(maxsize=1)
def _source_digest() -> bytes:
    digest = hashlib.blake2b(digest_size=16)
    package = Path(__file__).parent
    for sub in _SOURCES:
        for path in sorted((package / sub).rglob("*.py")):
            digest.update(path.relative_to(package).as_posix().encode())
            digest.update(path.read_bytes())
    digest.update(f"jax {jax.__version__} numpy {np.__version__}".encode())
    return digest.digest()


def _path(name: str, key: tuple) -> Path:
    digest = hashlib.blake2b(repr(key).encode(), digest_size=20, key=_source_digest())
    return cache_root() / name / f"{digest.hexdigest()}.npz"


def load_arrays(name: str, key: tuple) -> dict[str, np.ndarray] | None:
    """The arrays saved under ``key`` (whose ``repr`` must be deterministic) in the cache ``name``,
    or None (not saved, unreadable, or the cache off)."""
    if not enabled():
        return None
    path = _path(name, key)
    try:
        with np.load(path, allow_pickle=False) as stored:
            arrays = {k: stored[k] for k in stored.files}
        os.utime(path)  # used now: the last to be evicted
        return arrays
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):  # absent, or a partial / corrupt file: build again
        return None


def save_arrays(name: str, key: tuple, arrays: dict[str, np.ndarray]) -> None:
    """Save ``arrays`` under ``key``; silently nothing where the folder is not ours or not writable."""
    if not enabled():
        return
    path = _path(name, key)
    if not _private_folder(path.parent):
        return
    try:
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".tmp", delete=False) as file:
            np.savez(file, **arrays)
        os.replace(file.name, path)
    except OSError:
        try:
            os.unlink(file.name)
        except (OSError, NameError):
            pass
        return
    _evict(path.parent, MAX_BYTES)


def _evict(folder: Path, max_bytes: int) -> None:
    """Remove the least recently used files of ``folder`` until it holds at most ``max_bytes``."""
    try:
        files = sorted((p.stat().st_mtime, p.stat().st_size, p) for p in folder.glob("*.npz"))
        total = sum(size for _, size, _ in files)
        for _, size, path in files:
            if total <= max_bytes:
                break
            path.unlink(missing_ok=True)
            total -= size
    except OSError:  # another process evicting at the same time
        pass
