"""Every public function that evaluates the model under every JAX transformation, first call or not
(``tests/transformation_matrix.py`` holds the cases and the checks).

Quick tier: one fresh interpreter per transformation, whose first model calls (every case, the
default model) are under that transformation with ``jax.checking_leaks`` on, followed in the same
interpreter by every case under every transformation in the other dtype and by the other models
(``SkinModel.default()``, ``dj2006()``, one read from a file) under the first one. Slow tier: the
whole matrix (cases x transformations x models x dtypes) in one interpreter.

The interpreters share a persistent compilation cache in a temporary folder (all programs, however
small): a later interpreter loads what an earlier one compiled, which leaves the tracing, the part
under test, and halves the time. No tracer leak can hide there: leaks happen while tracing.
"""

from __future__ import annotations

import concurrent.futures
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import skinfit
from tests.transformation_matrix import CASES, TRANSFORMATIONS

ROOT = Path(__file__).resolve().parents[1]


def _environment(cache: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "SKINFIT_COMPILATION_CACHE"}
    env.update(
        JAX_COMPILATION_CACHE_DIR=str(cache / "jax"),  # the user's own setting: skinfit leaves it as it is
        JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0",
        JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES="-1",
        SKINFIT_CACHE_DIR=str(cache),
        PYTHONPATH=str(ROOT) + os.pathsep + env.get("PYTHONPATH", ""),
    )
    return env


def _matrix(first: str, dtype: str, model_file: Path, cache: Path, *extra: str) -> dict:
    command = [sys.executable, "-m", "tests.transformation_matrix", first, "--dtype", dtype, "--model-file", str(model_file), *extra]
    done = subprocess.run(command, cwd=ROOT, env=_environment(cache), capture_output=True, text=True, timeout=1800)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    """A model read from a file: the calibrated model with a thinner epidermis (transport method)."""
    path = tmp_path_factory.mktemp("model") / "thin_epidermis.json"
    skinfit.SkinModel.default().replace(epidermis_thickness_mm=0.2, name="thin-epidermis").save(path)
    return path


def _first_dtype(first: str) -> str:  # half the interpreters start in float32
    return ("float64", "float32")[TRANSFORMATIONS.index(first) % 2]


@pytest.fixture(scope="module")
def first_call_runs(model_file, tmp_path_factory) -> dict:
    """Every first transformation's interpreter, two at a time (the machine has two cores)."""
    cache = tmp_path_factory.mktemp("cache")
    with concurrent.futures.ThreadPoolExecutor(max_workers=2) as pool:
        runs = {first: pool.submit(_matrix, first, _first_dtype(first), model_file, cache, "--quick", "--check-leaks", "first")
                for first in TRANSFORMATIONS}
        return {first: run.result() for first, run in runs.items()}


@pytest.mark.parametrize("first", TRANSFORMATIONS)
def test_first_call_under_a_transformation_leaks_nothing(first, first_call_runs):
    run = first_call_runs[first]
    assert run["first"] == first and run["first_dtype"] == _first_dtype(first)
    # the first calls, then every case under every other transformation, then the other three models
    assert run["checks"] == len(CASES) * (1 + len(TRANSFORMATIONS) + 3)
    assert run["failures"] == [], json.dumps(run["failures"], indent=1)


@pytest.mark.slow
def test_whole_matrix_in_one_interpreter(model_file, tmp_path):
    run = _matrix("jit(vmap(grad))", "float64", model_file, tmp_path)
    assert run["checks"] == len(CASES) * len(TRANSFORMATIONS) * 4 * 2  # cases x transformations x models x dtypes
    assert run["failures"] == [], json.dumps(run["failures"], indent=1)


def test_a_cache_filled_inside_a_trace_holds_no_tracer():
    # the mechanism itself, in this process: a cache whose first call is inside jit returns a
    # concrete array there and after
    import jax
    import jax.numpy as jnp

    from skinfit._caching import BoundedCache, eager_cache

    @eager_cache()
    def table(n):
        return jnp.arange(float(n)) * 2.0

    store = BoundedCache(2)
    seen = []

    @jax.jit
    def traced(x):
        seen.append(isinstance(table(3), jax.core.Tracer))
        seen.append(isinstance(store.get("k", lambda: jnp.ones(3)), jax.core.Tracer))
        return x * table(3) + store.get("k", lambda: jnp.ones(3))

    with jax.checking_leaks():
        traced(jnp.ones(3))
        jax.grad(lambda x: jnp.sum(traced(x)))(jnp.ones(3))
    assert seen[:2] == [False, False]
    assert float(table(3)[2]) == 4.0 and not isinstance(store.get("k", lambda: None), jax.core.Tracer)
