"""Spectra to colour: CIE XYZ, linear sRGB and encoded sRGB under a chosen illuminant.

Colour matching functions and illuminant spectra come from colour-science (once per wavelength grid,
cached) and are applied inside JAX as a (3, n_wavelengths) weight matrix, so colour stays linear,
jit-able and differentiable.

Integration: the sampled spectrum is taken as piecewise linear between its samples and constant
beyond its ends, and integrated against illuminant x CMF on the 1 nm grid of the observer
(360-830 nm). Y is normalised so that a perfect white reflector has Y = 1 under every illuminant.

sRGB is defined for a D65 white. Under another illuminant, XYZ is first adapted to D65 with the
Bradford transform (a white-balanced camera), so a perfect white gives RGB (1, 1, 1) under any
illuminant.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._validate import SkinfitInputError, is_concrete

DEFAULT_ILLUMINANT = "D65"
DEFAULT_OBSERVER = "CIE 1931 2 Degree Standard Observer"


def _colour():
    import colour  # colour-science imports slowly; load it only when colour is asked for

    return colour


def _grid(wavelengths_nm) -> tuple[float, ...]:
    if not is_concrete(wavelengths_nm):
        raise SkinfitInputError("colour weights need concrete wavelengths (not traced values)")
    lam = np.asarray(wavelengths_nm, dtype=float).ravel()
    if lam.size == 0 or not np.all(np.isfinite(lam)):
        raise SkinfitInputError("wavelengths_nm must be finite and non-empty")
    if lam.size > 1 and np.any(np.diff(lam) <= 0):
        raise SkinfitInputError("wavelengths_nm must be strictly increasing for colour integration")
    return tuple(lam.tolist())


def xyz_weights(
    wavelengths_nm: ArrayLike, illuminant: str = DEFAULT_ILLUMINANT, observer: str = DEFAULT_OBSERVER
) -> np.ndarray:
    """Weights W of shape (3, n_wavelengths) with XYZ = W @ reflectance (white has Y = 1)."""
    return _xyz_weights(_grid(wavelengths_nm), illuminant, observer)


@functools.lru_cache(maxsize=64)
def _xyz_weights(wavelengths: tuple[float, ...], illuminant: str, observer: str) -> np.ndarray:
    colour = _colour()
    if observer not in colour.MSDS_CMFS:
        raise SkinfitInputError(f"unknown observer {observer!r}")
    if illuminant not in colour.SDS_ILLUMINANTS:
        raise SkinfitInputError(
            f"unknown illuminant {illuminant!r}; choose one of colour.SDS_ILLUMINANTS, e.g. D65, D50, A, E"
        )
    cmfs = colour.MSDS_CMFS[observer]
    grid = cmfs.wavelengths
    spd = colour.SDS_ILLUMINANTS[illuminant].copy().align(cmfs.shape).values
    weighted = spd[:, None] * cmfs.values  # (n_grid, 3), 1 nm steps
    lam = np.asarray(wavelengths)
    # Hat functions of linear interpolation (constant beyond the ends), sampled on the 1 nm grid.
    hats = np.stack([np.interp(grid, lam, row) for row in np.eye(lam.size)]) if lam.size > 1 else np.ones((1, grid.size))
    weights = (hats @ weighted).T / np.sum(spd * cmfs.values[:, 1])
    weights.setflags(write=False)
    return weights


@functools.lru_cache(maxsize=64)
def _xyz_to_linear_srgb_matrix(illuminant: str, observer: str) -> np.ndarray:
    colour = _colour()
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    white = _xyz_weights(tuple(np.arange(360.0, 831.0, 1.0).tolist()), illuminant, observer).sum(axis=1)
    d65 = colour.xy_to_XYZ(srgb.whitepoint)
    adapt = colour.adaptation.matrix_chromatic_adaptation_VonKries(white, d65, transform="Bradford")
    matrix = np.asarray(srgb.matrix_XYZ_to_RGB) @ adapt
    # Normalise so the illuminant's white maps exactly to (1, 1, 1) despite the rounded sRGB matrix.
    matrix = matrix / (matrix @ white)[:, None]
    matrix.setflags(write=False)
    return matrix


def spectrum_to_xyz(
    reflectance: ArrayLike,
    wavelengths_nm: ArrayLike,
    *,
    illuminant: str = DEFAULT_ILLUMINANT,
    observer: str = DEFAULT_OBSERVER,
) -> Float[Array, "... 3"]:
    """CIE XYZ (white Y = 1) of reflectance spectra of shape (..., n_wavelengths)."""
    return _weigh(reflectance, xyz_weights(wavelengths_nm, illuminant, observer))


def xyz_to_linear_srgb(
    xyz: ArrayLike, *, illuminant: str = DEFAULT_ILLUMINANT, observer: str = DEFAULT_OBSERVER
) -> Float[Array, "... 3"]:
    """Linear sRGB from XYZ computed under ``illuminant`` (Bradford-adapted to D65 if needed)."""
    xyz = jnp.asarray(xyz)
    matrix = _xyz_to_linear_srgb_matrix(illuminant, observer)
    return xyz @ jnp.asarray(matrix.T, xyz.dtype)


def linear_srgb_weights(
    wavelengths_nm: ArrayLike, illuminant: str = DEFAULT_ILLUMINANT, observer: str = DEFAULT_OBSERVER
) -> np.ndarray:
    """Weights of shape (3, n_wavelengths) taking a spectrum straight to linear sRGB."""
    return _xyz_to_linear_srgb_matrix(illuminant, observer) @ xyz_weights(wavelengths_nm, illuminant, observer)


def spectrum_to_linear_srgb(
    reflectance: ArrayLike,
    wavelengths_nm: ArrayLike,
    *,
    illuminant: str = DEFAULT_ILLUMINANT,
    observer: str = DEFAULT_OBSERVER,
) -> Float[Array, "... 3"]:
    """Linear sRGB of reflectance spectra of shape (..., n_wavelengths)."""
    return _weigh(reflectance, linear_srgb_weights(wavelengths_nm, illuminant, observer))


def spectrum_to_srgb(
    reflectance: ArrayLike,
    wavelengths_nm: ArrayLike,
    *,
    illuminant: str = DEFAULT_ILLUMINANT,
    observer: str = DEFAULT_OBSERVER,
) -> Float[Array, "... 3"]:
    """Encoded sRGB (IEC 61966-2-1 transfer function), clipped to [0, 1]."""
    linear = spectrum_to_linear_srgb(reflectance, wavelengths_nm, illuminant=illuminant, observer=observer)
    return srgb_encode(jnp.clip(linear, 0.0, 1.0))


_SRGB_KNEE = 0.0031308


def srgb_encode(linear: ArrayLike) -> Float[Array, "..."]:
    """sRGB transfer function (linear -> encoded); gradient-safe at 0."""
    linear = jnp.asarray(linear)
    # The power branch sees only values above the knee, so its gradient never meets 0 ** (negative).
    power = 1.055 * jnp.maximum(linear, _SRGB_KNEE) ** (1.0 / 2.4) - 0.055
    return jnp.where(linear <= _SRGB_KNEE, 12.92 * linear, power)


def srgb_decode(encoded: ArrayLike) -> Float[Array, "..."]:
    """Inverse sRGB transfer function (encoded -> linear)."""
    encoded = jnp.asarray(encoded)
    knee = 12.92 * _SRGB_KNEE
    power = ((jnp.maximum(encoded, knee) + 0.055) / 1.055) ** 2.4
    return jnp.where(encoded <= knee, encoded / 12.92, power)


def _weigh(reflectance, weights: np.ndarray):
    """Apply (3, n_wavelengths) colour weights along the last axis of ``reflectance``."""
    reflectance = jnp.asarray(reflectance)
    if reflectance.ndim == 0 or reflectance.shape[-1] != weights.shape[1]:
        raise SkinfitInputError(
            f"reflectance must have its last axis over the {weights.shape[1]} wavelengths, got shape {reflectance.shape}"
        )
    return reflectance @ jnp.asarray(weights.T, reflectance.dtype)
