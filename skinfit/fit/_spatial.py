"""Image-space helpers of the image fit: smooth fields from scattered pixels and robust
neighbourhood values, at a cost that stays linear in the pixels (4096 x 4096 included)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from .. import _scratch as scratch


def smooth_field(values, weights, sigma_px: float, out: np.ndarray | None = None) -> np.ndarray:
    """Normalised Gaussian smoothing of ``values`` (h, w) where ``weights`` (h, w) > 0: the
    weighted mean within ~``sigma_px``, defined everywhere (pixels far from any weight get the
    weighted mean of the image). Computed on blocks of ~sigma/2 pixels and interpolated back
    linearly, so a large sigma costs no more than a small one; float32 out (into ``out`` (h, w)
    where given: an out-of-core array), and no full-size temporaries: ``values`` and ``weights``
    are read a band of rows at a time (either may be a ``skinfit._scratch.Rows`` expression)."""
    h, w = values.shape[:2]
    block = max(1, int(sigma_px // 2))
    hb, wb = -(-h // block), -(-w // block)
    num, den = np.zeros((hb, wb)), np.zeros((hb, wb))
    band = block * max(1, 256 // block)  # rows per band, whole blocks: the float64 products stay small
    for top in range(0, h, band):
        v = np.asarray(values[top : top + band], dtype=np.float64)
        wt = np.asarray(weights[top : top + band], dtype=np.float64)
        wt = np.where(np.isfinite(v), wt, 0.0)
        v = np.where(wt > 0, v, 0.0)
        rows = -(-v.shape[0] // block)
        padded_v, padded_w = np.zeros((rows * block, wb * block)), np.zeros((rows * block, wb * block))
        padded_v[: v.shape[0], :w], padded_w[: v.shape[0], :w] = v * wt, wt
        first = top // block
        num[first : first + rows] = padded_v.reshape(rows, block, wb, block).sum(axis=(1, 3))
        den[first : first + rows] = padded_w.reshape(rows, block, wb, block).sum(axis=(1, 3))
        scratch.release_pages()
    field = np.empty((h, w), np.float32) if out is None else out
    if not np.any(den > 0):
        field[:] = 0.0
        return field
    fallback = float(num.sum() / den.sum())
    num = ndimage.gaussian_filter(num, sigma_px / block, mode="nearest")
    den = ndimage.gaussian_filter(den, sigma_px / block, mode="nearest")
    coarse = np.where(den > 1e-6 * den.max(), num / np.maximum(den, 1e-300), fallback)
    if block == 1:
        field[:] = coarse[:h, :w]
        return field
    # block centres sit at (i + 0.5) block - 0.5 in pixels: interpolate linearly between them,
    # first along the rows (to (h, wb)), then along the columns
    # (the second pass a band of rows at a time: whole, its float64 products take ~40 bytes a pixel)
    along_rows = _interpolate_axis0(coarse, (np.arange(h) + 0.5) / block - 0.5)
    columns = (np.arange(w) + 0.5) / block - 0.5
    for top in range(0, h, band):
        field[top : top + band] = _interpolate_axis0(along_rows[top : top + band].T, columns).T
        scratch.release_pages()
    return field


def _interpolate_axis0(table: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Linear interpolation of the rows of ``table`` (n, m) at fractional row ``positions`` (k,),
    clamped to the first and last row."""
    positions = np.clip(positions, 0, table.shape[0] - 1)
    low = np.minimum(positions.astype(int), table.shape[0] - 2) if table.shape[0] > 1 else np.zeros(len(positions), int)
    high = np.minimum(low + 1, table.shape[0] - 1)
    t = (positions - low)[:, None]
    return table[low] * (1.0 - t) + table[high] * t


def neighbourhood_median(values: np.ndarray, valid: np.ndarray, size: int, fill: np.ndarray) -> np.ndarray:
    """Median of ``values`` (h, w) over size x size neighbourhoods, invalid pixels replaced by
    ``fill`` (h, w) first (a smooth field, so that a hole or an edge of the mask does not drag
    the median). Edge-preserving: a step between two regions keeps its place."""
    return ndimage.median_filter(np.where(valid, values, fill), size=size, mode="nearest")


def speckle_fraction(values: np.ndarray, valid: np.ndarray, factor: float = 2.0) -> float:
    """Fraction of valid pixels whose value differs from the median of its 3 x 3 neighbourhood
    (valid pixels only) by more than ``factor`` either way: isolated pixels on another branch."""
    if not valid.any():
        return 0.0
    filled = np.where(valid, np.log(np.maximum(values, 1e-12)), np.nan)
    # nan-aware 3x3 median from the nine shifted copies
    padded = np.pad(filled, 1, constant_values=np.nan)
    h, w = values.shape
    stack = np.stack([padded[i : i + h, j : j + w] for i in range(3) for j in range(3)])
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            median = np.nanmedian(stack, axis=0)
    return float(np.mean(np.abs(filled[valid] - median[valid]) > np.log(factor)))
