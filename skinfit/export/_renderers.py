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
- **Medium** (pbrt-v4, Mitsuba 3, Blender): per RGB channel (and per wavelength for spectral
  renderers), the semi-infinite homogeneous medium behind a smooth dielectric boundary whose
  *exact* transport has the channel's diffuse reflectance R_d and the median energy radius of
  its profile (``skinfit.export``: adding-doubling for the colour, Monte Carlo for the
  scale), under stated ``RendererConventions`` (index, phase function g, units). A medium matched
  through diffusion theory instead renders too dark in a path tracer (down to 0.71 of the albedo
  in the renders of the renderers docs page). Blender's
  Principled BSDF inverts a base colour itself, with a drift measured per Blender version
  (``blender_principled``), which the export compensates.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.resources
import json
from pathlib import Path

import numpy as np
import scipy.interpolate
import scipy.optimize

from .._caching import eager_cache
from .._validate import SkinfitInputError
from .._version import __version__
from ..colorimetry import DEFAULT_ILLUMINANT, linear_srgb_weights, render_maps
from ..model import Layer, SkinParams, diffuse_reflectance, model_with_options, monte_carlo_reflectance, profile
from ._media import (
    DEFAULT_CONVENTIONS,
    RendererConventions,
    RendererMedium,
    medium_table,
    transport_medium,
)
from ._mitsuba import (
    mitsuba_heterogeneous_xml,
    mitsuba_material,
    mitsuba_medium,
    mitsuba_spectral_medium,
    mitsuba_xml,
    write_mitsuba_volume,
)
from ._profile_tables import ProfileTable, write_csv

ENERGY_FRACTION = 0.997
#: Radii (mm) and Monte Carlo photons per channel of the single medium's profile check, stated in every single-medium export.
PROFILE_CHECK_RADII_MM = (0.1, 0.5, 1.0, 2.0)
PROFILE_CHECK_PHOTONS = 20_000
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
        medium: the per-channel ``RendererMedium`` (exact transport under ``conventions``).
        spectral_medium: the same per wavelength.
        median_radius_mm: (n_wavelengths,) the median energy radius of each wavelength's profile.
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
    medium: RendererMedium
    spectral_medium: RendererMedium
    median_radius_mm: np.ndarray
    metadata: dict

    @functools.cached_property
    def single_medium_profile(self) -> dict:
        """How far the single homogeneous medium's profile is from the model's: the fraction of each
        RGB channel's diffuse energy within ``PROFILE_CHECK_RADII_MM``, from the model's profile and
        from skinfit's Monte Carlo of the exported medium (exact transport, ``PROFILE_CHECK_PHOTONS``
        photons per channel, standard error about 0.3 points), and the largest difference in points."""
        radii = np.asarray(PROFILE_CHECK_RADII_MM)
        within = np.stack([np.interp(np.log(radii), np.log(self.radii_mm), e) for e in cumulative_energy(self.radii_mm, self.rgb)])
        model = within / self.rgb_albedo[:, None]
        medium, conventions = self.medium, self.medium.conventions
        single = []
        for c in range(3):
            sigma_t, albedo = float(medium.extinction_per_mm[c]), float(medium.single_scattering_albedo[c])
            layer = Layer(sigma_t * (1 - albedo), sigma_t * albedo * (1 - conventions.anisotropy), float("inf"), conventions.ior,
                          conventions.anisotropy)
            run = monte_carlo_reflectance((layer,), photons=PROFILE_CHECK_PHOTONS, seed=c, radii_mm=radii)
            single.append(np.asarray(run.reflectance_within) / float(run.reflectance))
        single = np.array(single)
        return {"radii_mm": radii.tolist(), "model": model.round(4).tolist(), "single_medium": single.round(4).tolist(),
                "largest_difference_points": float(np.max(np.abs(100 * (single - model)))), "photons": PROFILE_CHECK_PHOTONS}

    def profile_note(self) -> str:
        """One line for the exports: what the single medium's profile misses (``single_medium_profile``)."""
        check = self.single_medium_profile
        cells = lambda rows: " / ".join(",".join(f"{v:.2f}" for v in row) for row in np.array(rows).T)  # noqa: E731
        return (f"profile: a homogeneous medium has the model's albedo and median radius, not its profile's shape; energy within "
                f"{'/'.join(f'{r:g}' for r in check['radii_mm'])} mm (R,G,B): model {cells(check['model'])}, this medium "
                f"{cells(check['single_medium'])} (skinfit Monte Carlo, {check['photons']} photons per channel), up to "
                f"{check['largest_difference_points']:.0f} points apart; the model's own layers: --format mitsuba-layered")


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
    conventions: RendererConventions = DEFAULT_CONVENTIONS,
    **model_options,
) -> RendererProfiles:
    """Energy-bounded spectral and RGB tables, sum-of-Gaussians and Burley fits and the
    per-channel and per-wavelength media (under the renderer ``conventions``) of one (scalar)
    parameter set; ``model_options`` as in ``diffuse_reflectance``."""
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
    reach = _radii_holding(energy_fraction, energy)
    max_radius = float(reach.max())

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
    median = _radii_holding(0.5, energy)
    medium = transport_medium(albedo, median, conventions)
    spectral_energy = cumulative_energy(_DENSE_RADII, dense) / reflectance[:, None]
    spectral_median = _radii_holding(0.5, spectral_energy)
    spectral_medium = transport_medium(reflectance, spectral_median, conventions)

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
        "renderer_conventions": conventions.describe(),
    }
    return RendererProfiles(lam, radii, spectral * spectral_scale[:, None], rgb * rgb_scale[:, None], reflectance, albedo,
                            max_radius, captured, gaussians, burley, medium, spectral_medium, spectral_median, metadata)


