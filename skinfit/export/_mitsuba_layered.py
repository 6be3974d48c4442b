"""Mitsuba 3 exports of the two-layer stack (``LayeredMedium``), and the renders that check them.

Mitsuba tracks the medium a path is in through the shapes it crosses: a shape's ``interior`` is
the medium behind its normal, its ``exterior`` the medium in front. The stack is three flat
shapes, normals up:

- the **surface**: a smooth ``dielectric`` (index n inside, 1 outside; with oil a ``blendbsdf``
  with the rough lobe), interior the epidermis, exterior air (no medium);
- the **interface** at the epidermis' depth: a ``null`` BSDF (index-matched), interior the dermis,
  exterior the epidermis;
- the **floor** of the dermis, ``depth_mm`` down: black (the dermis is semi-infinite in the
  model; 80 of its diffusion lengths down, the light that reaches it is negligible).

On a mesh the same holds: the mesh with the surface BSDF and the epidermis inside, and a copy
offset inwards by the epidermis' thickness with the ``null`` BSDF, the dermis inside and the
epidermis outside (``mitsuba_layered_xml`` says so in the file). Coefficients are per scene unit
(``mm_per_scene_unit``). The checks use the reference scene of ``skinfit.export._mitsuba``
(``volpathmis``, a uniform white environment, an orthographic camera at normal incidence, the
surface's specular F0 subtracted) and need ``mitsuba``.
"""

from __future__ import annotations

from xml.sax.saxutils import quoteattr

import numpy as np

from .._validate import SkinfitInputError
from ..model import SURFACE_IOR, SURFACE_ROUGHNESS
from ._layered import LayeredMedium
from ._mitsuba import (
    _mitsuba,
    _phase,
    _phase_xml,
    _slab_scene,
    _xml_value,
    render_spectral_bands,
    rgb_film,
    screened_scene,
    spectral_film,
    spectrum_value,
)

#: Path depth from which the checks' renders play Russian roulette. With g 0.8 a red path that
#: leaves the skin 5 mm from where it entered has scattered some 1,500 times; Mitsuba's roulette
#: keeps a path with probability at most 0.95 per bounce, so from depth 200 (the single medium's
#: setting, g 0) such paths all but vanish, an estimate unbiased in law and 8 % low in practice
#: (light preset, red: 0.547 against adding-doubling's 0.594 at 4,096 samples; from depth 1,000
#: 0.593, from 5,000 0.595; measured 2026-12-07).
RR_DEPTH = 5000

#: The stack's media and shapes, as named in the dictionaries and the XML.
EPIDERMIS, DERMIS = "epidermis", "dermis"


def _value(layered: LayeredMedium, values) -> dict:
    values = np.asarray(values, dtype=float)
    if layered.wavelengths_nm is not None:
        return spectrum_value(layered.wavelengths_nm, values)
    return {"type": "rgb", "value": [float(v) for v in values]}


def _medium(layered: LayeredMedium, absorption, scattering, mm_per_scene_unit: float) -> dict:
    """A ``homogeneous`` medium; RGB inputs are bounded to [0, 1] in Mitsuba, so sigma_t goes as
    its channels over their largest times ``scale`` (spectral: scale 1)."""
    sigma_t = (np.asarray(absorption) + np.asarray(scattering)) * mm_per_scene_unit
    albedo = np.asarray(scattering) / (np.asarray(absorption) + np.asarray(scattering))
    peak = float(sigma_t.max()) if layered.wavelengths_nm is None else 1.0
    return {"type": "homogeneous", "albedo": _value(layered, albedo), "sigma_t": _value(layered, sigma_t / peak),
            "scale": peak, "phase": _phase(layered.anisotropy)}


def mitsuba_layered_media(layered: LayeredMedium, *, mm_per_scene_unit: float = 1.0) -> dict:
    """``{"epidermis": medium, "dermis": medium}``: ``homogeneous`` media for ``mitsuba.load_dict``
    (RGB or spectral values as ``layered`` holds them)."""
    return {EPIDERMIS: _medium(layered, layered.epidermis_absorption_per_mm, layered.epidermis_scattering_per_mm, mm_per_scene_unit),
            DERMIS: _medium(layered, layered.dermis_absorption_per_mm, layered.dermis_scattering_per_mm, mm_per_scene_unit)}


