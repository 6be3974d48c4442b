"""Profiles in the forms renderers read: energy-bounded tables, sums of Gaussians, Christensen-Burley
parameters, a homogeneous medium per channel (pbrt-v4, Blender), and textures from parameter maps.

Conventions (stated in every export): radii in mm, coefficients in mm^-1, profiles R(r) in mm^-2
integrating (2 pi r dr) to the diffuse reflectance R_d = (1 - F0) R12(0) (specular excluded, entry
Fresnel included); RGB is linear sRGB under the chosen illuminant (D65 by default) with the same
colour weights as ``colorimetry``.

- **Energy-bounded tables**: the largest radius is where every RGB channel has captured
  ``energy_fraction`` (99.7 % by default) of its energy; radii are log-spaced from
  ``max_radius / 1e4``; each row is scaled by R_d / E, E its integral over the table (trapezoid in
  ln r of 2 pi r^2 R), so the table integrates to the reflectance it came from; the scale is stored.
- **Sum of Gaussians** (d'Eon & Luebke 2007): R(r) ~ sum_k w_k exp(-r^2 / 2 v_k) / (2 pi v_k),
  six terms per channel, weights non-negative and summing to R_d, variances in mm^2, fitted to
  the cumulative energy. Errors, as fractions of the channel's energy: ``energy_error``, the
  largest misplaced energy max_r |E_fit(r) - E(r)|, and ``density_l1_error``,
  int 2 pi r |R - fit| dr. Linear-sRGB profiles can dip below zero at large r (the sRGB
  primaries have negative weights where the red tail is long); a non-negative sum cannot follow.
- **Christensen-Burley** (2015): R(r) = A s (exp(-s r) + exp(-s r / 3)) / (8 pi r) with A = R_d
  and the shape s fitted to the cumulative energy; reported as d = 1 / s in mm, with the same
  errors.
- **Medium**: per channel, the semi-infinite homogeneous medium (same index, same DJ2005 model)
  whose diffuse reflectance equals the channel's R_d and whose profile has the same median energy
  radius; its absorption and reduced scattering in mm^-1 and mean free path 1 / sigma_t' in mm.
  That is what pbrt-v4's ``subsurface`` material (sigma_a, sigma_s with g = 0) and Blender's
  Principled BSDF (base colour, subsurface radius = mean free path) take; each renderer then
  applies its own transport model, so its profile differs from ours (the Burley error says by
  how much for that shape).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import scipy.optimize

from . import __version__
from ._validate import SkinfitInputError
from .colorimetry import DEFAULT_ILLUMINANT, linear_srgb_weights
from .layers import SKIN_IOR
from .multipole import dipole_energy
from .params import SkinParams
from .profiles import profile
from .reflectance import diffuse_reflectance, model_with_options, normal_fresnel_reflectance

ENERGY_FRACTION = 0.997
GAUSSIAN_TERMS = 6
CHANNELS = ("red", "green", "blue")
_DENSE_RADII = np.geomspace(1e-5, 200.0, 3000)


@dataclasses.dataclass(frozen=True)
class RendererProfiles:
    """Everything a renderer needs for one parameter set (see the module docstring).

    Attributes:
        wavelengths_nm: (n_wavelengths,)
        radii_mm: (n_radii,) log-spaced up to ``max_radius_mm``.
        spectral: (n_wavelengths, n_radii) R(r) in mm^-2, scaled to integrate to ``reflectance``.
        rgb: (3, n_radii) linear-sRGB profiles in mm^-2, scaled to integrate to ``rgb_albedo``.
        reflectance: (n_wavelengths,) diffuse reflectance R_d.
        rgb_albedo: (3,) R_d in linear sRGB.
        max_radius_mm: the radius where every channel has captured ``energy_fraction``.
        captured: (3,) energy fraction of each RGB channel within ``max_radius_mm`` (unscaled).
        gaussians: per channel {"variances_mm2", "weights", "energy_error"}.
        burley: per channel {"albedo", "shape_mm" (d = 1/s), "energy_error"}.
        medium: per channel lists {"absorption_per_mm", "reduced_scattering_per_mm",
            "mean_free_path_mm", "reduced_albedo", "median_radius_mm"}.
        metadata: parameters, options, units, conventions.
    """

    wavelengths_nm: np.ndarray
    radii_mm: np.ndarray
    spectral: np.ndarray
    rgb: np.ndarray
    reflectance: np.ndarray
    rgb_albedo: np.ndarray
    max_radius_mm: float
    captured: np.ndarray
    gaussians: dict
    burley: dict
    medium: dict
    metadata: dict


def cumulative_energy(radii_mm: np.ndarray, profiles: np.ndarray) -> np.ndarray:
    """int_0^r 2 pi r' R(r') dr' at each radius (trapezoid in ln r; the part below the first radius
    is taken as 2 pi r0^2 R(r0), exact for R ~ 1/r, the dipole's small-r form)."""
    ln_r = np.log(radii_mm)
    f = 2 * np.pi * radii_mm**2 * profiles
    steps = 0.5 * (f[..., 1:] + f[..., :-1]) * np.diff(ln_r)
    return f[..., :1] + np.concatenate([np.zeros_like(f[..., :1]), np.cumsum(steps, axis=-1)], axis=-1)


