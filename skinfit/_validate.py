"""Checks at the public boundary: clear errors for bad input, silent under tracing.

Values that are JAX tracers (inside jit, vmap or grad) cannot be inspected, so checks run only on
concrete inputs; that is where user input arrives.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


class SkinfitInputError(ValueError):
    """Bad input to a public skinfit function (the message says what and why)."""


def is_concrete(x) -> bool:
    """True if ``x`` holds values we can look at (not a tracer)."""
    return not isinstance(x, jax.core.Tracer)


def check_range(name: str, value, low: float, high: float, *, unit: str = "") -> None:
    """Raise SkinfitInputError unless every element of ``value`` lies in [low, high] and is finite."""
    if not is_concrete(value):
        return
    arr = np.asarray(value, dtype=float)
    if arr.size == 0:
        return
    unit = f" {unit}" if unit else ""
    if not np.all(np.isfinite(arr)):
        raise SkinfitInputError(f"{name} contains NaN or Inf")
    lo, hi = float(arr.min()), float(arr.max())
    if lo < low or hi > high:
        bad = lo if lo < low else hi
        raise SkinfitInputError(
            f"{name} = {bad:g}{unit} is outside the valid range [{low:g}, {high:g}]{unit}"
        )


def as_float_array(name: str, value, *, ndim: int | None = None) -> jax.Array:
    """Convert to a floating JAX array, with a clear error.

    Python scalars stay weakly typed, so they adopt the dtype of the arrays they meet (float32 inputs
    compute in float32); NumPy and JAX arrays keep their floating dtype.
    """
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if ndim not in (None, 0):
            raise SkinfitInputError(f"{name} must be {ndim}-D, got a scalar")
        return jnp.asarray(float(value))
    if is_concrete(value):
        try:
            arr = np.asarray(value)
        except Exception as err:  # noqa: BLE001 - anything unconvertible is a usage error
            raise SkinfitInputError(f"{name} must be numeric: {err}") from None
        if arr.dtype == object or not (
            np.issubdtype(arr.dtype, np.number) or arr.dtype == bool
        ):
            raise SkinfitInputError(f"{name} must be numeric, got dtype {arr.dtype}")
        if ndim is not None and arr.ndim != ndim:
            raise SkinfitInputError(f"{name} must be {ndim}-D, got shape {arr.shape}")
        if not np.issubdtype(arr.dtype, np.floating):
            arr = arr.astype(float)
        return jnp.asarray(arr)
    arr = jnp.asarray(value)
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(float)
    return arr


def wavelengths(value, *, low: float, high: float) -> jax.Array:
    """Validate a 1-D wavelength grid in nm (scalars become length-1 arrays)."""
    arr = as_float_array("wavelengths_nm", value)
    if arr.ndim == 0:
        arr = arr[None]
    if arr.ndim != 1:
        raise SkinfitInputError(f"wavelengths_nm must be 1-D, got shape {arr.shape}")
    if arr.shape[0] == 0:
        raise SkinfitInputError("wavelengths_nm is empty")
    check_range("wavelengths_nm", arr, low, high, unit="nm")
    return arr
