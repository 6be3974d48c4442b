"""The skin's own blur on a texel grid, and the albedo whose blurred render is a capture.

A renderer that traces light under the surface spreads what enters one texel over its
neighbours by the skin's radial profile: rendered under uniform light, per-texel media give
their albedos convolved with the profile's kernel (``profile_kernel``, ``blur_albedo``). A
measured albedo (a cross-polarised capture, or a photo's albedo) already holds that blur, so
maps fitted to it render blurred twice. ``deconvolve_albedo`` undoes one blur (regularised
inverse filter): fit the maps to its output and the renderer's blur brings back the capture.

The kernel is the model's RGB profile at one set of parameters (the face's median), with light
entering uniformly over the texel; the single-medium texture export matches each texel's median
energy radius to the model's, not the whole profile (see docs/renderers.md).
"""

from __future__ import annotations

import numpy as np

from .._validate import SkinfitInputError
from ..colorimetry import DEFAULT_ILLUMINANT, linear_srgb_weights
from ..model import SkinParams, profile
from ._renderers import cumulative_energy

_KERNEL_WAVELENGTHS_NM = np.arange(400.0, 701.0, 10.0)


def profile_kernel(params: SkinParams, mm_per_pixel: float, *, radius_pixels: int | None = None, illuminant: str = DEFAULT_ILLUMINANT,
                   model=None, samples: int = 4096) -> np.ndarray:
    """(k, k, 3) kernel per linear-sRGB channel, each summing to 1: the share of the light entering
    the centre texel (uniformly over it) that leaves through each texel, from the model's radial
    profile at ``params`` (scalars). ``radius_pixels`` (default: the radius holding 99.5 % of
    red's energy, at least 1) sets k = 2 radius + 1; light beyond it is dropped before the sum
    is normalised."""
    if not mm_per_pixel > 0:
        raise SkinfitInputError(f"mm_per_pixel must be positive, got {mm_per_pixel!r}")
    lam = _KERNEL_WAVELENGTHS_NM
    radii = np.geomspace(1e-4, 30.0, 600)  # mm
    weights = linear_srgb_weights(lam, illuminant)
    rgb = weights @ np.asarray(profile(params, lam, radii, entry_fresnel=True, model=model))  # (3, radii)
    energy = np.maximum.accumulate(np.asarray(cumulative_energy(radii, rgb)), axis=-1)
    energy = energy / energy[:, -1:]
    if radius_pixels is None:
        radius_pixels = max(1, int(np.ceil(np.interp(0.995, energy[0], radii) / mm_per_pixel)))
    k = 2 * radius_pixels + 1
    # exits: entry points on a 4 x 4 grid over the centre texel, radii at the energy's quantiles, 32 angles
    quantiles = (np.arange(samples) + 0.5) / samples
    angles = (np.arange(32) + 0.5) * (2 * np.pi / 32)
    entry = (np.arange(4) + 0.5) / 4 - 0.5
    ex, ey = (a.ravel() for a in np.meshgrid(entry, entry))
    kernel = np.zeros((k, k, 3))
    for c in range(3):
        r = np.interp(quantiles, energy[c], radii) / mm_per_pixel  # in texels
        x = (ex[:, None, None] + r[None, :, None] * np.cos(angles)).ravel()
        y = (ey[:, None, None] + r[None, :, None] * np.sin(angles)).ravel()
        i, j = np.rint(y).astype(int) + radius_pixels, np.rint(x).astype(int) + radius_pixels
        inside = (i >= 0) & (i < k) & (j >= 0) & (j < k)
        np.add.at(kernel[..., c], (i[inside], j[inside]), 1.0)
        kernel[..., c] /= kernel[..., c].sum()
    return kernel


def _transfer(kernel: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The kernel's transfer function (h, w//2 + 1, 3) on a grid of ``shape``, centred at the origin."""
    k = kernel.shape[0]
    padded = np.zeros((*shape, 3))
    padded[:k, :k] = kernel
    padded = np.roll(padded, (-(k // 2), -(k // 2)), axis=(0, 1))
    return np.fft.rfft2(padded, axes=(0, 1))


def _filled(rgb: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    """``rgb`` with the pixels outside ``mask`` set to the mask's mean colour (no edge to ring at)."""
    if mask is None:
        return rgb
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != rgb.shape[:2] or not mask.any():
        raise SkinfitInputError(f"mask must be (h, w) = {rgb.shape[:2]} with some pixels set")
    return np.where(mask[..., None], rgb, rgb[mask].mean(axis=0))


def _check(rgb, kernel) -> tuple[np.ndarray, np.ndarray]:
    rgb, kernel = np.asarray(rgb, dtype=float), np.asarray(kernel, dtype=float)
    if rgb.ndim != 3 or rgb.shape[-1] != 3:
        raise SkinfitInputError(f"expected an (h, w, 3) linear RGB image, got shape {rgb.shape}")
    if kernel.ndim != 3 or kernel.shape[0] != kernel.shape[1] or kernel.shape[0] % 2 == 0 or kernel.shape[-1] != 3:
        raise SkinfitInputError(f"expected a (k, k, 3) kernel with k odd (profile_kernel), got shape {kernel.shape}")
    return rgb, kernel


def blur_albedo(rgb, kernel, mask=None) -> np.ndarray:
    """``rgb`` (h, w, 3) convolved with ``kernel`` (``profile_kernel``) per channel, the image
    mirrored at its borders and filled outside ``mask`` with the mask's mean: what a renderer's
    subsurface transport does to per-texel albedos under uniform light."""
    rgb, kernel = _check(rgb, kernel)
    pad = kernel.shape[0] // 2
    image = np.pad(_filled(rgb, mask), ((pad, pad), (pad, pad), (0, 0)), mode="reflect")
    out = np.fft.irfft2(np.fft.rfft2(image, axes=(0, 1)) * _transfer(kernel, image.shape[:2]), s=image.shape[:2], axes=(0, 1))
    return out[pad:-pad, pad:-pad]


def deconvolve_albedo(rgb, kernel, mask=None, *, regularisation: float = 1e-3) -> np.ndarray:
    """The albedo (h, w, 3) whose ``blur_albedo`` is ``rgb``, by a regularised (Tikhonov) inverse
    filter per channel: conj(K) / (|K|^2 + ``regularisation``). Larger values keep more of the blur
    and amplify less noise. Clipped to [0, 1]."""
    rgb, kernel = _check(rgb, kernel)
    if not regularisation > 0:
        raise SkinfitInputError(f"regularisation must be positive, got {regularisation!r}")
    pad = kernel.shape[0] // 2
    image = np.pad(_filled(rgb, mask), ((pad, pad), (pad, pad), (0, 0)), mode="reflect")
    transfer = _transfer(kernel, image.shape[:2])
    inverse = np.conj(transfer) / (np.abs(transfer) ** 2 + regularisation)
    out = np.fft.irfft2(np.fft.rfft2(image, axes=(0, 1)) * inverse, s=image.shape[:2], axes=(0, 1))
    return np.clip(out[pad:-pad, pad:-pad], 0.0, 1.0)
