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

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._caching import eager_cache
from .._validate import SkinfitInputError, is_concrete

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


@eager_cache(maxsize=64)
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


@eager_cache(maxsize=64)
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


@eager_cache(maxsize=1)
def _linear_srgb_to_relative_xyz_matrix() -> np.ndarray:
    """Linear sRGB -> XYZ / XYZ_white, the white being the sRGB white point (D65 xy 0.3127, 0.3290)
    as colour-science takes it for L*a*b*."""
    colour = _colour()
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    matrix = np.asarray(srgb.matrix_RGB_to_XYZ, dtype=float) / colour.xy_to_XYZ(srgb.whitepoint)[:, None]
    matrix.setflags(write=False)
    return matrix


def linear_srgb_to_lab(linear: ArrayLike) -> Float[Array, "... 3"]:
    """CIE L*a*b* of linear sRGB colours (..., 3), relative to the sRGB white (D65, RGB = 1)."""
    linear = jnp.asarray(linear)
    matrix = _linear_srgb_to_relative_xyz_matrix()
    rgb = linear[..., 0], linear[..., 1], linear[..., 2]
    # the 3x3 product written out: XLA's CPU backend runs a matmul over a last axis of 3 as a
    # separate, slow dot instead of fusing it
    return _lab_of_relative(*(sum(float(matrix[row, col]) * rgb[col] for col in range(3)) for row in range(3)))


def xyz_to_lab(
    xyz: ArrayLike,
    *,
    illuminant: str = DEFAULT_ILLUMINANT,
    observer: str = DEFAULT_OBSERVER,
    white_xyz: ArrayLike | None = None,
) -> Float[Array, "... 3"]:
    """CIE L*a*b* of XYZ colours (..., 3) (white Y = 1, as ``spectrum_to_xyz`` gives them), relative
    to the white point of ``illuminant`` (its chromaticity under ``observer``, as colour-science's
    ``XYZ_to_Lab`` takes it), or to ``white_xyz`` (3,) when given (e.g. the XYZ of the perfect
    reflector on a sampled wavelength grid)."""
    xyz = jnp.asarray(xyz)
    if white_xyz is None:
        white = [float(v) for v in _white_xyz(illuminant, observer)]
    else:
        white = [white_xyz[..., i] for i in range(3)]
    return _lab_of_relative(*(xyz[..., i] / white[i] for i in range(3)))


@eager_cache(maxsize=16)
def _white_xyz(illuminant: str, observer: str) -> np.ndarray:
    colour = _colour()
    if observer not in colour.CCS_ILLUMINANTS or illuminant not in colour.CCS_ILLUMINANTS[observer]:
        raise SkinfitInputError(f"no white point for illuminant {illuminant!r} under observer {observer!r} in colour-science")
    return np.asarray(colour.xy_to_XYZ(colour.CCS_ILLUMINANTS[observer][illuminant]), dtype=float)


def _lab_of_relative(x, y, z):
    """L*a*b* from X/Xn, Y/Yn, Z/Zn."""
    knee = (6.0 / 29.0) ** 3

    def f(t):  # cube root only above the knee, so its gradient never sees 0
        return jnp.where(t > knee, jnp.cbrt(jnp.maximum(t, knee)), t / (3 * (6.0 / 29.0) ** 2) + 4.0 / 29.0)

    fx, fy, fz = f(x), f(y), f(z)
    return jnp.stack([116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)], axis=-1)


def delta_e2000(lab_1: ArrayLike, lab_2: ArrayLike) -> Float[Array, "..."]:
    """CIEDE2000 colour difference between L*a*b* colours (..., 3) (Sharma, Wu & Dalal 2005).

    Written in JAX so that image fits compute it inside their compiled chunks; checked against
    colour-science's ``delta_E(method="CIE 2000")`` in ``tests/colorimetry/test_cie.py``.
    """
    lab_1, lab_2 = jnp.asarray(lab_1), jnp.asarray(lab_2)
    l1, a1, b1 = lab_1[..., 0], lab_1[..., 1], lab_1[..., 2]
    l2, a2, b2 = lab_2[..., 0], lab_2[..., 1], lab_2[..., 2]
    c_mean = 0.5 * (jnp.hypot(a1, b1) + jnp.hypot(a2, b2))
    g = 0.5 * (1.0 - jnp.sqrt(c_mean**7 / (c_mean**7 + 25.0**7)))
    a1, a2 = (1.0 + g) * a1, (1.0 + g) * a2
    c1, c2 = jnp.hypot(a1, b1), jnp.hypot(a2, b2)
    h1 = jnp.mod(jnp.arctan2(b1, a1), 2 * jnp.pi)
    h2 = jnp.mod(jnp.arctan2(b2, a2), 2 * jnp.pi)
    chromatic = c1 * c2 != 0
    dh = h2 - h1
    dh = jnp.where(dh > jnp.pi, dh - 2 * jnp.pi, jnp.where(dh < -jnp.pi, dh + 2 * jnp.pi, dh))
    dh = jnp.where(chromatic, dh, 0.0)
    d_l, d_c = l2 - l1, c2 - c1
    d_h = 2.0 * jnp.sqrt(c1 * c2) * jnp.sin(0.5 * dh)
    l_mean, c_mean = 0.5 * (l1 + l2), 0.5 * (c1 + c2)
    h_sum = h1 + h2
    h_mean = jnp.where(
        jnp.abs(h1 - h2) <= jnp.pi, 0.5 * h_sum, jnp.where(h_sum < 2 * jnp.pi, 0.5 * h_sum + jnp.pi, 0.5 * h_sum - jnp.pi)
    )
    h_mean = jnp.where(chromatic, h_mean, h_sum)
    deg = jnp.pi / 180.0
    # T of the mean hue from one cosine and one sine (multiple-angle identities instead of four cosines)
    cos_1, sin_1 = jnp.cos(h_mean), jnp.sin(h_mean)
    cos_2, sin_2 = 2.0 * cos_1 * cos_1 - 1.0, 2.0 * sin_1 * cos_1
    cos_3, sin_3 = cos_2 * cos_1 - sin_2 * sin_1, sin_2 * cos_1 + cos_2 * sin_1
    cos_4, sin_4 = 2.0 * cos_2 * cos_2 - 1.0, 2.0 * sin_2 * cos_2
    t = (
        1.0
        - 0.17 * (cos_1 * np.cos(30 * deg) + sin_1 * np.sin(30 * deg))
        + 0.24 * cos_2
        + 0.32 * (cos_3 * np.cos(6 * deg) - sin_3 * np.sin(6 * deg))
        - 0.20 * (cos_4 * np.cos(63 * deg) + sin_4 * np.sin(63 * deg))
    )
    rotation = 30 * deg * jnp.exp(-(((h_mean / deg - 275.0) / 25.0) ** 2))
    r_c = 2.0 * jnp.sqrt(c_mean**7 / (c_mean**7 + 25.0**7))
    s_l = 1.0 + 0.015 * (l_mean - 50.0) ** 2 / jnp.sqrt(20.0 + (l_mean - 50.0) ** 2)
    s_c = 1.0 + 0.045 * c_mean
    s_h = 1.0 + 0.015 * c_mean * t
    r_t = -jnp.sin(2.0 * rotation) * r_c
    terms = (d_l / s_l) ** 2 + (d_c / s_c) ** 2 + (d_h / s_h) ** 2 + r_t * (d_c / s_c) * (d_h / s_h)
    return jnp.sqrt(jnp.maximum(terms, 0.0))
