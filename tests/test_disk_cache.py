"""Colour tables kept on disk between processes (``skinfit._disk_cache``)."""

import os

import numpy as np
import pytest

from skinfit import _disk_cache
from skinfit.colorimetry import _colour_table, colour_table

#: A small table: what is cached does not depend on its size, and this one builds in a second.
SMALL = dict(nodes=17, inverse_cells=32)


@pytest.fixture
def disk_cache(tmp_path, monkeypatch):
    """The disk cache on, in a private folder of its own, with empty in-memory caches."""
    monkeypatch.setenv("SKINFIT_DISK_CACHE", "1")
    monkeypatch.setenv("SKINFIT_CACHE_DIR", str(tmp_path / "cache"))
    for cache in (_colour_table._TABLES, _colour_table._COARSE_TABLES):
        cache.clear()
    yield tmp_path / "cache" / "colour-tables"
    for cache in (_colour_table._TABLES, _colour_table._COARSE_TABLES):
        cache.clear()


def _forget():
    """What a new process has: no table in memory."""
    _colour_table._COARSE_TABLES.clear()


def _same(a, b):
    for name in ("coefficients", "inverse_roots", "inverse_chroma", "inverse_jacobian"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    for x, y in zip(a.inverse_edges, b.inverse_edges):
        np.testing.assert_array_equal(x, y)
    assert (a.melanin_blend, a.illuminant, a.melanin_max, a.haemoglobin_max, a.nodes) == (
        b.melanin_blend, b.illuminant, b.melanin_max, b.haemoglobin_max, b.nodes)


def test_a_table_built_once_is_read_back_not_built_again(disk_cache, monkeypatch):
    built = colour_table(0.3, **SMALL)
    (stored,) = disk_cache.glob("*.npz")
    _forget()
    monkeypatch.setattr(_colour_table, "_colour_table", lambda *a: pytest.fail("built again, not read"))
    read = colour_table(0.3, **SMALL)
    _same(built, read)
    # the same fits from it: warm starts and spline colours
    pixels = np.array([[0.4, 0.25, 0.2], [0.2, 0.1, 0.08]])
    np.testing.assert_array_equal(built.warm_starts(pixels), read.warm_starts(pixels))
    assert stored.exists()


def test_another_key_or_another_code_is_another_file(disk_cache, monkeypatch):
    colour_table(0.3, **SMALL)
    colour_table(0.6, **SMALL)
    assert len(list(disk_cache.glob("*.npz"))) == 2
    # a change of the model's source (here: its digest) never reads the old files
    _forget()
    monkeypatch.setattr(_disk_cache, "_source_digest", lambda: b"other code")
    colour_table(0.3, **SMALL)
    assert len(list(disk_cache.glob("*.npz"))) == 3


def test_a_corrupt_file_is_built_again(disk_cache):
    built = colour_table(0.3, **SMALL)
    (stored,) = disk_cache.glob("*.npz")
    stored.write_bytes(stored.read_bytes()[:1000])  # a write cut short
    _forget()
    _same(built, colour_table(0.3, **SMALL))
    assert stored.stat().st_size > 1000  # and saved whole again


def test_no_disk_cache_when_opted_out_or_the_folder_is_not_private(disk_cache, monkeypatch):
    monkeypatch.setenv("SKINFIT_DISK_CACHE", "0")
    colour_table(0.3, **SMALL)
    assert not disk_cache.exists()
    monkeypatch.setenv("SKINFIT_DISK_CACHE", "1")
    disk_cache.mkdir(parents=True)
    os.chmod(disk_cache, 0o777)  # others may write: its files could be anyone's
    _forget()
    colour_table(0.3, **SMALL)
    assert not list(disk_cache.glob("*.npz"))


def test_the_cache_is_bounded_least_recently_used_first(disk_cache, monkeypatch):
    colour_table(0.1, **SMALL)
    size = next(disk_cache.glob("*.npz")).stat().st_size
    monkeypatch.setattr(_disk_cache, "MAX_BYTES", int(2.5 * size))
    colour_table(0.2, **SMALL)
    _forget()
    os.utime(next(p for p in disk_cache.glob("*.npz")), (0, 0))  # make one file the oldest
    oldest = min(disk_cache.glob("*.npz"), key=lambda p: p.stat().st_mtime)
    colour_table(0.4, **SMALL)  # a third file: over the bound, the oldest goes
    files = set(disk_cache.glob("*.npz"))
    assert len(files) == 2 and oldest not in files