def renderer_profiles(
    params: SkinParams,
    wavelengths_nm=np.arange(400.0, 701.0, 10.0),
    *,
    illuminant: str = DEFAULT_ILLUMINANT,
    energy_fraction: float = ENERGY_FRACTION,
    n_radii: int = 256,
    label: str = "",
    **model_options,
) -> RendererProfiles:
    """Energy-bounded spectral and RGB tables, sum-of-Gaussians and Burley fits and the per-channel
    medium of one (scalar) parameter set; ``model_options`` as in ``diffuse_reflectance``."""
    if params.shape != ():
        raise SkinfitInputError("renderer_profiles takes one parameter set (scalar SkinParams fields)")
    if not 0.5 < energy_fraction < 1.0:
        raise SkinfitInputError(f"energy_fraction must be in (0.5, 1), got {energy_fraction}")
    lam = np.asarray(wavelengths_nm, dtype=float)
    weights = linear_srgb_weights(lam, illuminant)
    reflectance = np.asarray(diffuse_reflectance(params, lam, **model_options))
    albedo = weights @ reflectance
    dense = np.asarray(profile(params, lam, _DENSE_RADII, entry_fresnel=True, **model_options))
    dense_rgb = weights @ dense
    energy = cumulative_energy(_DENSE_RADII, dense_rgb) / albedo[:, None]
    reach = [float(np.interp(energy_fraction, np.maximum.accumulate(e), _DENSE_RADII)) for e in energy]
    max_radius = max(reach)

    radii = np.geomspace(max_radius * 1e-4, max_radius, n_radii)
    spectral = np.asarray(profile(params, lam, radii, entry_fresnel=True, **model_options))
    rgb = weights @ spectral
    captured = np.array([float(np.interp(max_radius, _DENSE_RADII, e)) for e in energy])
    spectral_scale = reflectance / cumulative_energy(radii, spectral)[:, -1]
    rgb_scale = albedo / cumulative_energy(radii, rgb)[:, -1]

    inside = _DENSE_RADII <= 2 * max_radius
    gaussians = {c: fit_gaussians(_DENSE_RADII[inside], dense_rgb[i, inside], albedo[i]) for i, c in enumerate(CHANNELS)}
    burley = {c: fit_burley(_DENSE_RADII[inside], dense_rgb[i, inside], albedo[i]) for i, c in enumerate(CHANNELS)}
    resolved = model_with_options(model_options.get("model"), ior=model_options.get("ior"))
    ior = float(np.mean(np.asarray(resolved.ior)))
    median = [float(np.interp(0.5, np.maximum.accumulate(e), _DENSE_RADII)) for e in energy]
    medium = homogeneous_medium(albedo, np.array(median), ior)

    metadata = {
        "generator": f"skinfit {__version__}",
        "model": resolved.description,
        "ior": ior,
        "label": label,
        "parameters": {f: float(getattr(params, f)) for f in ("melanin", "melanin_blend", "haemoglobin")},
        "options": {k: (v if isinstance(v, (str, float, int)) else repr(v)) for k, v in model_options.items() if k != "model"},
        "units": {"wavelength": "nm", "radius": "mm", "profile": "mm^-2", "coefficients": "mm^-1", "variance": "mm^2"},
        "rgb": f"linear sRGB, illuminant {illuminant}, CIE 1931 2 degree observer (white = 1)",
        "radius_range_mm": [float(radii[0]), float(radii[-1])],
        "max_radius": f"every RGB channel has captured {energy_fraction:.4g} of its energy within {max_radius:.6g} mm",
        "normalisation": "each row scaled so that the trapezoid in ln r of 2 pi r^2 R over the table equals its "
                         "diffuse reflectance (specular excluded, entry Fresnel included)",
        "spectral_scale": spectral_scale.tolist(),
        "rgb_scale": rgb_scale.tolist(),
        "captured_within_max_radius": captured.tolist(),
    }
    return RendererProfiles(lam, radii, spectral * spectral_scale[:, None], rgb * rgb_scale[:, None], reflectance, albedo,
                            max_radius, captured, gaussians, burley, medium, metadata)


