"""Per-image unknowns fitted once over many pixels: the melanin blend and the camera white balance.

Three channels per pixel carry melanin, haemoglobin and shading; a fourth per-pixel unknown would
be unconstrained. Quantities that one image shares are another matter: thousands of pixels pin
them down. ``calibrate`` fits

- the melanin blend beta_m (``fit_blend``), and
- a white balance: per-channel camera gains (g_r, 1, g_b) with ``pixel = gains * shading * model
  colour`` (a von Kries adaptation: the unknown light and camera balance of a photo; green stays 1
  because the overall scale is the shading's),

by minimising a trimmed mean of a per-pixel score over a random sample of the image's fittable
pixels (the best ``trim`` fraction: hair, eyes, lips and background must not pull the
calibration). Blend: a grid over [0, 1] then a finer one around the best; gains, for each blend
tried: a 5 x 5 grid of ln gains in [-0.4, 0.4] on a quarter of the sample, a 5 x 5 grid of step
0.05 about its best on the whole sample, then two Newton steps from least-squares quadratics
fitted to 3 x 3 stencils (the quadratic's Hessian gives the standard errors), all inside
``_GAIN_BOUND`` standard deviations of the camera prior. Each grid or stencil is one batched call
of the compiled pixel fit over all its gain candidates (Nelder-Mead over whole fits took three
times as long for the same gains, to 0.003).

The camera prior. A photo's JPEG is white-balanced by its camera already, and an albedo capture by
its maker: the gains left to find are small. ln g_r and ln g_b are taken as normal about 0 with
standard deviation ``camera_sd`` (0.15: about 15 % per channel), and the search never leaves 3 of
them (gains 0.64-1.57). Without it, on a studio portrait whose backdrop and clothes the sample
held, the search ran to gains 0.41 / 1.00 / 3.78, under which the backdrop was in the skin gamut
and the face was not.

The score. With the shading free per pixel, every pixel whose colour the model can reach is fitted
exactly whatever the blend and gains: the colour residual alone sees them only through the edge of
the model's gamut, and an image whose colours all lie inside it for many gains (most albedo
captures) does not determine them. A model with a population prior (the calibrated model) scores
each pixel by its negative log posterior instead, |r|^2 / colour_noise^2 + z^2 (r the relative
colour residual of the MAP fit, z the fitted ln C_m and ln C_h in prior standard deviations): the
gains that make the image's skin reachable with the parameters skin has. The score is a mean over
pixels, which weighs the face as one draw from the population; the camera prior's
(ln g / camera_sd)^2 is added to it as one draw from the cameras. Read as -2 ln of the posterior of
the gains, its curvature at the optimum gives their standard errors (``white_balance_sd``,
relative): what the data and the two priors leave of them, not a measurement error. This is a prior
assumption as much as a measurement (like a grey-world white balance, with the population's skin
as the grey): a face far from the population (very light or very dark skin) pulls the gains
toward the population by up to the spread the prior allows, and every pixel counts as an
independent draw from the population, which overstates what the prior knows about one face.
Measured: on the demo photo (warm studio light) gains (0.78-0.82, 1, 1.04-1.10) take the skin mask
from 92 % to 98 % fitted; on a smooth rendering of the model that spans melanin 0.2-40 % (no face's
distribution), the gains move to about (1.2, 1, 0.8) and every parameter is biased (benchmarks/white_balance.py): fit renderings,
and other inputs known to be calibrated, with ``white_balance="none"``. Without a prior (DJ2006) the score is
the CIEDE2000 of the maximum-likelihood fit, the gamut coverage. Treat fitted gains and blend as
choices that fit, not measurements; where a colour chart is in the frame, calibrate from it.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..colorimetry import DEFAULT_ILLUMINANT
from ..model import resolve_model
from ._pixels import fit_pixels
from ._variables import prior_coordinate


@dataclasses.dataclass(frozen=True)
class ImageCalibration:
    """The fitted per-image unknowns and the score they reached (trimmed mean CIEDE2000)."""

    melanin_blend: float
    white_balance: tuple[float, float, float]
    score: float
    #: standard errors of ln g (r, g, b) (relative errors of the gains; green 0 by definition),
    #: or None where the score is not a posterior (a model without a population prior)
    white_balance_sd: tuple[float, float, float] | None = None


#: Standard deviation of the camera prior on ln g_r and ln g_b.
CAMERA_SD = 0.15

#: The search's bound on |ln g|, in camera-prior standard deviations.
_GAIN_BOUND = 3.0


#: ln gains of the coarse grid that starts the white balance search (gains 0.67-1.5).
_GAIN_GRID = np.linspace(-0.4, 0.4, 5)


def calibrate(
    pixels: np.ndarray,
    *,
    melanin_blend: float | None = None,
    white_balance: bool = True,
    illuminant: str = DEFAULT_ILLUMINANT,
    sample_size: int = 2048,
    trim: float = 0.8,
    seed: int = 0,
    method: str | None = None,
    model=None,
    colour_noise: float = 0.003,
    prior: bool | None = None,
    camera_sd: float = CAMERA_SD,
) -> ImageCalibration:
    """Fit the blend (unless given) and the white balance (if asked) to linear sRGB pixels (n, 3)
    that are fittable (finite, not black, not saturated, inside the mask); ``colour_noise`` as in
    ``fit_pixels``; ``prior=False`` scores by the gamut alone even for a model with a prior.
    ``score`` is the trimmed mean of the per-pixel score at the optimum (with the camera prior's
    term where the score is a posterior); ``camera_sd`` the camera prior's standard deviation of
    ln g (``inf``: none, and no bound)."""
    pixels = np.asarray(pixels, dtype=float).reshape(-1, 3)
    if len(pixels) == 0:
        raise ValueError("no fittable pixels to calibrate on")
    rng = np.random.default_rng(seed)
    sample = pixels[rng.choice(len(pixels), min(sample_size, len(pixels)), replace=False)]

    population = None if prior is False else resolve_model(model).prior
    bound = _GAIN_BOUND * camera_sd

    def scores(log_gains, blend, pixels=sample) -> np.ndarray:
        """The score at each of (k, 2) ln gains (r, b): one batched fit of the k corrected copies
        of ``pixels`` (one call, not k: a call's fixed cost is most of a 2,048-pixel fit's)."""
        log_gains = np.atleast_2d(np.asarray(log_gains, dtype=float))
        out = np.full(len(log_gains), np.inf)
        inside = np.flatnonzero(np.all(np.abs(log_gains) <= bound + 1e-12, axis=1))
        if inside.size == 0:
            return out
        gains = np.exp(np.stack([log_gains[inside, 0], np.zeros(inside.size), log_gains[inside, 1]], axis=-1))
        targets = (pixels[None] / gains[:, None, :]).reshape(-1, 3)
        maps = fit_pixels(targets, melanin_blend=blend, progress=False, lm_max_steps=0, max_straggler_rounds=8, method=method,
                          model=model, prior=population is not None, colour_noise=colour_noise)
        n = len(pixels)
        for j, k in enumerate(inside):
            part = {name: value[j * n:(j + 1) * n] for name, value in maps.items()}
            out[k] = _pixel_score(targets[j * n:(j + 1) * n], part, log_gains[k], population, colour_noise, trim, camera_sd)
        return out

    def best_gains(blend):
        """(ln gains (r, b), score, Hessian of the score there or None) at ``blend``."""
        if not white_balance:
            return np.zeros(2), float(scores(np.zeros(2), blend)[0]), None
        # the coarse grid on a quarter of the sample (the score has flat regions and local minima),
        # then a 5 x 5 grid of step 0.05 about its best on the whole sample, with the neutral point,
        # then two quadratic steps on 3 x 3 stencils (whose fit gives the Hessian as well)
        grid = np.array([[r, b] for r in _GAIN_GRID for b in _GAIN_GRID if max(abs(r), abs(b)) <= bound])
        start = grid[int(np.argmin(scores(grid, blend, sample[: max(1, len(sample) // 4)])))]
        local = np.vstack([start + _REFINE_STEP * _STENCIL_5, np.zeros((1, 2))])
        values = scores(local, blend)
        neutral = float(values[-1])
        best = local[int(np.argmin(values[:-1]))]
        x, value, hessian = best, float(np.min(values[:-1])), None
        for _ in range(_QUADRATIC_STEPS):
            x, value, hessian = _quadratic_step(lambda g: scores(g, blend), x, value)
        # gains 1 unless others score clearly better: an image the model reaches for any gains
        # (a rendering of the model) keeps its balance rather than drifting on round-off
        if not value < neutral - 1e-3 * abs(neutral) - 1e-9:
            return np.zeros(2), neutral, None
        return x, value, hessian

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
    log_gains, value, hessian = tried[blend]
    gains = np.exp([log_gains[0], 0.0, log_gains[1]])
    sd = _laplace_sd(hessian) if white_balance and population is not None and hessian is not None else None
    return ImageCalibration(float(blend), tuple(float(g) for g in gains), value, sd)


#: Step in ln g of the refining grid and of the quadratic steps' 3 x 3 stencils.
_REFINE_STEP = 0.05
_CURVATURE_STEP = 0.03
_QUADRATIC_STEPS = 2
#: Weight of the untrimmed mean CIEDE2000 (capped at 1) in the likelihood score (no prior).
_REACH_WEIGHT = 0.01
_STENCIL_5 = np.array([[i, j] for i in range(-2, 3) for j in range(-2, 3)], dtype=float)
_STENCIL_3 = np.array([[i, j] for i in range(-1, 2) for j in range(-1, 2)], dtype=float)


def _quadratic_step(scores, x, value):
    """One Newton step on the quadratic fitted to the score on a 3 x 3 stencil of step
    ``_CURVATURE_STEP`` about x (limited to the stencil). Returns (x', S(x'), Hessian at x); x' is
    x itself where the step does not lower the score or the quadratic is not convex."""
    h = _CURVATURE_STEP
    points = x + h * _STENCIL_3
    values = scores(points)
    if not np.all(np.isfinite(values)):
        best = int(np.argmin(values))
        return (points[best], float(values[best]), None) if values[best] < value else (x, value, None)
    d = _STENCIL_3  # in units of h: S = c + g.d + d.H.d / 2
    design = np.column_stack([np.ones(9), d[:, 0], d[:, 1], d[:, 0] ** 2 / 2, d[:, 1] ** 2 / 2, d[:, 0] * d[:, 1]])
    c, g0, g1, h00, h11, h01 = np.linalg.lstsq(design, values, rcond=None)[0]
    hessian = np.array([[h00, h01], [h01, h11]]) / h**2
    candidates = [(points[int(np.argmin(values))], float(np.min(values)))]
    if np.linalg.det(hessian) > 0 and hessian[0, 0] > 0:
        step = np.clip(-np.linalg.solve(np.array([[h00, h01], [h01, h11]]), [g0, g1]), -1.0, 1.0) * h
        candidates.append((x + step, float(scores(x + step)[0])))
    else:
        hessian = None
    new, new_value = min(candidates, key=lambda c: c[1])
    return (new, new_value, hessian) if new_value < value else (x, value, hessian)


def _laplace_sd(hessian) -> tuple[float, float, float] | None:
    """Standard errors of ln g_r, ln g_b from the curvature H of the score S (= -2 ln posterior)
    at its optimum: covariance 2 H^-1. None where S is not convex there."""
    if not np.all(np.isfinite(hessian)) or np.linalg.det(hessian) <= 0 or hessian[0, 0] <= 0:
        return None
    covariance = 2.0 * np.linalg.inv(hessian)
    return (float(np.sqrt(covariance[0, 0])), 0.0, float(np.sqrt(covariance[1, 1])))


def _pixel_score(target, maps, log_gains, population, colour_noise, trim, camera_sd) -> float:
    """The score of one set of gains from the fit of the corrected pixels ``target`` (see the
    module docstring)."""
    fitted = maps["status"] <= 2
    if not fitted.any():
        return np.inf
    if population is not None:
        camera = float(np.sum((log_gains / camera_sd) ** 2)) if np.isfinite(camera_sd) else 0.0
        return _negative_log_posterior(target[fitted], maps, fitted, population, colour_noise, trim) + camera
    per_pixel = np.sort(maps["residual_dE2000"][fitted])
    # the trimmed mean is flat (zero) over every gain that brings the best ``trim`` of the pixels
    # into the gamut; the untrimmed mean of the misses (capped at 1 CIEDE2000: a background pixel
    # counts as one miss), weighed 1 %, picks among those the gains that reach the most
    reach = _REACH_WEIGHT * float(np.mean(np.minimum(per_pixel, 1.0)))
    return float(np.mean(per_pixel[: max(1, int(trim * len(per_pixel)))])) + reach


def _negative_log_posterior(target, maps, fitted, prior, colour_noise, trim):
    """Trimmed mean over the fitted pixels of |r|^2 / colour_noise^2 + z^2 of the MAP fit (see the
    module docstring)."""
    residual = (target - maps["fitted_rgb"][fitted]) / np.linalg.norm(target, axis=-1, keepdims=True)
    total = np.sum(residual**2, axis=-1) / colour_noise**2
    for name in ("melanin", "haemoglobin"):
        mean, sd = prior.moments(name)
        total = total + ((prior_coordinate(name, maps[name][fitted]) - mean) / sd) ** 2
    total = np.sort(total)
    return float(np.mean(total[: max(1, int(trim * len(total)))]))