def mitsuba_layered_surface(layered: LayeredMedium) -> dict:
    """The surface's BSDF: a smooth dielectric, with oil a blend with the rough oil lobe."""
    smooth = {"type": "dielectric", "int_ior": float(layered.ior), "ext_ior": 1.0}
    if layered.oil == 0:
        return smooth
    rough = {"type": "roughdielectric", "distribution": "beckmann", "alpha": SURFACE_ROUGHNESS, "int_ior": SURFACE_IOR, "ext_ior": 1.0}
    return {"type": "blendbsdf", "weight": float(layered.oil), "bsdf_0": smooth, "bsdf_1": rough}


def mitsuba_layered_shapes(mi, layered: LayeredMedium, *, width_mm: float, depth_mm: float, mm_per_scene_unit: float = 1.0) -> dict:
    """Scene entries of a flat patch of the stack, ``width_mm`` wide and ``depth_mm`` deep (its top at
    z = 0, normal +z): the two media (ids ``epidermis``, ``dermis``) and the surface, interface and
    floor rectangles (module docstring)."""
    transform = mi.ScalarTransform4f
    half = width_mm / 2 / mm_per_scene_unit
    plane = lambda z: transform().translate([0, 0, z / mm_per_scene_unit]) @ transform().scale([half, half, 1])  # noqa: E731
    ref = lambda name: {"type": "ref", "id": name}  # noqa: E731
    return {
        **{name: {**medium, "id": name} for name, medium in mitsuba_layered_media(layered, mm_per_scene_unit=mm_per_scene_unit).items()},
        "skin_surface": {"type": "rectangle", "to_world": plane(0.0), "bsdf": mitsuba_layered_surface(layered), "interior": ref(EPIDERMIS)},
        "skin_interface": {"type": "rectangle", "to_world": plane(-layered.epidermis_thickness_mm), "bsdf": {"type": "null"},
                           "interior": ref(DERMIS), "exterior": ref(EPIDERMIS)},
        "skin_floor": {"type": "rectangle", "to_world": plane(-depth_mm), "bsdf": {"type": "diffuse", "reflectance": 0.0},
                       "exterior": ref(DERMIS)},
    }


def _dielectric_xml(bsdf: dict, attributes: str = "") -> str:
    rough = (f'<string name="distribution" value="{bsdf["distribution"]}"/><float name="alpha" value="{bsdf["alpha"]:g}"/>'
             if "alpha" in bsdf else "")
    return (f'<bsdf type="{bsdf["type"]}"{attributes}>{rough}<float name="int_ior" value="{bsdf["int_ior"]:g}"/>'
            f'<float name="ext_ior" value="{bsdf["ext_ior"]:g}"/></bsdf>')


def surface_xml(surface: dict) -> list[str]:
    """XML lines of the stack's BSDFs: ``skin_surface`` (``mitsuba_layered_surface``'s dielectric,
    or its blend with the rough oil lobe) and the ``null`` ``skin_interface``."""
    if surface["type"] == "blendbsdf":
        lines = [f'<bsdf type="blendbsdf" id="skin_surface"><float name="weight" value="{surface["weight"]:g}"/>',
                 f'    {_dielectric_xml(surface["bsdf_0"])}', f'    {_dielectric_xml(surface["bsdf_1"])}', "</bsdf>"]
    else:
        lines = [_dielectric_xml(surface, ' id="skin_surface"')]
    return lines + ['<bsdf type="null" id="skin_interface"/>']


def mitsuba_layered_xml(layered: LayeredMedium, *, mm_per_scene_unit: float = 1.0, comment: str = "") -> str:
    """An XML fragment (Mitsuba 3 scene format): media ``epidermis`` and ``dermis``, the surface BSDF
    ``skin_surface`` and the interface BSDF ``skin_interface``, with how to use them in comments."""
    media = mitsuba_layered_media(layered, mm_per_scene_unit=mm_per_scene_unit)
    notes = [*comment.splitlines(), *(f"{k}: {v}" for k, v in layered.describe().items()),
             f"coefficients per scene unit ({mm_per_scene_unit:g} mm)",
             "use: the skin mesh with <ref id=\"skin_surface\"/> <ref name=\"interior\" id=\"epidermis\"/>; a copy offset inwards by "
             f"{layered.epidermis_thickness_mm / mm_per_scene_unit:g} scene units with <ref id=\"skin_interface\"/> "
             "<ref name=\"interior\" id=\"dermis\"/> <ref name=\"exterior\" id=\"epidermis\"/>; the volpathmis integrator "
             "(spectral MIS: the channels' sigma_t differ), max_depth -1, rr_depth 5000 or more (g 0.8 takes thousands of bounces; from depth 200 the red renders 8 % dark)"]
    lines = [f"<!-- {line.replace('--', '- -')} -->" for line in notes if line.strip()]
    lines += surface_xml(mitsuba_layered_surface(layered))
    for name, medium in media.items():
        lines += [f'<medium type="homogeneous" id={quoteattr(name)}>',
                  *(f"    {_xml_value(key, medium[key])}" for key in ("albedo", "sigma_t", "scale")),
                  f"    {_phase_xml(layered.anisotropy)}", "</medium>"]
    return "\n".join(lines) + "\n"