def _energy_measure(radii):
    """Weights of int 2 pi r f(r) dr on log-spaced radii (trapezoid in ln r)."""
    ln_r = np.log(radii)
    w = np.zeros_like(radii)
    d = np.diff(ln_r)
    w[:-1] += 0.5 * d
    w[1:] += 0.5 * d
    return 2 * np.pi * radii**2 * w


def gaussian_sum(radii_mm, variances_mm2, weights):
    """sum_k w_k exp(-r^2 / 2 v_k) / (2 pi v_k) in mm^-2."""
    r2 = np.asarray(radii_mm)[..., None] ** 2
    v = np.asarray(variances_mm2)
    return np.sum(np.asarray(weights) * np.exp(-r2 / (2 * v)) / (2 * np.pi * v), axis=-1)


def burley_profile(radii_mm, albedo, shape_mm):
    """A s (exp(-s r) + exp(-s r / 3)) / (8 pi r) with s = 1 / shape_mm, in mm^-2."""
    r = np.asarray(radii_mm)
    s = 1.0 / shape_mm
    return albedo * s * (np.exp(-s * r) + np.exp(-s * r / 3)) / (8 * np.pi * r)


def _errors(radii, target, fitted, fitted_cumulative, albedo) -> dict:
    """The fit's error as fractions of the channel's energy: the largest misplaced energy
    max_r |E_fit(r) - E(r)| (``energy_error``) and the L1 density error int 2 pi r |R - fit| dr."""
    return {
        "energy_error": float(np.max(np.abs(fitted_cumulative - cumulative_energy(radii, target))) / albedo),
        "density_l1_error": float(np.sum(_energy_measure(radii) * np.abs(target - fitted)) / albedo),
    }


def fit_gaussians(radii_mm, target, albedo, terms: int = GAUSSIAN_TERMS) -> dict:
    """Sum of ``terms`` Gaussians fitted to ``target`` (mm^-2) on log-spaced ``radii_mm``: weights
    non-negative and summing to ``albedo``, least squares on the cumulative energy E(r) (each
    Gaussian's is w (1 - exp(-r^2 / 2 v))). Start: non-negative least squares over 80 log-spaced
    variances, grouped into ``terms`` bands of equal weight; then all variances and weights."""
    energy = cumulative_energy(radii_mm, target)
    r2 = radii_mm[:, None] ** 2
    top = 4.0 * radii_mm[-1] ** 2

    def cumulative(v):
        return 1.0 - np.exp(-r2 / (2.0 * v))

    dictionary = np.geomspace(1e-10, top, 80)
    a = np.vstack([cumulative(dictionary) / albedo, 100.0 * np.ones((1, dictionary.size)) / albedo])
    w, _ = scipy.optimize.nnls(a, np.concatenate([energy / albedo, [100.0]]))
    share = np.cumsum(w) / w.sum()
    band = np.minimum((share * terms).astype(int), terms - 1)
    log_v = np.array([np.average(np.log(dictionary), weights=w * (band == k) + 1e-300) for k in range(terms)])
    start = np.concatenate([log_v, np.maximum([w[band == k].sum() for k in range(terms)], 1e-9)])

    def residual(x):
        v, weights = np.exp(x[:terms]), x[terms:]
        return np.concatenate([(cumulative(v) @ weights - energy) / albedo, [100.0 * (weights.sum() / albedo - 1.0)]])

    low = np.concatenate([np.full(terms, np.log(1e-12)), np.zeros(terms)])
    high = np.concatenate([np.full(terms, np.log(top)), np.full(terms, 2.0 * albedo)])
    x = scipy.optimize.least_squares(residual, np.clip(start, low, high), bounds=(low, high), method="trf",
                                     xtol=1e-12, ftol=1e-12, max_nfev=4000).x
    order = np.argsort(x[:terms])
    v, weights = np.exp(x[:terms][order]), x[terms:][order]
    weights = weights * albedo / weights.sum()  # exact energy: the constraint held to ~1e-4 only
    fitted = gaussian_sum(radii_mm, v, weights)
    return {"variances_mm2": v.tolist(), "weights": weights.tolist(),
            **_errors(radii_mm, target, fitted, cumulative(v) @ weights, albedo)}


