"""Resampling and polygon filling in NumPy (no imaging library): what the models' inputs and the
region map need."""

from __future__ import annotations

import numpy as np

from .. import _scratch as scratch


def box_downscale(image: np.ndarray, factor: int) -> np.ndarray:
    """Mean over factor x factor blocks (an anti-aliasing prefilter before bilinear sampling)."""
    if factor <= 1:
        return image
    h, w = image.shape[0] // factor * factor, image.shape[1] // factor * factor
    if h == 0 or w == 0:
        return image[:h, :w].reshape(h // factor, factor, w // factor, factor, -1).mean(axis=(1, 3))
    out = None
    rows = factor * max(1, (1 << 20) // max(w * factor, 1))  # whole blocks, ~1 MP a band
    for top in range(0, h, rows):  # a band at a time: an out-of-core photo's pages given back after each
        bottom = min(top + rows, h)
        part = image[top:bottom, :w].reshape((bottom - top) // factor, factor, w // factor, factor, -1).mean(axis=(1, 3))
        if out is None:
            out = np.empty((h // factor, *part.shape[1:]), part.dtype)
        out[top // factor : bottom // factor] = part
        scratch.release_pages()
    return out


def warp(image: np.ndarray, centre_x: float, centre_y: float, side: float, angle: float, out: int) -> np.ndarray:
    """A square of ``side`` pixels about the centre, rotated by ``angle`` (radians), sampled to
    (out, out, 3) bilinearly with edges replicated: output pixel (u, v) is the image point
    c + R(angle) (((u + 0.5) / out - 0.5) side, ((v + 0.5) / out - 0.5) side)."""
    factor = int(side / out) if side / out >= 2 else 1
    source = box_downscale(image, factor)
    cx, cy, side = centre_x / factor, centre_y / factor, side / factor
    t = ((np.arange(out) + 0.5) / out - 0.5) * side
    u, v = np.meshgrid(t, t)
    c, s = np.cos(angle), np.sin(angle)
    return bilinear(source, c * u - s * v + cx - 0.5, s * u + c * v + cy - 0.5)


def bilinear(source: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``source`` (h, w, c) at pixel coordinates x, y (centres at integers), edges replicated."""
    h, w = source.shape[:2]
    x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    x0, y0 = np.minimum(x.astype(int), max(w - 2, 0)), np.minimum(y.astype(int), max(h - 2, 0))
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    top = source[y0, x0] * (1 - fx) + source[y0, x1] * fx
    bottom = source[y1, x0] * (1 - fx) + source[y1, x1] * fx
    return (top * (1 - fy) + bottom * fy).astype(np.float32)


def letterbox(image: np.ndarray, out: int) -> tuple[np.ndarray, float, int, int]:
    """The whole image in an (out, out, 3) square, aspect kept, centred, zero padding; returns it,
    the scale (square pixels per image pixel) and the offsets (x, y) of the image in it."""
    h, w = image.shape[:2]
    scale = out / max(h, w)
    factor = int(1 / scale) if 1 / scale >= 2 else 1
    source = box_downscale(image, factor).astype(np.float32)
    nh, nw = max(1, round(h * scale)), max(1, round(w * scale))
    y = (np.arange(nh) + 0.5) / (scale * factor) - 0.5
    x = (np.arange(nw) + 0.5) / (scale * factor) - 0.5
    xx, yy = np.meshgrid(x, y)
    square = np.zeros((out, out, 3), np.float32)
    oy, ox = (out - nh) // 2, (out - nw) // 2
    square[oy : oy + nh, ox : ox + nw] = bilinear(source, xx, yy)
    return square, scale, ox, oy


def fill_polygon(polygon: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(h, w) bool: pixels whose centres lie inside ``polygon`` (n, 2) of (x, y), even-odd rule,
    by scanlines (a difference array per row)."""
    h, w = shape
    polygon = np.asarray(polygon, np.float64)
    mask = np.zeros((h, w), bool)
    top, bottom = max(int(np.floor(polygon[:, 1].min())), 0), min(int(np.ceil(polygon[:, 1].max())) + 1, h)
    if bottom <= top:
        return mask
    rows = np.arange(top, bottom) + 0.5
    a, b = polygon, np.roll(polygon, -1, axis=0)
    crosses = (a[:, 1][None] <= rows[:, None]) != (b[:, 1][None] <= rows[:, None])  # (rows, edges)
    dy = np.where(crosses, b[:, 1] - a[:, 1], 1.0)  # an edge crossing a row is not horizontal
    x = np.where(crosses, a[:, 0] + (rows[:, None] - a[:, 1]) / dy * (b[:, 0] - a[:, 0]), np.inf)
    x.sort(axis=1)
    count = crosses.sum(axis=1)
    diff = np.zeros((bottom - top, w + 1), np.int32)
    index = np.arange(bottom - top)
    for k in range(0, x.shape[1] - 1, 2):
        inside = count > k + 1
        start = np.clip(np.ceil(x[inside, k] - 0.5), 0, w).astype(int)
        stop = np.clip(np.ceil(x[inside, k + 1] - 0.5), 0, w).astype(int)
        np.add.at(diff, (index[inside], start), 1)
        np.add.at(diff, (index[inside], stop), -1)
    mask[top:bottom] = np.cumsum(diff[:, :w], axis=1) > 0
    return mask
