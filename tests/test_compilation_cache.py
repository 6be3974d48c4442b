"""The persistent compilation cache that importing skinfit turns on (skinfit/_compilation_cache.py):
a second process loads what the first compiled; the opt-out and the user's own setting are obeyed;
the folder is private and per machine. Each case runs in a fresh interpreter (the setting is made at
import)."""

import json
import os
import stat
import subprocess
import sys

import pytest

# compiles a program of the fit's kind and reports the cache folder, the files in it and the cache hits
PROBE = """
import json, jax, numpy as np
hits = []
jax.monitoring.register_event_listener(lambda name, **kw: hits.append(name) if name.endswith("cache_hits") else None)
import skinfit
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
skinfit.diffuse_reflectance(skinfit.preset("light"), np.arange(400.0, 701.0, 50.0)).block_until_ready()
folder = jax.config.jax_compilation_cache_dir
import pathlib
files = sorted(p.name for p in pathlib.Path(folder).iterdir()) if folder else []
print(json.dumps({"folder": folder, "files": len(files), "hits": len(hits), "max_bytes": jax.config.jax_compilation_cache_max_size}))
"""


def _probe(tmp_path, **environment):
    env = {k: v for k, v in os.environ.items() if k not in ("SKINFIT_COMPILATION_CACHE", "JAX_COMPILATION_CACHE_DIR")}
    env.update(SKINFIT_CACHE_DIR=str(tmp_path / "cache"), **environment)
    done = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_second_process_loads_what_the_first_compiled(tmp_path):
    first = _probe(tmp_path)
    assert first["folder"].startswith(str(tmp_path / "cache" / "jax"))
    assert first["files"] > 0 and first["hits"] == 0
    assert 0 < first["max_bytes"] <= 4 * 1024**3  # bounded: JAX evicts the least recently used
    mode = os.stat(first["folder"]).st_mode
    assert not mode & (stat.S_IRWXG | stat.S_IRWXO)  # private: JAX runs what it finds there
    second = _probe(tmp_path)
    assert second["folder"] == first["folder"] and second["hits"] > 0


def test_the_opt_out_and_the_users_own_folder_win(tmp_path):
    assert not _probe(tmp_path, SKINFIT_COMPILATION_CACHE="0")["folder"]
    own = tmp_path / "mine"
    own.mkdir()
    assert _probe(tmp_path, JAX_COMPILATION_CACHE_DIR=str(own))["folder"] == str(own)


@pytest.mark.skipif(not hasattr(os, "getuid"), reason="POSIX permissions")
def test_a_folder_others_may_write_to_is_not_used(tmp_path):
    shared = tmp_path / "cache" / "jax"
    shared.mkdir(parents=True)
    from skinfit._compilation_cache import machine_key

    (shared / machine_key()).mkdir(mode=0o777)
    os.chmod(shared / machine_key(), 0o777)
    assert not _probe(tmp_path)["folder"]


def test_programs_cached_before_the_size_bound_do_not_break_later_writes(tmp_path):
    """A program cached without its access-time file (written while the cache had no size bound) gets
    one at import: later writes then succeed, where JAX's eviction failed on every one."""
    from skinfit._compilation_cache import machine_key

    folder = tmp_path / "cache" / "jax" / machine_key()
    folder.mkdir(parents=True, mode=0o700)
    (tmp_path / "cache").chmod(0o700)
    (tmp_path / "cache" / "jax").chmod(0o700)
    (folder / "jit_old_program-0123-cache").write_bytes(b"\0" * 64)
    env = {k: v for k, v in os.environ.items() if k not in ("SKINFIT_COMPILATION_CACHE", "JAX_COMPILATION_CACHE_DIR")}
    env.update(SKINFIT_CACHE_DIR=str(tmp_path / "cache"))
    done = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Error writing persistent compilation cache entry" not in done.stderr
    assert (folder / "jit_old_program-0123-atime").exists()
    assert json.loads(done.stdout.strip().splitlines()[-1])["files"] > 2  # the new program was written