def _radii_holding(fraction: float, energy: np.ndarray) -> np.ndarray:
    """Per row of ``energy`` (cumulative energy fractions on ``_DENSE_RADII``), the radius within
    which it holds ``fraction`` (monotone envelope: far tails of linear-sRGB rows can dip)."""
    return np.array([float(np.interp(fraction, np.maximum.accumulate(e), _DENSE_RADII)) for e in energy])


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


def _header(result: RendererProfiles, comment: str = "# ") -> str:
    """The provenance and conventions every medium export states."""
    p = result.metadata["parameters"]
    medium = result.medium
    rgb = " ".join(f"{x:.6g}" for x in result.rgb_albedo)
    lines = [
        f"skinfit {__version__}, model {result.metadata['model']}: C_m {p['melanin']:g}, beta_m {p['melanin_blend']:g}, C_h {p['haemoglobin']:g}",
        f"per-channel semi-infinite homogeneous medium whose exact transport gives the linear-sRGB diffuse albedo ({rgb})",
        "and each channel's median energy radius (" + " ".join(f"{x:.4g}" for x in medium.median_radius_mm) + " mm)",
        *(f"{k}: {v}" for k, v in medium.conventions.describe().items()),
        result.profile_note(),
    ]
    return "".join(f"{comment}{line}\n" for line in lines)


def pbrt_v4_material(result: RendererProfiles, name: str = "skin", mm_per_scene_unit: float = 1000.0) -> str:
    """A pbrt-v4 ``subsurface`` material: sigma_a and sigma_s (of the phase function with the
    conventions' g) per RGB channel in mm^-1, ``scale`` = mm per scene unit (1000: a scene in
    metres), ``eta`` the conventions' index. pbrt-v4 renders it with its photon-beam-diffusion
    BSSRDF, which approximates the exact transport the medium was matched with."""
    m = result.medium
    fmt = lambda v: " ".join(f"{x:.6g}" for x in v)  # noqa: E731
    return (
        _header(result)
        + f'MakeNamedMaterial "{name}"\n'
        f'    "string type" "subsurface"\n'
        f'    "rgb sigma_a" [ {fmt(m.absorption_per_mm)} ]\n'
        f'    "rgb sigma_s" [ {fmt(m.scattering_per_mm)} ]\n'
        f'    "float g" {m.conventions.anisotropy:g}\n'
        f'    "float eta" {m.conventions.ior:g}\n'
        f'    "float scale" {mm_per_scene_unit:g}\n'
    )