def fit_burley(radii_mm, target, albedo) -> dict:
    """Christensen-Burley shape d = 1/s (mm) fitted to the cumulative energy of ``target`` with
    A = ``albedo`` (E(r) = A (1 - exp(-s r) / 4 - 3 exp(-s r / 3) / 4))."""
    energy = cumulative_energy(radii_mm, target)

    def cumulative(d):
        s = 1.0 / d
        return albedo * (1.0 - 0.25 * np.exp(-s * radii_mm) - 0.75 * np.exp(-s * radii_mm / 3.0))

    def cost(log_d):
        return float(np.sum((cumulative(np.exp(log_d)) - energy) ** 2))

    best = min(np.log(np.geomspace(1e-4, 100.0, 300)), key=cost)
    d = float(np.exp(scipy.optimize.minimize_scalar(cost, bracket=(best - 0.05, best, best + 0.05)).x))
    return {"albedo": float(albedo), "shape_mm": d,
            **_errors(radii_mm, target, burley_profile(radii_mm, albedo, d), cumulative(d), albedo)}


def _unit_medium_energy(reduced_albedo, ior, radius_mm):
    """Energy within ``radius_mm`` of the semi-infinite medium with sigma_t' = 1 mm^-1, entry Fresnel
    included (the DJ2005 multipole of a semi-infinite layer is its dipole: closed form)."""
    a = np.asarray(reduced_albedo, dtype=float)
    energy = dipole_energy(1.0 - a, a, ior, radius_mm)
    return (1.0 - float(normal_fresnel_reflectance(ior))) * np.asarray(energy)


def homogeneous_medium(albedo: np.ndarray, median_radius_mm: np.ndarray, ior: float = SKIN_IOR) -> dict:
    """Per channel, the semi-infinite medium with diffuse reflectance ``albedo`` and median energy
    radius ``median_radius_mm`` (both in this model): coefficients in mm^-1."""
    grid = np.concatenate([[0.0], 1.0 - np.geomspace(1e-9, 1.0, 4000)[::-1][:-1]])  # 0 .. 1 - 1e-9, dense near 1
    reflect = _unit_medium_energy(grid, ior, np.inf)
    order = np.argsort(reflect)
    if np.any(albedo >= reflect.max()) or np.any(albedo <= 0):
        raise SkinfitInputError("a channel albedo is outside what a homogeneous medium of this index can reflect")
    reduced = np.interp(albedo, reflect[order], grid[order])
    radii = np.geomspace(1e-6, 1e6, 20000)
    out = {"absorption_per_mm": [], "reduced_scattering_per_mm": [], "mean_free_path_mm": [], "reduced_albedo": [], "median_radius_mm": []}
    for a, r50 in zip(reduced, median_radius_mm):
        energy = _unit_medium_energy(a, ior, radii)
        unit_r50 = float(np.interp(0.5 * _unit_medium_energy(a, ior, np.inf), energy, radii))
        extinction = unit_r50 / r50  # profiles scale as sigma_t'^2 R(sigma_t' r)
        out["absorption_per_mm"].append(float((1 - a) * extinction))
        out["reduced_scattering_per_mm"].append(float(a * extinction))
        out["mean_free_path_mm"].append(float(1.0 / extinction))
        out["reduced_albedo"].append(float(a))
        out["median_radius_mm"].append(float(r50))
    return out


