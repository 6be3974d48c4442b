"""The model's own two layers for renderers that nest media: epidermis slab over deep dermis.

One homogeneous medium per channel can be matched to a colour and one radius of the profile, never
to its shape (the renderers docs page: at 0.5 mm the rendered single medium holds 17 points more
of its energy than the model). A volumetric path tracer that nests media (Mitsuba 3) can carry the
model's stack instead, and its exact transport then is the reference that ``method="transport"``
(adding-doubling, Henyey-Greenstein g) agrees with:

- the **epidermis**: a slab of the model's thickness (mm) with the model's absorption sigma_a and
  scattering sigma_s = sigma_s' / (1 - g) (mm^-1);
- the **dermis** below it, semi-infinite in the model, a slab deep enough here (``depth_mm``,
  default 80 diffusion lengths of its least absorbing channel, at least 10 mm);
- both with the transport mode's Henyey-Greenstein g (0.8 unless the model's method says
  otherwise) and index n; the interface between them is index-matched (a ``null`` boundary), the
  surface a smooth dielectric of index n under air (index 1). The renderer adds that boundary's
  specular reflection F0 = ((n - 1) / (n + 1))^2, which the model's diffuse albedo excludes.
- the **oil** lobe (``params.oil`` > 0): a fraction ``oil`` of the surface is the model's rough
  dielectric (Beckmann, RMS slope 0.35, index 1.4) and the rest smooth (``blendbsdf``); the
  model adds its lobe to a smooth surface's diffuse light instead, so the export's specular
  reflection is the model's to first order only, and its diffuse light the same.

**Per wavelength** (``spectral=True``, Mitsuba's spectral variants) the coefficients are the
model's exactly. **Per RGB channel** no stack of coefficients is exact (the model mixes
wavelengths whose absorption differs a hundredfold), so each channel gets the log-mean of each
layer's sigma_a and sigma_s' over the wavelengths it sees (weights: its positive colour weight
times the model's reflectance) and then one factor on both layers' absorption, solved by
adding-doubling so that the stack's diffuse reflectance is the channel's linear-sRGB albedo of
the model's transport reflectance. The profile is then that stack's, which the renders check
against skinfit's Monte Carlo of the same stack (``benchmarks/renderers.py``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.optimize

from .._validate import SkinfitInputError
from .._version import __version__
from ..colorimetry import DEFAULT_ILLUMINANT, linear_srgb_weights
from ..model import (
    SKIN_ANISOTROPY,
    SURFACE_IOR,
    SURFACE_ROUGHNESS,
    Layer,
    SkinParams,
    diffuse_reflectance,
    model_with_options,
    monte_carlo_reflectance,
    normal_fresnel_reflectance,
    stack_reflectance_transport,
)

#: Streams of the adding-doubling that matches an RGB channel's stack to its albedo.
LAYERED_STREAMS = 32
#: Wavelengths of a layered export unless given, nm: what Mitsuba's spectral variants sample.
LAYERED_WAVELENGTHS_NM = np.arange(360.0, 831.0, 10.0)


@dataclasses.dataclass(frozen=True)
class LayeredMedium:
    """Epidermis over dermis, per RGB channel or per wavelength (module docstring).

    Attributes:
        channels: (k,) the channels' names (``"R", "G", "B"``) or wavelengths in nm as strings.
        wavelengths_nm: (k,) the wavelengths (spectral) or None (RGB).
        epidermis_absorption_per_mm, epidermis_scattering_per_mm: (k,) sigma_a and sigma_s (not
            reduced) of the epidermis, mm^-1.
        dermis_absorption_per_mm, dermis_scattering_per_mm: (k,) the same for the dermis.
        epidermis_thickness_mm: the epidermis slab's thickness, mm.
        anisotropy: Henyey-Greenstein g of both layers.
        ior: index of both layers and of the smooth surface (air above).
        oil: the share of the surface that is the rough oil lobe (0: smooth).
        albedo: (k,) the model's transport diffuse reflectance per channel (linear sRGB) or
            wavelength: what the stack renders (specular excluded, entry Fresnel included).
        absorption_factor: (k,) the factor on both layers' absorption that matched each RGB
            channel's stack to its albedo (ones for spectral).
        metadata: parameters, model, conventions.
    """

    channels: tuple[str, ...]
    wavelengths_nm: np.ndarray | None
    epidermis_absorption_per_mm: np.ndarray
    epidermis_scattering_per_mm: np.ndarray
    dermis_absorption_per_mm: np.ndarray
    dermis_scattering_per_mm: np.ndarray
    epidermis_thickness_mm: float
    anisotropy: float
    ior: float
    oil: float
    albedo: np.ndarray
    absorption_factor: np.ndarray
    metadata: dict

    @property
    def specular(self) -> float:
        """Normal-incidence reflectance F0 of the smooth surface, which the renderer adds."""
        return float(normal_fresnel_reflectance(self.ior))

    def layers(self, channel: int) -> tuple[Layer, Layer]:
        """The stack of one channel as ``skinfit.model.Layer`` s (for Monte Carlo and adding-doubling)."""
        reduced = lambda s: float(s[channel]) * (1.0 - self.anisotropy)  # noqa: E731
        epidermis = Layer(float(self.epidermis_absorption_per_mm[channel]), reduced(self.epidermis_scattering_per_mm),
                          self.epidermis_thickness_mm, self.ior, self.anisotropy)
        dermis = Layer(float(self.dermis_absorption_per_mm[channel]), reduced(self.dermis_scattering_per_mm),
                       float("inf"), self.ior, self.anisotropy)
        return epidermis, dermis

    def diffusion_length_mm(self) -> float:
        """The longest diffusion length 1 / sqrt(3 sigma_a (sigma_a + sigma_s')) of the dermis over
        the channels, mm: how deep and wide light spreads."""
        a = self.dermis_absorption_per_mm
        reduced = self.dermis_scattering_per_mm * (1.0 - self.anisotropy)
        return float(np.max(1.0 / np.sqrt(3.0 * np.maximum(a, 1e-9) * (a + reduced))))

    def monte_carlo_energy_within(self, radii_mm, *, photons: int = 400_000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(energy (len(radii), k), standard error): skinfit's Monte Carlo of each channel's stack,
        the diffuse reflectance within each radius of a normally incident narrow beam."""
        results = [monte_carlo_reflectance(self.layers(c), photons=photons, seed=seed + c, radii_mm=radii_mm)
                   for c in range(len(self.channels))]
        return (np.stack([r.reflectance_within for r in results], axis=-1),
                np.stack([r.reflectance_within_error for r in results], axis=-1))

    def describe(self) -> dict:
        """The assumptions of the export, stated in every file written from it."""
        per = "wavelength (nm)" if self.wavelengths_nm is not None else "linear-sRGB channel"
        return {
            "geometry": f"epidermis slab {self.epidermis_thickness_mm:g} mm thick over a dermis deep enough to be semi-infinite",
            "coefficients": f"per {per}: sigma_a and sigma_s (not reduced) in mm^-1 of each layer"
                            + ("" if self.wavelengths_nm is not None else
                               "; each channel's log-mean coefficients with one absorption factor matched by adding-doubling"),
            "phase_function": f"Henyey-Greenstein g {self.anisotropy:g} in both layers",
            "boundaries": f"smooth dielectric surface, index {self.ior:g} inside, 1 (air) outside; the layers index-matched (null interface)",
            "surface_lobe": "none (oil 0)" if self.oil == 0 else
                            f"a share {self.oil:g} of the surface is a rough dielectric (Beckmann, RMS slope {SURFACE_ROUGHNESS:g}, "
                            f"index {SURFACE_IOR:g}): the model's oil lobe to first order",
            "albedo": "the model's transport diffuse reflectance (normal incidence, specular excluded, entry Fresnel included); "
                      f"the renderer adds the surface's specular F0 = {self.specular:.4f}",
            "units": "coefficients in mm^-1, lengths in mm (a scene in metres: mm_per_scene_unit 1000)",
        }


def _transport_anisotropy(model) -> float:
    g = getattr(model.method, "anisotropy", None)
    return float(SKIN_ANISOTROPY if g is None else g)


def _stack_albedo(absorption, scattering, thickness, g, ior, factor) -> float:
    """Adding-doubling diffuse reflectance of epidermis over semi-infinite dermis, absorption times ``factor``."""
    return float(stack_reflectance_transport(np.asarray(absorption) * factor, np.asarray(scattering) * (1.0 - g),
                                             np.array([thickness, 1.0]), np.array([g, g]), ior=ior, ior_above=1.0,
                                             semi_infinite=True, streams=LAYERED_STREAMS))


def _matched_factor(absorption, scattering, thickness, g, ior, target) -> float:
    """The factor on both layers' absorption whose stack reflects ``target`` (bracketed in log over
    1/20-20: the matched factors of skin lie within 0.7-1.3; the adding-doubling's fixed doublings lose
    accuracy beyond optical depths of a few hundred)."""
    low, high = np.log(1 / 20), np.log(20.0)
    residual = lambda log_k: _stack_albedo(absorption, scattering, thickness, g, ior, np.exp(log_k)) - target  # noqa: E731
    at_low, at_high = residual(low), residual(high)
    if at_low <= 0:
        return float(np.exp(low))
    if at_high >= 0:
        return float(np.exp(high))
    return float(np.exp(scipy.optimize.brentq(residual, low, high, xtol=1e-10, rtol=1e-12)))


def layered_medium(params: SkinParams, wavelengths_nm=None, *, spectral: bool = False, illuminant: str = DEFAULT_ILLUMINANT,
                   model=None, label: str = "") -> LayeredMedium:
    """The model's two layers for one (scalar) parameter set, per RGB channel or (``spectral``) per
    wavelength (module docstring). ``wavelengths_nm``: default 360-830 nm every 10 nm."""
    if params.shape != ():
        raise SkinfitInputError("layered_medium takes one parameter set (scalar SkinParams fields)")
    lam = LAYERED_WAVELENGTHS_NM if wavelengths_nm is None else np.asarray(wavelengths_nm, dtype=float)
    if lam.ndim != 1 or lam.size < 2 or np.any(np.diff(lam) <= 0):
        raise SkinfitInputError("wavelengths_nm must be increasing, at least two of them")
    model = model_with_options(model)
    g, ior = _transport_anisotropy(model), float(np.mean(np.asarray(model.ior)))
    epidermis, dermis = model.layers(params, lam)
    thickness = float(np.asarray(epidermis.thickness).reshape(-1)[0])
    absorption = np.stack([np.broadcast_to(np.asarray(layer.absorption, dtype=float), lam.shape) for layer in (epidermis, dermis)])
    scattering = np.stack([np.broadcast_to(np.asarray(layer.reduced_scattering, dtype=float), lam.shape)
                           for layer in (epidermis, dermis)]) / (1.0 - g)
    reflectance = np.asarray(diffuse_reflectance(params, lam, model=model, method="transport", anisotropy=g), dtype=float)
    metadata = {
        "generator": f"skinfit {__version__}",
        "model": model.description,
        "label": label,
        "parameters": {f: float(getattr(params, f)) for f in ("melanin", "melanin_blend", "haemoglobin", "oil")},
    }
    if spectral:
        return LayeredMedium(tuple(f"{w:g}" for w in lam), lam, absorption[0], scattering[0], absorption[1], scattering[1],
                             thickness, g, ior, float(params.oil), reflectance, np.ones(lam.size),
                             {**metadata, "albedo": "per wavelength"})
    weights = linear_srgb_weights(lam, illuminant)
    albedo = weights @ reflectance
    seen = np.maximum(weights, 0.0) * reflectance
    seen = seen / seen.sum(axis=1, keepdims=True)
    log_mean = lambda values: np.exp(seen @ np.log(np.maximum(values, 1e-12)).T).T  # noqa: E731 - (2, 3)
    absorption_rgb, scattering_rgb = log_mean(absorption), log_mean(scattering)
    factors = np.array([_matched_factor(absorption_rgb[:, c], scattering_rgb[:, c], thickness, g, ior, albedo[c]) for c in range(3)])
    absorption_rgb = absorption_rgb * factors
    return LayeredMedium(("R", "G", "B"), None, absorption_rgb[0], scattering_rgb[0], absorption_rgb[1], scattering_rgb[1],
                         thickness, g, ior, float(params.oil), albedo, factors,
                         {**metadata, "albedo": f"linear sRGB, illuminant {illuminant}, CIE 1931 2 degree observer (white = 1)"})
