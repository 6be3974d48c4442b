"""Traced programs kept on disk between processes (``jax.export``), so that a fresh process skips tracing.

The persistent compilation cache (``skinfit._compilation_cache``) saves compiling, but JAX still
traces and lowers every program in every process to find its cache key: for the pixel solver's
programs (a lock-step Gauss-Newton loop, optimistix's Levenberg-Marquardt) that is most of a first
fit in a fresh process. ``persistent_jit`` wraps a function as ``jax.jit`` does and, where the disk
cache is on (``skinfit._disk_cache``), serialises each program it traces (``jax.export``: StableHLO
with its calling convention) under a key of the function, its arguments' shapes, dtypes and weak
types, its static arguments, the backend, ``jax_enable_x64`` and a digest of skinfit's source; a
later process deserialises it (milliseconds) and compiles it, or finds it in the compilation cache.

The program run is the one ``jax.jit`` would run (the same StableHLO; results bit for bit the
same: ``tests/test_exported.py``). Inside a transformation (a tracer among the arguments) or with
the disk cache off (``SKINFIT_DISK_CACHE=0``, as in tests) the function is plain ``jax.jit``.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax import export

from . import _disk_cache

_CACHE_NAME = "programs"

#: Rounds of allowing the custom calls an export reports before a program is left to plain ``jax.jit``.
_MAX_CUSTOM_CALLS = 8


@functools.lru_cache(maxsize=1)
def _package_digest() -> str:
    """Digest of every source file of skinfit: a traced program depends on any module it calls."""
    digest = hashlib.blake2b(digest_size=16)
    package = Path(__file__).parent
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _spec(leaf) -> jax.ShapeDtypeStruct:
    """The abstract value ``jax.jit`` would trace ``leaf`` as (Python scalars weakly typed)."""
    weak = isinstance(leaf, (bool, int, float, complex))
    value = jnp.asarray(leaf) if weak else leaf
    return jax.ShapeDtypeStruct(np.shape(value), jnp.result_type(value), weak_type=weak or bool(getattr(value, "weak_type", False)))


class PersistentJit:
    """``jax.jit(function, static_argnums=...)`` whose traced programs persist on disk (module docstring)."""

    def __init__(self, function, static_argnums: tuple[int, ...] = ()):
        self._function = function
        self._static = tuple(sorted(static_argnums))
        self._jitted = jax.jit(function, static_argnums=self._static)
        self._programs: dict[tuple, object] = {}
        functools.update_wrapper(self, function)

    def __call__(self, *args):
        if not _disk_cache.enabled():
            return self._jitted(*args)
        static = tuple(args[i] for i in self._static)
        dynamic = [a for i, a in enumerate(args) if i not in self._static]
        leaves, tree = jax.tree.flatten(dynamic)
        if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
            return self._jitted(*args)
        specs = tuple(_spec(leaf) for leaf in leaves)
        key = (tree, tuple((s.shape, s.dtype.str, s.weak_type) for s in specs), static)
        program = self._programs.get(key)
        if program is None:
            exported = self._exported(tree, specs, static, key)
            program = self._programs[key] = self._jitted if exported is None else jax.jit(exported.call)
        return program(*args) if program is self._jitted else program(*leaves)

    def _exported(self, tree, specs, static, key) -> export.Exported | None:
        disk_key = (f"{self._function.__module__}.{self._function.__qualname__}", str(key), jax.default_backend(),
                    bool(jax.config.jax_enable_x64), jax.__version__, importlib.metadata.version("jaxlib"), _package_digest())
        stored = _disk_cache.load_arrays(_CACHE_NAME, disk_key)
        if stored is not None:
            try:
                return export.deserialize(bytearray(stored["exported"].tobytes()))
            except Exception:  # written by another JAX (the key holds its version): trace again
                pass

        def flat(*leaves):
            dynamic = jax.tree.unflatten(tree, leaves)  # the list of the non-static arguments
            count, dynamic, statics = len(static) + len(dynamic), iter(dynamic), iter(static)
            return self._function(*(next(statics) if i in self._static else next(dynamic) for i in range(count)))

        # LAPACK's custom calls (lineax's QR in optimistix's Levenberg-Marquardt) carry no guarantee
        # across JAX versions; the key holds the version and the machine's backend, so they are
        # allowed, as each is found
        allowed = []
        for _ in range(_MAX_CUSTOM_CALLS):
            try:
                exported = export.export(jax.jit(flat), disabled_checks=allowed)(*specs)
                break
            except ValueError as error:
                targets = set(re.findall(r"custom_call @(\w+)", str(error))) - {c.is_custom_call() for c in allowed}
                if not targets:
                    raise
                allowed += [export.DisabledSafetyCheck.custom_call(t) for t in sorted(targets)]
        else:
            return None
        _disk_cache.save_arrays(_CACHE_NAME, disk_key, {"exported": np.frombuffer(exported.serialize(), np.uint8)})
        return exported


def persistent_jit(function=None, *, static_argnums: tuple[int, ...] = ()):
    """Decorator: ``jax.jit`` with traced programs kept on disk between processes (``PersistentJit``)."""
    if function is None:
        return functools.partial(persistent_jit, static_argnums=static_argnums)
    return PersistentJit(function, static_argnums)
