"""Traced programs kept on disk between processes (``skinfit._exported``)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from skinfit import _exported
from skinfit.fit import _pixels


@pytest.fixture
def programs(tmp_path, monkeypatch):
    """The disk cache on, in a private folder of its own; yields the programs' folder."""
    monkeypatch.setenv("SKINFIT_DISK_CACHE", "1")
    monkeypatch.setenv("SKINFIT_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache" / "programs"


def _scaled_sum(x, tol, n, power):
    """A program with a weakly typed scalar (tol), a traced integer (n) and a static one (power)."""
    return jnp.sum(jnp.where(x > tol, x**power, 0.0)) * n, x * tol


def test_a_program_is_written_once_and_read_by_a_new_process(programs, monkeypatch):
    """The first call traces, exports and saves the program; a new wrapper of the same function (what
    a new process has) reads it without tracing; both give jax.jit's results bit for bit, with
    jax.jit's dtypes (a Python float does not promote float32)."""
    x = jnp.linspace(0.0, 1.0, 7, dtype=jnp.float32)
    expected = jax.jit(_scaled_sum, static_argnums=3)(x, 0.3, 2, 3)
    first = _exported.PersistentJit(_scaled_sum, static_argnums=(3,))
    got = first(x, 0.3, 2, 3)
    assert len(list(programs.glob("*.npz"))) == 1
    monkeypatch.setattr(_exported.export, "export", lambda *a, **k: pytest.fail("traced again"))
    again = _exported.PersistentJit(_scaled_sum, static_argnums=(3,))(x, 0.3, 2, 3)
    for a, b, c in zip(expected, got, again):
        assert a.dtype == b.dtype == c.dtype == jnp.float32
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)


def test_other_shapes_and_static_values_are_other_programs(programs):
    wrapped = _exported.PersistentJit(_scaled_sum, static_argnums=(3,))
    x = jnp.linspace(0.0, 1.0, 7)
    wrapped(x, 0.3, 2, 3)
    wrapped(x[:5], 0.3, 2, 3)
    wrapped(x, 0.3, 2, 2)
    wrapped(x, 0.5, 4, 2)  # the same program: only traced values differ
    assert len(list(programs.glob("*.npz"))) == 3


def test_transformations_see_plain_jit(programs):
    """Under grad and vmap (tracers among the arguments) the function is jax.jit's: nothing is saved."""
    wrapped = _exported.PersistentJit(_scaled_sum, static_argnums=(3,))
    x = jnp.linspace(0.0, 1.0, 7)
    grad = jax.grad(lambda y: wrapped(y, 0.3, 2, 3)[0])(x)
    np.testing.assert_allclose(grad, jnp.where(x > 0.3, 6.0 * x**2, 0.0))
    assert jax.vmap(lambda y: wrapped(y, 0.3, 2, 3)[0])(x[:, None]).shape == (7,)
    assert not programs.exists() or not list(programs.glob("*.npz"))


def test_the_solvers_programs_round_trip_bit_for_bit(programs):
    """The pixel solver's Levenberg-Marquardt fallback (optimistix, with LAPACK's custom calls, which
    are allowed: the key holds the JAX version) gives the same roots from the saved program."""
    from skinfit.colorimetry import colour_table

    table = colour_table(0.425, "D65", nodes=17, inverse_cells=32)
    rng = np.random.default_rng(0)
    target = jnp.asarray(rng.uniform(0.2, 0.5, (4, 3)) * np.array([1.0, 0.7, 0.6]))
    roots, prior = jnp.full((4, 2), 0.3), jnp.zeros((4, 6))
    args = (jnp.asarray(table.coefficients), roots, target, prior, 20, 1e-10, 1e-12)
    plain = _pixels._levenberg_marquardt._jitted(*args)
    saved = _exported.PersistentJit(_pixels._levenberg_marquardt._function, static_argnums=(4, 5, 6))
    first = saved(*args)
    read = _exported.PersistentJit(_pixels._levenberg_marquardt._function, static_argnums=(4, 5, 6))(*args)
    assert len(list(programs.glob("*.npz"))) == 1
    for a, b, c in zip(plain, first, read):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