def pbrt_v4_material(result: RendererProfiles, name: str = "skin", scene_units_per_mm: float = 1e-3) -> str:
    """A pbrt-v4 ``subsurface`` material: sigma_a and sigma_s (g = 0, so sigma_s = sigma_s') per
    RGB channel. pbrt's coefficients are per scene unit: ``scale`` converts from mm^-1 (1000 for
    scenes in metres)."""
    m = result.medium
    fmt = lambda v: " ".join(f"{x:.6g}" for x in v)  # noqa: E731
    p = result.metadata["parameters"]
    return (
        f"# skinfit {__version__}: DJ2006 skin C_m {p['melanin']:g}, beta_m {p['melanin_blend']:g}, C_h {p['haemoglobin']:g}\n"
        f"# per-channel semi-infinite medium matching the linear-sRGB albedo ({fmt(result.rgb_albedo)}) and the median\n"
        f"# energy radius of each channel's profile; coefficients in mm^-1, scale = mm per scene unit\n"
        f'MakeNamedMaterial "{name}"\n'
        f'    "string type" "subsurface"\n'
        f'    "rgb sigma_a" [ {fmt(m["absorption_per_mm"])} ]\n'
        f'    "rgb sigma_s" [ {fmt(m["reduced_scattering_per_mm"])} ]\n'
        f'    "float g" 0\n'
        f'    "float eta" {float(result.metadata.get("ior", SKIN_IOR)):g}\n'
        f'    "float scale" {1.0 / scene_units_per_mm:g}\n'
    )


def blender_principled(result: RendererProfiles) -> dict:
    """Blender Principled BSDF inputs: base colour (linear), subsurface radius (mean free path per
    channel, mm) and the scale that turns mm into metres."""
    return {
        "Base Color": [*map(float, result.rgb_albedo), 1.0],
        "Subsurface Weight": 1.0,
        "Subsurface Radius": result.medium["mean_free_path_mm"],
        "Subsurface Scale": 0.001,
        "Subsurface IOR": float(result.metadata.get("ior", SKIN_IOR)),
        "subsurface_method": "RANDOM_WALK",
        "note": "Subsurface Radius in mm (mean free path 1/sigma_t' per channel); Subsurface Scale 0.001 for scenes in metres",
    }


RENDERER_FORMATS = ("table", "gaussians", "burley", "pbrt", "blender", "json")


