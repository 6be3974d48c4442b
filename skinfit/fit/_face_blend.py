"""The melanin blend of each face, pooled over its skin, with its uncertainty.

Three channels per pixel carry melanin, haemoglobin and shading; the blend beta_m (the eumelanin
fraction) is one value per person, which thousands of pixels of one face can tell only through
what the colours allow. ``estimate_blends`` scores every blend of ``BLEND_GRID`` by fitting a
sample of each face's pixels at that blend (``fit_pixels`` on a coarse colour table, maximum
likelihood, the shading free, or held to its scale for an albedo capture) and reads the face's
posterior over the grid:

    S(beta) = trimmed mean over the sample of  |r|^2 / MODEL_DISCREPANCY^2 + z_k^2   +  z_beta^2

with r a pixel's relative colour residual, z_k its ln shading's distance from the albedo scale in
``ALBEDO_SHADING_SD`` (albedo captures only) and z_beta the blend's in the model's population prior
(logit normal; none without one). The mean over pixels weighs the face as one observation (its
pixels share the model's errors, they are not independent draws), whose colour the model reaches
to within ``MODEL_DISCREPANCY``; exp(-S / 2) over the grid is the face's posterior, whose mode is
the blend used and whose standard deviation is reported.

What it can tell. In an albedo capture the shading is known up to the image's one scale, so every
pixel's colour pins (C_m, beta_m, C_h) and the face's blend is measured. In a photo the shading is
free: at any blend every colour inside the model's gamut fits exactly, and only the gamut's edge
tells blends apart (dark skin lies outside the gamut of the light-skin blends); elsewhere the
posterior is the population prior, and its width goes into the maps' standard errors
(``melanin_log_slope``: how far ln C_m moves per unit blend at a fixed colour).

The grid's points are cell centres (0.025 ... 0.975): a face's blend never lies on a bound. A face
whose fits at its blend reach the edge of the default box is searched again, and fitted, on the
dark-skin box (``skinfit.colorimetry.DARK_MELANIN_MAX``; ``dark_box``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..colorimetry import DARK_HAEMOGLOBIN_MAX, DARK_MELANIN_MAX, DEFAULT_ILLUMINANT, HAEMOGLOBIN_MAX, MELANIN_MAX, colour_table
from ..model import resolve_model
from ._pixels import PixelStatus, fit_pixels
from ._variables import prior_coordinate

#: The blends tried: the centres of 20 cells of [0, 1].
BLEND_GRID = (np.arange(20) + 0.5) / 20

#: Relative RMS colour error (linear sRGB, per pixel) to which the model reproduces real skin: the
#: colour of the measured spectra of ISSA's cheeks against that of their own spectral fits
#: (``benchmarks/fit_image_tones.py`` reports it per group). What weighs a face's colours against
#: the blend's prior, and the model's share of the maps' standard errors.
MODEL_DISCREPANCY = 0.01

#: Spline nodes, inverse cells and box of the coarse colour tables the search fits on (0.2 s each
#: to build, against 4 s for a full table).
SEARCH_TABLE = {"nodes": 65, "inverse_cells": 64}
DARK_SEARCH_TABLE = {**SEARCH_TABLE, "melanin_max": DARK_MELANIN_MAX, "haemoglobin_max": DARK_HAEMOGLOBIN_MAX}

#: Share of a face's sample beyond 90 % of the default box's top (melanin or haemoglobin) at its
#: blend above which the face is fitted on the dark-skin box.
_EDGE_SHARE = 0.05


@dataclasses.dataclass(frozen=True)
class BlendEstimate:
    """One face's blend: the grid's posterior mode, the posterior's standard deviation, and the
    median slopes d ln C / d beta_m at a fixed colour over the face's sample (at the mode), which
    turn the blend's uncertainty into the maps'."""

    melanin_blend: float
    sd: float
    melanin_log_slope: float
    haemoglobin_log_slope: float
    pixels: int
    score: np.ndarray  # (len(BLEND_GRID),) S(beta) of the module docstring
    dark_box: bool = False  # fitted on the dark-skin box (its fits reach the default box's edge)

    def as_dict(self) -> dict:
        return {"melanin_blend": self.melanin_blend, "sd": self.sd, "melanin_log_slope": self.melanin_log_slope,
                "haemoglobin_log_slope": self.haemoglobin_log_slope, "pixels": self.pixels, "dark_box": self.dark_box}


def estimate_blends(
    faces: list[np.ndarray],
    *,
    model=None,
    illuminant: str = DEFAULT_ILLUMINANT,
    white_balance=(1.0, 1.0, 1.0),
    shading_prior: tuple[float, float] | None = None,
    prior: bool | None = None,
    sample_size: int = 256,
    trim: float = 0.8,
    seed: int = 0,
) -> list[BlendEstimate]:
    """The blend of each face from its fittable linear sRGB pixels (each (n_k, 3), camera values
    with ``white_balance``); ``shading_prior`` (scale, sd of ln shading) for an albedo capture;
    ``prior=False`` leaves the population prior on the blend out. All faces are fitted together,
    one coarse table per blend of the grid."""
    model = resolve_model(model)
    rng = np.random.default_rng(seed)
    samples = []
    for pixels in faces:
        pixels = np.asarray(pixels, dtype=float).reshape(-1, 3)
        if len(pixels) == 0:
            raise ValueError("a face without fittable pixels has no blend")
        samples.append(pixels[rng.choice(len(pixels), min(sample_size, len(pixels)), replace=False)])
    sizes = [len(s) for s in samples]
    target = np.concatenate(samples) / np.asarray(white_balance, dtype=float)
    owner = np.repeat(np.arange(len(samples)), sizes)

    population = model.prior if prior is not False else None
    blend_prior = None
    if population is not None and "melanin_blend" in population.names:
        blend_prior = population.moments("melanin_blend")
    arguments = dict(illuminant=illuminant, model=model, shading_prior=shading_prior, trim=trim)
    # the default box first; a face whose fits reach its edge at its blend is searched again on the
    # dark-skin box (not every face there: the wider box lets light skin reach the fold's other branch)
    search = _search(target, owner, len(samples), SEARCH_TABLE, **arguments)
    estimates = [_estimate(search, k, blend_prior, sizes[k], dark_box=False) for k in range(len(samples))]
    dark = [k for k, e in enumerate(estimates) if e.dark_box]
    if dark:
        keep = np.isin(owner, dark)
        relabel = {k: i for i, k in enumerate(dark)}
        wide = _search(target[keep], np.array([relabel[k] for k in owner[keep]]), len(dark), DARK_SEARCH_TABLE, **arguments)
        for k in dark:
            estimates[k] = _estimate(wide, relabel[k], blend_prior, sizes[k], dark_box=True)
    return estimates


def _search(target, owner, faces, table_size, *, illuminant, model, shading_prior, trim) -> dict:
    """Every face's score (faces, grid) before the blend prior, and per pixel the fitted ln C_m,
    ln C_h (pixels, grid) and whether the fit reaches the edge of the default box."""
    score = np.zeros((faces, len(BLEND_GRID)))
    log_melanin = np.full((len(target), len(BLEND_GRID)), np.nan)
    log_haemoglobin = np.full_like(log_melanin, np.nan)
    at_edge = np.zeros((len(target), len(BLEND_GRID)), bool)
    for j, blend in enumerate(BLEND_GRID):
        table = colour_table(float(blend), illuminant, model=model, **table_size)
        fit = fit_pixels(target, melanin_blend=float(blend), table=table, illuminant=illuminant, model=model, prior=False,
                         shading_prior=shading_prior, lm_max_steps=0, max_straggler_rounds=8, max_delta_e=np.inf, progress=False)
        fitted = fit["status"] <= PixelStatus.OUT_OF_MODEL
        residual = np.linalg.norm(target - fit["fitted_rgb"], axis=-1) / np.linalg.norm(target, axis=-1)
        per_pixel = (residual / MODEL_DISCREPANCY) ** 2
        if shading_prior is not None:
            scale, sd = shading_prior
            per_pixel = per_pixel + (np.log(np.maximum(fit["shading"], 1e-12) / scale) / sd) ** 2
        per_pixel = np.where(fitted, per_pixel, np.inf)
        for k in range(faces):
            values = np.sort(per_pixel[owner == k])
            score[k, j] = np.mean(values[: max(1, int(trim * len(values)))])
        ok = fitted & (fit["melanin"] > 0) & (fit["haemoglobin"] > 0)
        log_melanin[ok, j] = np.log(fit["melanin"][ok])
        log_haemoglobin[ok, j] = np.log(fit["haemoglobin"][ok])
        at_edge[:, j] = fitted & ((fit["melanin"] > 0.9 * MELANIN_MAX) | (fit["haemoglobin"] > 0.9 * HAEMOGLOBIN_MAX))
    return {"score": score, "owner": owner, "log_melanin": log_melanin, "log_haemoglobin": log_haemoglobin, "at_edge": at_edge}


def _estimate(search: dict, k: int, blend_prior, pixels: int, dark_box: bool) -> BlendEstimate:
    """Face ``k``'s posterior over the grid: its mode, sd and slopes there; on the default box,
    ``dark_box`` is whether its fits reach that box's edge at the mode."""
    s = search["score"][k]
    prior_term = 0.0 if blend_prior is None else ((prior_coordinate("melanin_blend", BLEND_GRID) - blend_prior[0]) / blend_prior[1]) ** 2
    s = s + prior_term if np.isfinite(s).any() else np.zeros_like(s) + prior_term  # nothing fits at any blend: the prior's
    best = int(np.argmin(s))
    weights = np.exp(-0.5 * (s - s[best]))
    weights /= weights.sum()
    mean = float(np.sum(weights * BLEND_GRID))
    # at least the grid's own resolution (a uniform cell's sd)
    sd = float(np.sqrt(np.sum(weights * (BLEND_GRID - mean) ** 2) + (BLEND_GRID[1] - BLEND_GRID[0]) ** 2 / 12))
    mine = search["owner"] == k
    reaches_edge = bool(np.mean(search["at_edge"][mine, best]) > _EDGE_SHARE)
    return BlendEstimate(float(BLEND_GRID[best]), sd, _slope(search["log_melanin"][mine], best), _slope(search["log_haemoglobin"][mine], best),
                         pixels, s, dark_box or reaches_edge)


def _slope(log_values: np.ndarray, best: int) -> float:
    """Median over pixels of d ln C / d beta at the grid's point ``best`` (central differences,
    one-sided at the grid's ends), from pixels fitted at both neighbours; 0 where none is."""
    low, high = max(0, best - 1), min(len(BLEND_GRID) - 1, best + 1)
    difference = (log_values[:, high] - log_values[:, low]) / (BLEND_GRID[high] - BLEND_GRID[low])
    difference = difference[np.isfinite(difference)]
    return float(np.median(difference)) if difference.size else 0.0