def _checked(layered: LayeredMedium) -> LayeredMedium:
    if not isinstance(layered, LayeredMedium):
        raise SkinfitInputError(f"expected a skinfit LayeredMedium (export.layered_medium), got {type(layered).__name__}")
    if layered.oil != 0:
        raise SkinfitInputError("the render checks measure the diffuse albedo: export with oil 0")
    return layered


def _film(layered: LayeredMedium, resolution: int, band_nm: float) -> dict:
    if layered.wavelengths_nm is not None:
        if layered.wavelengths_nm.size > 16:
            raise SkinfitInputError("a spectral render check takes at most 16 wavelengths: export fewer for it")
        return spectral_film(layered.wavelengths_nm, band_nm, resolution)
    return rgb_film(resolution)


def _patch_mm(layered: LayeredMedium) -> float:
    """The checks' patch size: 80 diffusion lengths of the dermis, within 10-400 mm."""
    return float(np.clip(80.0 * layered.diffusion_length_mm(), 10.0, 400.0))


def _render(mi, layered: LayeredMedium, scene: dict, spp: int, seed: int) -> np.ndarray:
    """(pixels, channels) of ``scene``, the surface's specular reflection subtracted."""
    k = len(layered.channels)
    if layered.wavelengths_nm is not None:
        pixels = render_spectral_bands(mi, scene, k, spp, seed)
    else:
        pixels = np.asarray(mi.render(mi.load_dict(scene)), dtype=float).reshape(-1, k)
    return pixels - layered.specular


def _variant(layered: LayeredMedium, variant: str | None) -> str:
    return variant or ("scalar_spectral" if layered.wavelengths_nm is not None else "scalar_rgb")


def render_layered_albedo(layered: LayeredMedium, *, spp: int = 4096, resolution: int = 4, seed: int = 0, band_nm: float = 2.0,
                          variant: str | None = None, rr_depth: int = RR_DEPTH) -> tuple[np.ndarray, np.ndarray]:
    """(albedo (k,), standard error (k,)): the diffuse albedo Mitsuba renders for the stack per
    channel or wavelength (spectral: box bands ``band_nm`` wide), in a patch 80 diffusion lengths
    wide and deep (at least 10 mm); the error from the spread over the pixels."""
    layered = _checked(layered)
    mi = _mitsuba(_variant(layered, variant))
    size = _patch_mm(layered)
    extra = mitsuba_layered_shapes(mi, layered, width_mm=2 * size, depth_mm=size)
    scene = _slab_scene(mi, None, _film(layered, resolution, band_nm), spp=spp, seed=seed, view_mm=1.0, extra=extra,
                        rr_depth=rr_depth)
    pixels = _render(mi, layered, scene, spp, seed)
    return pixels.mean(axis=0), pixels.std(axis=0, ddof=1) / np.sqrt(len(pixels))


def render_layered_energy_within(layered: LayeredMedium, radii_mm, *, spp: int = 16384, seed: int = 0, band_nm: float = 2.0,
                                 variant: str | None = None, gap_fraction: float = 1e-2, rr_depth: int = RR_DEPTH) -> tuple[np.ndarray, np.ndarray]:
    """(energy (len(radii), k), standard error): the diffuse reflectance within each radius of a
    normally incident narrow beam, by reciprocity (``render_energy_within``: a black screen with a
    hole of radius r just above the surface, 16 pixels over 1e-3 mm at the centre)."""
    layered = _checked(layered)
    mi = _mitsuba(_variant(layered, variant))
    size = _patch_mm(layered)
    shapes = mitsuba_layered_shapes(mi, layered, width_mm=size, depth_mm=size / 2)
    energy, error = [], []
    for r in np.asarray(radii_mm, dtype=float):
        scene = screened_scene(mi, None, _film(layered, 4, band_nm), float(r), size, spp=spp, seed=seed, gap_fraction=gap_fraction,
                               shapes=shapes, rr_depth=rr_depth)
        pixels = _render(mi, layered, scene, spp, seed)
        energy.append(pixels.mean(axis=0))
        error.append(pixels.std(axis=0, ddof=1) / np.sqrt(len(pixels)))
    return np.array(energy), np.array(error)
