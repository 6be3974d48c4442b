"""JAX's persistent compilation cache for skinfit: compiled programs kept on disk between runs.

A fit compiles for several seconds on a small CPU; with the cache a second process loads the
programs instead. Importing skinfit turns it on where that is safe:

- never over the user's own JAX setting (``JAX_COMPILATION_CACHE_DIR`` or
  ``jax.config.update("jax_compilation_cache_dir", ...)`` made before the import wins);
- in a folder private to the user (created with mode 0700; a folder owned by someone else, or one
  that others may write to, is not used: JAX treats the cache as trusted code);
- one subfolder per machine (architecture, host name and CPU features): cached programs are native
  code for the CPU that compiled them, and a home folder shared by cluster nodes must not hand one
  node's programs to another;
- only programs that took 0.1 s or more to compile are written (smaller ones cost about as much to
  read as to compile; at 0.5 s the pixel solver's dozen programs of 0.1-0.4 s were compiled again
  in every process: the demo's first fit in a fresh process took 8.1-9.1 s, at 0.1 s 7.0-7.2 s,
  measured 2026-12-06), and the folder is kept under 2 GiB (JAX evicts the least recently used
  programs; one demo run wrote about 50 MB, 2026-12-06).

Opt out with the environment variable ``SKINFIT_COMPILATION_CACHE=0`` (set before the import). The
folder is ``$SKINFIT_CACHE_DIR/jax``, else ``$XDG_CACHE_HOME/skinfit/jax``, else
``~/.cache/skinfit/jax``.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import platform
import stat
from pathlib import Path

import jax

#: Environment variable that turns the cache off ("0", "off", "false" or "no").
OPT_OUT_VARIABLE = "SKINFIT_COMPILATION_CACHE"
MIN_COMPILE_SECONDS = 0.1
MAX_CACHE_BYTES = 2 * 1024**3


def cache_root() -> Path:
    """skinfit's cache folder: ``$SKINFIT_CACHE_DIR``, else ``$XDG_CACHE_HOME/skinfit``, else ``~/.cache/skinfit``."""
    root = os.environ.get("SKINFIT_CACHE_DIR")
    if root:
        return Path(root).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache").expanduser() / "skinfit"


def _cpu_features() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as file:
            for line in file:
                if line.startswith(("flags", "Features")):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def machine_key() -> str:
    """A folder name for this machine: its architecture and a digest of its host name and CPU features."""
    digest = hashlib.sha256(f"{platform.node()}|{_cpu_features()}".encode()).hexdigest()[:16]
    return f"{platform.machine() or 'unknown'}-{digest}"


def _private_folder(folder: Path) -> bool:
    """Create ``folder`` (mode 0700) if needed; True if it is ours and no one else may write to it."""
    try:
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        info = folder.stat()
    except OSError:
        return False  # a read-only home: run uncached
    if hasattr(os, "getuid") and info.st_uid != os.getuid():
        return False
    return not info.st_mode & (stat.S_IWGRP | stat.S_IWOTH)


def enable_compilation_cache() -> Path | None:
    """Point JAX's persistent compilation cache at skinfit's per-machine folder, where safe (module
    docstring). Returns the folder, or None where the cache was left as it was."""
    if os.environ.get(OPT_OUT_VARIABLE, "1").strip().lower() in ("0", "off", "false", "no"):
        return None
    if jax.config.jax_compilation_cache_dir:  # the user's own choice
        return None
    folder = cache_root() / "jax" / machine_key()
    if not _private_folder(folder):
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    if importlib.util.find_spec("filelock") is not None:  # a dependency; JAX needs it for the bound
        _backfill_access_times(folder)
        jax.config.update("jax_compilation_cache_max_size", MAX_CACHE_BYTES)
    return folder


def _backfill_access_times(folder: Path) -> None:
    """Give every cached program its access-time file, from the program's modification time.

    JAX's bounded cache keeps ``<key>-atime`` (nanoseconds, 8 bytes little-endian) beside each
    ``<key>-cache``; programs written while the cache had no bound have none, and then every later
    write fails (FileNotFoundError while choosing what to evict: a warning per compiled program,
    seen 2026-12-03 on a folder filled before the bound was set) and nothing more is cached."""
    try:
        for program in folder.glob("*-cache"):
            access = program.with_name(program.name.removesuffix("-cache") + "-atime")
            if not access.exists():
                access.write_bytes(program.stat().st_mtime_ns.to_bytes(8, "little"))
    except OSError:  # a folder we cannot read or write: JAX will report it where it matters
        pass