def mitsuba_export(result: RendererProfiles, *, spectral: bool = False, mm_per_scene_unit: float = 1.0) -> str:
    """A Mitsuba 3 XML fragment: the dielectric boundary and the homogeneous interior medium, per
    RGB channel or (``spectral``) per wavelength of ``result`` (``skinfit.export``)."""
    m = result.medium
    if spectral:
        medium = mitsuba_spectral_medium(result.wavelengths_nm, result.spectral_medium, mm_per_scene_unit=mm_per_scene_unit)
    else:
        medium = mitsuba_medium(m, mm_per_scene_unit=mm_per_scene_unit)
    use = ('use: <shape type="..."> <ref id="skin_boundary"/> <ref name="interior" id="skin"/> </shape> '
           f"with the volpathmis integrator (spectral MIS: the channels' sigma_t differ); coefficients per scene unit ({mm_per_scene_unit:g} mm)")
    return mitsuba_xml(mitsuba_material(medium, m.conventions.ior), comment=_header(result, comment="") + use)


#: Blender Cycles subsurface methods with a measured drift (``spectra/blender_cycles_<method>.json``).
BLENDER_METHODS = ("RANDOM_WALK", "RANDOM_WALK_SKIN")


@eager_cache()
def blender_drift(method: str = "RANDOM_WALK") -> dict:
    """The measured Cycles curve of ``method``: rendered diffuse albedo against base colour, with
    the Blender version and scene it was measured in (``benchmarks/measure_blender_drift.py``)."""
    if method not in BLENDER_METHODS:
        raise SkinfitInputError(f"no measured Blender drift for {method!r}; use one of {', '.join(BLENDER_METHODS)}")
    text = importlib.resources.files("skinfit.spectra").joinpath(f"blender_cycles_{method.lower()}.json").read_text(encoding="utf-8")
    return json.loads(text)


def blender_base_colour(albedo, method: str = "RANDOM_WALK") -> np.ndarray:
    """The Principled BSDF base colour that Cycles (the measured version) renders as ``albedo``
    (diffuse, specular excluded): the measured curve inverted, monotone in log-log."""
    drift = blender_drift(method)
    base, rendered = np.log(drift["base_colour"]), np.log(drift["rendered_albedo"])
    a = np.asarray(albedo, dtype=float)
    if np.any(~np.isfinite(a)) or np.any(a < np.exp(rendered[0])) or np.any(a > np.exp(rendered[-1])):
        raise SkinfitInputError(f"albedo outside the measured Blender range {np.exp(rendered[0]):.3g} to {np.exp(rendered[-1]):.3g}")
    return np.exp(scipy.interpolate.PchipInterpolator(rendered, base)(np.log(a)))


def blender_radius(median_radius_mm, base_colour, method: str = "RANDOM_WALK") -> np.ndarray:
    """The Subsurface Radius (mm) with which Cycles renders base colour ``base_colour`` with the
    median energy radius ``median_radius_mm``: the radius over the measured k(base colour), the
    median Cycles renders per unit of radius (``benchmarks/measure_blender_drift.py``)."""
    radial = blender_drift(method)["radial"]
    k = scipy.interpolate.PchipInterpolator(np.log(radial["base_colour"]), np.log(radial["median_over_radius"]), extrapolate=True)
    return np.asarray(median_radius_mm, dtype=float) / np.exp(k(np.log(np.asarray(base_colour, dtype=float))))


def blender_principled(result: RendererProfiles, method: str = "RANDOM_WALK") -> dict:
    """Blender Principled BSDF inputs: the base colour that the measured Cycles version renders as
    the model's albedo, the Subsurface Radius with which it renders each channel's median energy
    radius (mm), and the scale that turns mm into metres. Cycles treats a radius below 1e-4
    scene units (0.1 mm here) as a diffuse surface; the exported radii of skin lie above it."""
    drift = blender_drift(method)
    base = blender_base_colour(result.rgb_albedo, method)
    return {
        "Base Color": [*map(float, base), 1.0],
        "Subsurface Weight": 1.0,
        "Subsurface Radius": blender_radius(result.medium.median_radius_mm, base, method).tolist(),
        "Subsurface Scale": 0.001,
        "Subsurface IOR": result.medium.conventions.ior,
        "IOR": result.medium.conventions.ior,
        "Subsurface Anisotropy": result.medium.conventions.anisotropy,
        "Roughness": 0.0,
        "subsurface_method": method,
        "target_albedo": result.rgb_albedo.tolist(),
        "target_median_radius_mm": result.medium.median_radius_mm.tolist(),
        "note": (f"base colour and radius compensated for Blender {drift['blender']} Cycles {method} as measured in {drift['scene']}; "
                 "Subsurface Radius in mm (Cycles renders a median energy radius of k(base colour) x radius), "
                 "Subsurface Scale 0.001 for scenes in metres"),
        "profile": result.profile_note().replace("--format mitsuba-layered", "skinfit profiles --format mitsuba-layered (Mitsuba 3)"),
    }


