"""Caches that never capture a tracer.

A public call is as likely to come first inside ``jit``, ``vmap`` or ``grad`` as outside. Anything it
builds once and keeps (the default model, chromophore and colour tables, transport and fit tables)
must then be built eagerly, whatever trace the caller is in: built inside the trace it would hold
that trace's tracers, and every later call would meet a leaked tracer. Every cache in skinfit goes
through one of the three helpers here, which run a build that starts inside a trace under
``jax.ensure_compile_time_eval``.
"""

from __future__ import annotations

import contextlib
import functools
from collections import OrderedDict
from typing import Callable, Hashable, TypeVar

import jax

T = TypeVar("T")

try:  # private, hence guarded: without it every build runs under ensure_compile_time_eval
    from jax._src.core import trace_state_clean as _no_trace
except ImportError:  # pragma: no cover - another JAX
    def _no_trace() -> bool:
        return False


def _eagerly():
    """``jax.ensure_compile_time_eval()`` inside a trace; nothing outside one, where it would only
    compile the build's small programs a second time (JAX keys its in-memory cache by the context)."""
    return contextlib.nullcontext() if _no_trace() else jax.ensure_compile_time_eval()


def eager_cache(maxsize: int | None = None):
    """``functools.lru_cache(maxsize)`` whose misses are computed eagerly (outside any trace).

    Arguments must be hashable, as for ``lru_cache`` (a tracer is not, so no traced value can key it).
    """

    def decorate(build: Callable[..., T]) -> Callable[..., T]:
        @functools.lru_cache(maxsize)
        @functools.wraps(build)
        def cached(*args, **kwargs):
            with _eagerly():
                return build(*args, **kwargs)

        return cached

    return decorate


def eager_cached_property(build: Callable[[object], T]) -> functools.cached_property:
    """``functools.cached_property`` whose first access is computed eagerly (outside any trace)."""

    @functools.wraps(build)
    def eager(self):
        with _eagerly():
            return build(self)

    return functools.cached_property(eager)


class BoundedCache:
    """A dict-like cache of at most ``size`` entries (the oldest goes first), built eagerly on a miss.

    For values keyed by something ``lru_cache`` cannot hash directly (a model's values, through
    ``skinfit.model.cache_key``)."""

    def __init__(self, size: int):
        self.size = int(size)
        self._entries: OrderedDict = OrderedDict()

    def get(self, key: Hashable, build: Callable[[], T]) -> T:
        """The value under ``key``, made by ``build()`` (eagerly) if absent."""
        if key in self._entries:
            self._entries.move_to_end(key)
            return self._entries[key]
        with _eagerly():
            value = build()
        self._entries[key] = value
        while len(self._entries) > self.size:
            self._entries.popitem(last=False)
        return value

    def clear(self) -> None:
        self._entries.clear()

    def __len__(self) -> int:
        return len(self._entries)