def write_renderer(result: RendererProfiles, fmt: str, path: str | Path) -> Path:
    """Write one format: ``table`` (CSV of the energy-bounded spectral and RGB tables), ``gaussians``,
    ``burley``, ``blender`` or ``json`` (everything but the tables) as JSON, ``pbrt`` as a pbrt-v4
    snippet."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = result.metadata
    if fmt == "table":
        from .tables import ProfileTable, _write_csv

        _write_csv(ProfileTable(result.wavelengths_nm, result.radii_mm, result.spectral, result.rgb, result.reflectance, meta), path)
    elif fmt == "pbrt":
        path.write_text(pbrt_v4_material(result), encoding="utf-8")
    elif fmt in ("gaussians", "burley", "blender", "json"):
        content = {
            "gaussians": {"form": "R(r) = sum_k w_k exp(-r^2 / (2 v_k)) / (2 pi v_k) (d'Eon & Luebke 2007), r in mm, v in mm^2",
                          "channels": result.gaussians},
            "burley": {"form": "R(r) = A s (exp(-s r) + exp(-s r / 3)) / (8 pi r), s = 1 / shape_mm (Christensen & Burley 2015)",
                       "channels": result.burley},
            "blender": blender_principled(result),
        }
        if fmt == "json":
            content = {**content, "medium": result.medium, "rgb_albedo": result.rgb_albedo.tolist(), "max_radius_mm": result.max_radius_mm}
        else:
            content = content[fmt]
        path.write_text(json.dumps({"metadata": meta, **content}, indent=1), encoding="utf-8")
    else:
        raise SkinfitInputError(f"unknown renderer format {fmt!r}; use one of {', '.join(RENDERER_FORMATS)}")
    return path


def median_radius(params: SkinParams, wavelengths_nm=np.arange(400.0, 701.0, 10.0), illuminant: str = DEFAULT_ILLUMINANT,
                  **model_options) -> tuple[np.ndarray, np.ndarray]:
    """(rgb albedo (..., 3), median energy radius per RGB channel (..., 3) in mm) for parameters of
    any batch shape: the radius within which each channel has half its energy."""
    lam = np.asarray(wavelengths_nm, dtype=float)
    weights = linear_srgb_weights(lam, illuminant)
    albedo = np.asarray(diffuse_reflectance(params, lam, **model_options)) @ weights.T
    radii = np.geomspace(1e-5, 10.0, 400)  # medians of skin lie far inside 10 mm
    rgb = np.einsum("cw,...wr->...cr", weights, np.asarray(profile(params, lam, radii, entry_fresnel=True, **model_options)))
    energy = np.maximum.accumulate(cumulative_energy(radii, rgb), axis=-1) / albedo[..., None]
    flat = energy.reshape(-1, radii.size)
    median = np.array([np.interp(0.5, e, radii) for e in flat]).reshape(albedo.shape)
    return albedo, median


def renderer_textures(maps: dict, *, illuminant: str = DEFAULT_ILLUMINANT, grid: int = 24, ior: float | None = None,
                      model=None) -> dict:
    """Albedo and subsurface-radius textures from fitted maps (``melanin``, ``haemoglobin``,
    ``melanin_blend`` as (h, w) arrays, e.g. ``skinfit.fit_image(...).maps``).

    Returns float32 (h, w) channels ``albedo.R/G/B`` (linear sRGB, the shading removed) and
    ``mfp.R/G/B`` (the per-channel mean free path 1/sigma_t' of ``homogeneous_medium``, mm). The
    radius is interpolated (bilinear in log C_m, log C_h) from a ``grid`` x ``grid`` table over
    the maps' range; the albedo is exact per pixel.
    """
    from .image_fit import render_maps

    model = model_with_options(model, ior=ior)
    ior = float(np.mean(np.asarray(model.ior)))
    melanin, haemoglobin = (np.asarray(maps[k], dtype=float) for k in ("melanin", "haemoglobin"))
    blend = float(np.median(np.asarray(maps.get("melanin_blend", 0.7), dtype=float)))
    if melanin.shape != haemoglobin.shape or melanin.ndim != 2:
        raise SkinfitInputError("maps must hold (h, w) melanin and haemoglobin arrays")
    floor = 1e-4
    c_m, c_h = np.maximum(melanin, floor), np.maximum(haemoglobin, floor)
    axis_m = np.geomspace(c_m.min(), max(c_m.max(), c_m.min() * 1.001), grid)
    axis_h = np.geomspace(c_h.min(), max(c_h.max(), c_h.min() * 1.001), grid)
    mm, hh = np.meshgrid(axis_m, axis_h, indexing="ij")
    table_albedo, table_median = median_radius(SkinParams(mm, blend, hh), illuminant=illuminant, model=model)
    table_mfp = np.empty_like(table_median)
    for idx in np.ndindex(grid, grid):
        table_mfp[idx] = homogeneous_medium(table_albedo[idx], table_median[idx], ior)["mean_free_path_mm"]
    x = np.interp(np.log(c_m), np.log(axis_m), np.arange(grid))
    y = np.interp(np.log(c_h), np.log(axis_h), np.arange(grid))
    mfp = _bilinear(table_mfp, x, y)
    albedo = render_maps(melanin, haemoglobin, np.ones_like(melanin), melanin_blend=blend, illuminant=illuminant, model=model)
    channels = {}
    for i, c in enumerate("RGB"):
        channels[f"albedo.{c}"] = albedo[..., i].astype(np.float32)
        channels[f"mfp.{c}"] = mfp[..., i].astype(np.float32)
    return channels


def _bilinear(table, x, y):
    """table (g, g, k) sampled at fractional indices x, y (same shape) -> (..., k)."""
    g = table.shape[0]
    x0, y0 = np.clip(np.floor(x).astype(int), 0, g - 2), np.clip(np.floor(y).astype(int), 0, g - 2)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    return ((1 - fx) * (1 - fy) * table[x0, y0] + fx * (1 - fy) * table[x0 + 1, y0]
            + (1 - fx) * fy * table[x0, y0 + 1] + fx * fy * table[x0 + 1, y0 + 1])