RENDERER_FORMATS = ("table", "gaussians", "burley", "pbrt", "mitsuba", "mitsuba-spectral", "blender", "json")


def write_renderer(result: RendererProfiles, fmt: str, path: str | Path) -> Path:
    """Write one format: ``table`` (CSV of the energy-bounded spectral and RGB tables), ``gaussians``,
    ``burley``, ``blender`` or ``json`` (everything but the tables) as JSON, ``pbrt`` as a pbrt-v4
    snippet, ``mitsuba`` / ``mitsuba-spectral`` as a Mitsuba 3 XML fragment."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = result.metadata
    if fmt == "table":
        write_csv(ProfileTable(result.wavelengths_nm, result.radii_mm, result.spectral, result.rgb, result.reflectance, meta), path)
    elif fmt == "pbrt":
        path.write_text(pbrt_v4_material(result), encoding="utf-8")
    elif fmt in ("mitsuba", "mitsuba-spectral"):
        path.write_text(mitsuba_export(result, spectral=fmt == "mitsuba-spectral"), encoding="utf-8")
    elif fmt in ("gaussians", "burley", "blender", "json"):
        content = {
            "gaussians": {"form": "R(r) = sum_k w_k exp(-r^2 / (2 v_k)) / (2 pi v_k) (d'Eon & Luebke 2007), r in mm, v in mm^2",
                          "channels": result.gaussians},
            "burley": {"form": "R(r) = A s (exp(-s r) + exp(-s r / 3)) / (8 pi r), s = 1 / shape_mm (Christensen & Burley 2015)",
                       "channels": result.burley},
            "blender": blender_principled(result),
        }
        if fmt == "json":
            content = {**content, "medium": result.medium.to_dict(), "spectral_medium": result.spectral_medium.to_dict(),
                       "wavelengths_nm": result.wavelengths_nm.tolist(), "rgb_albedo": result.rgb_albedo.tolist(),
                       "max_radius_mm": result.max_radius_mm}
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
                      model=None, conventions: RendererConventions = DEFAULT_CONVENTIONS,
                      blender_method: str = "RANDOM_WALK") -> dict:
    """Per-texel media from fitted maps (``melanin``, ``haemoglobin``, ``melanin_blend`` as (h, w)
    arrays, e.g. ``skinfit.fit_image(...).maps``).

    Returns float32 (h, w) channels, each per RGB channel ``.R/.G/.B``: ``albedo`` (the model's
    linear-sRGB diffuse albedo, the shading removed), ``sigma_t`` and ``ss_albedo`` (the exact
    transport medium of ``renderer_media`` under ``conventions``: extinction in mm^-1 and
    single-scattering albedo, what Mitsuba's heterogeneous medium takes), ``mfp`` (its mean free
    path 1/sigma_t, mm), ``base_colour`` and ``blender_radius`` (the Principled BSDF base colour and
    Subsurface Radius in mm with which the measured Blender Cycles renders that albedo and median
    radius, ``blender_principled``). The albedo is exact per pixel; the median energy radius is
    interpolated (bilinear in log C_m, log C_h, of its log) from a ``grid`` x ``grid`` table over
    the maps' range. Albedos beyond what the medium or Blender's measured curve reach (maps
    zeroed outside skin) are clipped into their range.
    """

    model = model_with_options(model, ior=ior)
    melanin, haemoglobin = (np.asarray(maps[k], dtype=float) for k in ("melanin", "haemoglobin"))
    blend = float(np.median(np.asarray(maps.get("melanin_blend", 0.7), dtype=float)))
    if melanin.shape != haemoglobin.shape or melanin.ndim != 2:
        raise SkinfitInputError("maps must hold (h, w) melanin and haemoglobin arrays")
    floor = 1e-4
    c_m, c_h = np.maximum(melanin, floor), np.maximum(haemoglobin, floor)
    axis_m = np.geomspace(c_m.min(), max(c_m.max(), c_m.min() * 1.001), grid)
    axis_h = np.geomspace(c_h.min(), max(c_h.max(), c_h.min() * 1.001), grid)
    mm, hh = np.meshgrid(axis_m, axis_h, indexing="ij")
    _, table_median = median_radius(SkinParams(mm, blend, hh), illuminant=illuminant, model=model)
    x = np.interp(np.log(c_m), np.log(axis_m), np.arange(grid))
    y = np.interp(np.log(c_h), np.log(axis_h), np.arange(grid))
    median = np.exp(_bilinear(np.log(table_median), x, y))
    albedo = render_maps(melanin, haemoglobin, np.ones_like(melanin), melanin_blend=blend, illuminant=illuminant, model=model)
    table = medium_table(conventions)
    low, high = table.reflectance_range
    medium = transport_medium(np.clip(albedo, low, high), median, conventions)
    drift = blender_drift(blender_method)
    base = blender_base_colour(np.clip(albedo, drift["rendered_albedo"][0], drift["rendered_albedo"][-1]), blender_method)
    layers = {"albedo": albedo, "sigma_t": medium.extinction_per_mm, "ss_albedo": medium.single_scattering_albedo,
              "mfp": medium.mean_free_path_mm, "base_colour": base, "blender_radius": blender_radius(median, base, blender_method)}
    return {f"{name}.{c}": values[..., i].astype(np.float32) for name, values in layers.items() for i, c in enumerate("RGB")}


def write_mitsuba_textures(textures: dict, folder, *, conventions: RendererConventions = DEFAULT_CONVENTIONS,
                           mm_per_scene_unit: float = 1.0) -> Path:
    """Write the media of ``renderer_textures`` for Mitsuba 3: ``sigma_t.vol`` (extinction over
    its peak), ``albedo.vol`` (single-scattering albedo), one texel per map pixel and one layer
    deep, and ``skin_medium.xml`` (the heterogeneous medium with its boundary). Row 0 of the maps
    is y = 0 of the grids' unit cube. Returns the XML's path."""
    folder = Path(folder)
    stack = lambda name: np.stack([textures[f"{name}.{c}"] for c in "RGB"], axis=-1)  # noqa: E731
    sigma_t = stack("sigma_t").astype(float) * mm_per_scene_unit
    peak = float(sigma_t.max())
    write_mitsuba_volume(folder / "sigma_t.vol", sigma_t / peak)
    write_mitsuba_volume(folder / "albedo.vol", stack("ss_albedo"))
    comment = "\n".join([f"skinfit {__version__}: per-texel media of fitted maps, matched with exact transport",
                          *(f"{k}: {v}" for k, v in conventions.describe().items()),
                          f"coefficients per scene unit ({mm_per_scene_unit:g} mm); the grids span their unit cube: add a to_world "
                          "to each volume to lay them over the skin (z: depth)"])
    xml = mitsuba_heterogeneous_xml("sigma_t.vol", "albedo.vol", peak, ior=conventions.ior, anisotropy=conventions.anisotropy, comment=comment)
    path = folder / "skin_medium.xml"
    path.write_text(xml, encoding="utf-8")
    return path


def _bilinear(table, x, y):
    """table (gx, gy, k) sampled at fractional indices x, y (same shape) -> (..., k)."""
    x0, y0 = np.clip(np.floor(x).astype(int), 0, table.shape[0] - 2), np.clip(np.floor(y).astype(int), 0, table.shape[1] - 2)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    return ((1 - fx) * (1 - fy) * table[x0, y0] + fx * (1 - fy) * table[x0 + 1, y0]
            + (1 - fx) * fy * table[x0, y0 + 1] + fx * fy * table[x0 + 1, y0 + 1])
