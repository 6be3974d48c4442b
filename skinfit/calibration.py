"""Per-image unknowns fitted once over many pixels: the melanin blend and the camera white balance.

Three channels per pixel carry melanin, haemoglobin and shading; a fourth per-pixel unknown would
be unconstrained. Quantities that one image shares are another matter: thousands of pixels pin
them down. ``calibrate`` fits

- the melanin blend beta_m (``fit_blend``), and
- a white balance: per-channel camera gains (g_r, 1, g_b) with ``pixel = gains * shading * model
  colour`` (a von Kries adaptation: the unknown light and camera balance of a photo; green stays 1
  because the overall scale is the shading's),

by minimising a trimmed mean of the per-pixel fit's CIEDE2000 over a random sample of the image's
fittable pixels (the best ``trim`` fraction: hair, eyes, lips and background must not pull the
calibration). Blend: a grid over [0, 1] then a finer one around the best; gains: Nelder-Mead in
log space for each blend tried.

How well-posed this is: with the shading free per pixel, every pixel whose colour the model can
reach is fitted exactly whatever the blend and gains, so these are seen only through the edge of
the model's gamut: the calibration picks the blend and gains that let the model reach the most of
the image (a photo under warm light: measured on the bundled photo, gains (0.954, 1, 1.040)). An
image whose colours all lie inside the gamut for many choices (a rendering of the model itself)
does not determine them: the first best of the grid wins. Treat a fitted blend as a choice that
fits, not a measurement.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .colorimetry import DEFAULT_ILLUMINANT


@dataclasses.dataclass(frozen=True)
class ImageCalibration:
    """The fitted per-image unknowns and the score they reached (trimmed mean CIEDE2000)."""

    melanin_blend: float
    white_balance: tuple[float, float, float]
    score: float


def calibrate(
    pixels: np.ndarray,
    *,
    melanin_blend: float | None = None,
    white_balance: bool = True,
    illuminant: str = DEFAULT_ILLUMINANT,
    sample_size: int = 4096,
    trim: float = 0.5,
    seed: int = 0,
    method: str | None = None,
    model=None,
) -> ImageCalibration:
    """Fit the blend (unless given) and the white balance (if asked) to linear sRGB pixels (n, 3)
    that are fittable (finite, not black, not saturated, inside the mask)."""
    from scipy.optimize import minimize

    from .image_fit import fit_pixels

    pixels = np.asarray(pixels, dtype=float).reshape(-1, 3)
    if len(pixels) == 0:
        raise ValueError("no fittable pixels to calibrate on")
    rng = np.random.default_rng(seed)
    sample = pixels[rng.choice(len(pixels), min(sample_size, len(pixels)), replace=False)]

    def score(log_gains, blend):
        gains = np.exp([log_gains[0], 0.0, log_gains[1]])
        maps = fit_pixels(sample / gains, melanin_blend=blend, progress=False, lm_max_steps=0, method=method, model=model)
        delta_e = np.sort(maps["residual_dE2000"][maps["status"] <= 2])
        return float(np.mean(delta_e[: max(1, int(trim * len(delta_e)))])) if delta_e.size else np.inf

    def best_gains(blend):
        if not white_balance:
            return np.zeros(2), score(np.zeros(2), blend)
        result = minimize(score, np.zeros(2), args=(blend,), method="Nelder-Mead", options={"xatol": 1e-3, "fatol": 1e-4, "maxfev": 80})
        return result.x, float(result.fun)

    if melanin_blend is not None:
        blends = [float(melanin_blend)]
    else:
        blends = [0.0, 0.25, 0.5, 0.75, 1.0]
    tried = {b: best_gains(b) for b in blends}
    if melanin_blend is None:
        best = min(tried, key=lambda b: tried[b][1])
        for b in (best - 0.125, best + 0.125):
            if 0.0 <= b <= 1.0:
                tried[b] = best_gains(b)
    blend = min(tried, key=lambda b: tried[b][1])
    log_gains, value = tried[blend]
    gains = np.exp([log_gains[0], 0.0, log_gains[1]])
    return ImageCalibration(float(blend), tuple(float(g) for g in gains), value)
