"""Mitsuba 3 exports of skin media, and the renders that check them.

The exports describe the homogeneous medium of ``skinfit.export`` (matched with exact
transport) as Mitsuba 3 plugins: a ``dielectric`` boundary (``int_ior`` n, ``ext_ior`` 1) with a
``homogeneous`` interior medium (single-scattering ``albedo``, extinction ``sigma_t`` times
``scale``, ``isotropic`` or ``hg`` phase function), for the volumetric path tracer (``volpath``):

- ``mitsuba_medium`` / ``mitsuba_material``: Python dictionaries for ``mitsuba.load_dict`` (RGB
  variants: one value per linear-sRGB channel);
- ``mitsuba_spectral_medium``: the same with ``spectrum`` values per wavelength, for the spectral
  variants (Mitsuba samples 360-830 nm, so the export should cover that range);
- ``mitsuba_xml``: an XML fragment with both (``mitsuba.load_string`` / scene files);
- ``write_mitsuba_volume`` and ``mitsuba_heterogeneous_medium``: per-texel media from fitted maps
  as Mitsuba ``.vol`` grids (sigma_t and albedo per RGB channel) for a ``heterogeneous`` medium.

Coefficients are per scene unit: ``mm_per_scene_unit`` (1 for scenes in mm, 1000 in metres).

The checks (``render_albedo``, ``render_spectral_albedo``, ``render_energy_within``) need the
optional dependency ``mitsuba`` (``pip install skinfit[mitsuba]``). They use the spectral-MIS
volumetric path tracer ``volpathmis`` (``volpath`` samples distances with one channel's sigma_t
and its estimate of a channel with a much smaller sigma_t is heavy-tailed: the light preset's red
rendered 28 % dark at 4,096 samples), Russian roulette from depth 200 and the ``multijitter``
sampler (with independent samples the specular choice at the boundary, a Bernoulli trial with
p = F0, dominated the error of dark channels and their estimates came out 5-15 % low at 4,096
samples). They render the exported
medium in a slab 100 mm deep and 400 mm wide under a uniform white environment, viewed at
normal incidence by an orthographic camera, and subtract the boundary's specular reflection
F0: what remains is the diffuse albedo the export was matched to (by reciprocity, the radiance
seen at normal view under uniform light is the reflectance of a normally incident beam).
``render_energy_within`` uses the same reciprocity for the radial check: a black screen with a
hole of radius r just above the surface lets the environment light only the disc r, and the
radiance seen at the centre is then the diffuse reflectance within r of a beam at the centre.
"""

from __future__ import annotations

import struct
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from .._validate import SkinfitInputError
from ..model import normal_fresnel_reflectance
from ._media import RendererMedium

#: Depth and width of the checks' slab, mm (the issue's reference scene).
SLAB_DEPTH_MM = 100.0
SLAB_WIDTH_MM = 400.0


def _phase(anisotropy: float) -> dict:
    return {"type": "isotropic"} if anisotropy == 0 else {"type": "hg", "g": float(anisotropy)}


def _check_rgb(medium: RendererMedium):
    if np.shape(medium.albedo) != (3,):
        raise SkinfitInputError(f"an RGB Mitsuba medium needs 3 channels, got shape {np.shape(medium.albedo)}")


def mitsuba_medium(medium: RendererMedium, *, mm_per_scene_unit: float = 1.0) -> dict:
    """A ``homogeneous`` medium (RGB variants) for ``mitsuba.load_dict``. Mitsuba's RGB inputs
    are bounded to [0, 1], so ``sigma_t`` is given as its channels over their largest times
    ``scale``."""
    _check_rgb(medium)
    sigma_t = np.asarray(medium.extinction_per_mm, dtype=float) * mm_per_scene_unit
    peak = float(sigma_t.max())
    return {
        "type": "homogeneous",
        "albedo": {"type": "rgb", "value": [float(v) for v in medium.single_scattering_albedo]},
        "sigma_t": {"type": "rgb", "value": [float(v) for v in sigma_t / peak]},
        "scale": peak,
        "phase": _phase(medium.conventions.anisotropy),
    }


#: The wavelength range Mitsuba's spectral variants sample, nm.
MITSUBA_SPECTRAL_RANGE_NM = (360.0, 830.0)


def mitsuba_spectral_medium(wavelengths_nm, medium: RendererMedium, *, mm_per_scene_unit: float = 1.0) -> dict:
    """A ``homogeneous`` medium with ``spectrum`` values per wavelength (spectral variants);
    ``medium`` holds one entry per wavelength (``renderer_profiles(...).spectral_medium``).
    Mitsuba samples 360-830 nm and reads an irregular spectrum as zero outside its wavelengths (a
    transparent medium there), so values are held constant from the export's ends to that range:
    export 360-830 nm (``skinfit profiles --format mitsuba-spectral`` does) for colours there."""
    lam = np.asarray(wavelengths_nm, dtype=float)
    if np.shape(medium.albedo) != lam.shape or lam.ndim != 1 or lam.size < 2 or np.any(np.diff(lam) <= 0):
        raise SkinfitInputError("a spectral Mitsuba medium needs one medium per wavelength, wavelengths increasing")
    albedo = np.asarray(medium.single_scattering_albedo, dtype=float)
    sigma_t = np.asarray(medium.extinction_per_mm, dtype=float) * mm_per_scene_unit
    return {
        "type": "homogeneous",
        "albedo": spectrum_value(lam, albedo),
        "sigma_t": spectrum_value(lam, sigma_t),
        "scale": 1.0,
        "phase": _phase(medium.conventions.anisotropy),
    }


def spectrum_value(wavelengths_nm, values) -> dict:
    """An irregular ``spectrum`` for Mitsuba, held constant from its ends to 360-830 nm (Mitsuba
    reads it as zero outside its wavelengths)."""
    lam, values = np.asarray(wavelengths_nm, dtype=float), np.asarray(values, dtype=float)
    low, high = MITSUBA_SPECTRAL_RANGE_NM
    if lam[0] > low:
        lam, values = np.r_[low, lam], np.r_[values[0], values]
    if lam[-1] < high:
        lam, values = np.r_[lam, high], np.r_[values, values[-1]]
    return {"type": "spectrum", "value": [(float(w), float(v)) for w, v in zip(lam, values)]}


def mitsuba_material(medium: dict, ior: float) -> dict:
    """The entries of a shape dictionary that make it skin: a smooth dielectric boundary and the
    interior ``medium`` (from ``mitsuba_medium`` or ``mitsuba_spectral_medium``)."""
    return {"bsdf": {"type": "dielectric", "int_ior": float(ior), "ext_ior": 1.0}, "interior": medium}


def _xml_head(comment: str, name: str, ior: float, ior_outside: float = 1.0) -> list[str]:
    """The comment lines and the dielectric boundary of a fragment."""
    lines = [f"<!-- {line.replace('--', '- -')} -->" for line in comment.splitlines() if line.strip()]  # XML comments cannot hold "--"
    return lines + [
        f'<bsdf type="dielectric" id={quoteattr(name + "_boundary")}>',
        f'    <float name="int_ior" value="{ior:g}"/>',
        f'    <float name="ext_ior" value="{ior_outside:g}"/>',
        "</bsdf>",
    ]


def _phase_xml(anisotropy: float) -> str:
    return '<phase type="isotropic"/>' if anisotropy == 0 else f'<phase type="hg"><float name="g" value="{anisotropy:g}"/></phase>'


def _xml_value(name: str, value) -> str:
    if isinstance(value, dict) and value["type"] == "rgb":
        return f'<rgb name="{name}" value="{", ".join(f"{v:.8g}" for v in value["value"])}"/>'
    if isinstance(value, dict) and value["type"] == "spectrum":
        return f'<spectrum name="{name}" value="{", ".join(f"{w:g}:{v:.8g}" for w, v in value["value"])}"/>'
    return f'<float name="{name}" value="{float(value):.8g}"/>'


def mitsuba_xml(material: dict, *, name: str = "skin", comment: str = "") -> str:
    """An XML fragment (Mitsuba 3 scene format) of ``material`` (``mitsuba_material``): a BSDF
    with id ``{name}_boundary`` and a medium with id ``name``, to reference from a shape as
    ``<ref id="{name}_boundary"/> <ref name="interior" id="{name}"/>``."""
    bsdf, medium = material["bsdf"], material["interior"]
    lines = _xml_head(comment, name, float(bsdf["int_ior"]), float(bsdf["ext_ior"])) + [
        f'<medium type="homogeneous" id={quoteattr(name)}>',
        f'    {_xml_value("albedo", medium["albedo"])}',
        f'    {_xml_value("sigma_t", medium["sigma_t"])}',
        f'    {_xml_value("scale", medium["scale"])}',
        f"    {_phase_xml(float(medium['phase'].get('g', 0.0)))}",
        "</medium>",
    ]
    return "\n".join(lines) + "\n"


def write_mitsuba_volume(path, values: np.ndarray) -> Path:
    """Write ``values`` (h, w, channels), one texel per map pixel and one layer deep, as a Mitsuba
    ``.vol`` grid (format version 3, float32, bounding box the unit cube; row 0 at y = 0)."""
    values = np.asarray(values, dtype=np.float32)
    if values.ndim != 3 or values.shape[-1] not in (1, 3):
        raise SkinfitInputError(f"a volume takes (h, w, 1 or 3) values, got shape {values.shape}")
    h, w, channels = values.shape
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = b"VOL" + struct.pack("<B", 3) + struct.pack("<iiiii", 1, w, h, 1, channels) + struct.pack("<6f", 0, 0, 0, 1, 1, 1)
    path.write_bytes(header + np.ascontiguousarray(values).tobytes())  # x fastest, then y, then z
    return path


def mitsuba_heterogeneous_medium(sigma_t_path, albedo_path, peak_extinction: float, anisotropy: float = 0.0, to_world=None) -> dict:
    """A ``heterogeneous`` medium reading the grids of ``write_mitsuba_volume`` (sigma_t as
    channels over ``peak_extinction`` per scene unit, which is the ``scale``); the grids span the
    unit cube, which ``to_world`` (a ``mitsuba.ScalarTransform4f``, given to both grids) places
    over the shape (outside the grids the medium is empty)."""
    placement = {} if to_world is None else {"to_world": to_world}
    return {
        "type": "heterogeneous",
        "albedo": {"type": "gridvolume", "filename": str(albedo_path), **placement},
        "sigma_t": {"type": "gridvolume", "filename": str(sigma_t_path), **placement},
        "scale": float(peak_extinction),
        "phase": _phase(anisotropy),
    }


def mitsuba_heterogeneous_xml(sigma_t_file: str, albedo_file: str, peak_extinction: float, *, ior: float, anisotropy: float = 0.0,
                              name: str = "skin", comment: str = "") -> str:
    """The XML fragment of ``mitsuba_heterogeneous_medium`` with its dielectric boundary (grid
    files relative to the scene file); place the grids with a ``to_world`` in each ``volume``."""
    lines = _xml_head(comment, name, ior) + [
        f'<medium type="heterogeneous" id={quoteattr(name)}>',
        f'    <volume type="gridvolume" name="albedo"><string name="filename" value={quoteattr(albedo_file)}/></volume>',
        f'    <volume type="gridvolume" name="sigma_t"><string name="filename" value={quoteattr(sigma_t_file)}/></volume>',
        f'    <float name="scale" value="{peak_extinction:.8g}"/>',
        f"    {_phase_xml(anisotropy)}",
        "</medium>",
    ]
    return "\n".join(lines) + "\n"


def _mitsuba(variant: str):
    try:
        import mitsuba as mi
    except ImportError as error:  # an optional dependency
        raise SkinfitInputError("the Mitsuba checks need Mitsuba 3: pip install 'skinfit[mitsuba]'") from error
    mi.set_variant(variant)
    return mi


def _slab_scene(mi, material: dict | None, film: dict, *, spp: int, seed: int, view_mm: float, extra: dict | None = None,
                rr_depth: int = 200, integrator: str = "volpathmis", sampler: str = "multijitter",
                width_mm: float = SLAB_WIDTH_MM, depth_mm: float = SLAB_DEPTH_MM) -> dict:
    transform = mi.ScalarTransform4f
    half_depth, half_width = depth_mm / 2, width_mm / 2
    scene = {
        "type": "scene",
        # Russian roulette from depth 200: the default (5) multiplies the variance of a bright,
        # weakly absorbing channel several times over
        "integrator": {"type": integrator, "max_depth": -1, "rr_depth": rr_depth},
        "sensor": {"type": "orthographic",
                   "to_world": transform().look_at(origin=[0, 0, 10], target=[0, 0, 0], up=[0, 1, 0]) @ transform().scale([view_mm, view_mm, 1]),
                   "film": film, "sampler": {"type": sampler, "sample_count": int(spp), "seed": int(seed)}},
        "environment": {"type": "constant", "radiance": 1.0},
    }
    if material is not None:  # else the slab's shapes come in ``extra``
        scene["slab"] = {"type": "cube", "to_world": transform().translate([0, 0, -half_depth]) @ transform().scale([half_width, half_width, half_depth]),
                         **material}
    return {**scene, **(extra or {})}


def _specular(material: dict) -> float:
    return float(normal_fresnel_reflectance(float(material["bsdf"]["int_ior"]), float(material["bsdf"]["ext_ior"])))


def render_albedo(material: dict, *, spp: int = 4096, resolution: int = 4, seed: int = 0,
                  variant: str = "scalar_rgb") -> tuple[np.ndarray, np.ndarray]:
    """(albedo (3,), standard error (3,)): the diffuse albedo Mitsuba renders for ``material``
    (``mitsuba_material`` of an RGB medium) in the reference slab; the error is the spread over
    the ``resolution``^2 independent pixels."""
    mi = _mitsuba(variant)
    scene = mi.load_dict(_slab_scene(mi, material, rgb_film(resolution), spp=spp, seed=seed, view_mm=1.0))
    pixels = np.asarray(mi.render(scene), dtype=float).reshape(-1, 3) - _specular(material)
    return pixels.mean(axis=0), pixels.std(axis=0, ddof=1) / np.sqrt(len(pixels))


def render_spectral_albedo(material: dict, wavelengths_nm, *, band_nm: float = 2.0, spp: int = 4096, resolution: int = 4,
                           seed: int = 0, variant: str = "scalar_spectral") -> tuple[np.ndarray, np.ndarray]:
    """(albedo, standard error) at each of ``wavelengths_nm`` (at most ~16): Mitsuba's spectral
    film with a box band ``band_nm`` wide around each wavelength, of the spectral ``material``.
    Each band is normalised by a render of the white environment alone through the same film
    (the film's band responses are not normalised to one another)."""
    mi = _mitsuba(variant)
    lam = np.asarray(wavelengths_nm, dtype=float)
    scene = _slab_scene(mi, material, spectral_film(lam, band_nm, resolution), spp=spp, seed=seed, view_mm=1.0)
    pixels = render_spectral_bands(mi, scene, lam.size, spp, seed) - _specular(material)
    return pixels.mean(axis=0), pixels.std(axis=0, ddof=1) / np.sqrt(len(pixels))


def rgb_film(resolution: int) -> dict:
    """Mitsuba's RGB film, ``resolution`` pixels square, box filter (independent pixels)."""
    return {"type": "hdrfilm", "width": resolution, "height": resolution, "rfilter": {"type": "box"}, "pixel_format": "rgb"}


def spectral_film(wavelengths_nm, band_nm: float, resolution: int) -> dict:
    """Mitsuba's spectral film with a box band ``band_nm`` wide around each wavelength (at most ~16)."""
    half = band_nm / 2
    bands = {f"band{k:02d}": {"type": "spectrum", "value": [(float(w - half), 1.0), (float(w + half), 1.0)]}
             for k, w in enumerate(np.asarray(wavelengths_nm, dtype=float))}
    return {"type": "specfilm", "width": resolution, "height": resolution, "rfilter": {"type": "box"}, **bands}


def render_spectral_bands(mi, scene: dict, bands: int, spp: int, seed: int) -> np.ndarray:
    """(pixels, bands): ``scene`` (a dictionary with a ``spectral_film``) rendered, each band
    normalised by a render of the white environment alone through the same film (the film's band
    responses are not normalised to one another)."""
    white = {key: scene[key] for key in ("type", "integrator", "sensor", "environment")}
    white["sensor"] = {**scene["sensor"], "sampler": {"type": "independent", "sample_count": 4 * int(spp), "seed": int(seed) + 1}}
    unit = np.asarray(mi.render(mi.load_dict(white)), dtype=float).reshape(-1, bands).mean(axis=0)
    return np.asarray(mi.render(mi.load_dict(scene)), dtype=float).reshape(-1, bands) / unit


def _annulus(mi, inner_mm: float, outer_mm: float, height_mm: float, segments: int = 512):
    """A black, flat ring at ``height_mm`` over the slab, as a mesh (Mitsuba has no annulus); the
    inner polygon circumscribes the circle of radius ``inner_mm``."""
    angle = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring = lambda r: np.stack([r * np.cos(angle), r * np.sin(angle), np.full(segments, height_mm)], axis=-1)  # noqa: E731
    vertices = np.concatenate([ring(inner_mm / np.cos(np.pi / segments)), ring(outer_mm)]).astype(np.float32)
    k = np.arange(segments)
    after = (k + 1) % segments
    faces = np.concatenate([np.stack([k, after, segments + k], -1), np.stack([after, segments + after, segments + k], -1)]).astype(np.uint32)
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": 0.0})
    mesh = mi.Mesh("screen", vertex_count=len(vertices), face_count=len(faces), props=props,
                   has_vertex_normals=False, has_vertex_texcoords=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = vertices.ravel()
    params["faces"] = faces.ravel()
    params.update()
    return mesh


def diffusion_length_mm(medium: dict) -> float:
    """The longest diffusion length 1 / sqrt(3 sigma_a sigma_t') over the channels of an RGB
    ``mitsuba_medium`` (mm per scene unit): how far light spreads before it is absorbed."""
    sigma_t = float(medium["scale"]) * np.asarray(medium["sigma_t"]["value"], dtype=float)
    albedo = np.asarray(medium["albedo"]["value"], dtype=float)
    g = float(medium["phase"].get("g", 0.0))
    return float(np.max(1.0 / np.sqrt(3.0 * (1.0 - albedo) * sigma_t * sigma_t * (1.0 - albedo * g))))


def render_energy_within(material: dict, radii_mm, *, spp: int = 16384, seed: int = 0, variant: str = "scalar_rgb",
                         gap_fraction: float = 1e-2) -> tuple[np.ndarray, np.ndarray]:
    """(energy (k, 3), standard error (k, 3)): the diffuse reflectance within each of
    ``radii_mm`` of a normally incident narrow beam, by reciprocity (module docstring): a black
    screen with a hole of radius r, ``gap_fraction`` r above the surface, and 16 pixels over
    1e-3 mm at the centre; the error from their spread. The slab is 40 diffusion lengths wide and
    deep (at least 5 mm): single precision resolves the gap only to ~3e-5 of the scene's size
    (smaller gaps leak light), and the gap is kept above that."""
    mi = _mitsuba(variant)
    radii = np.asarray(radii_mm, dtype=float)
    size = float(np.clip(80.0 * diffusion_length_mm(material["interior"]), 10.0, SLAB_WIDTH_MM))
    energy, error = [], []
    for r in radii:
        scene = screened_scene(mi, material, rgb_film(4), float(r), size, spp=spp, seed=seed, gap_fraction=gap_fraction)
        pixels = np.asarray(mi.render(mi.load_dict(scene)), dtype=float).reshape(-1, 3) - _specular(material)
        energy.append(pixels.mean(axis=0))
        error.append(pixels.std(axis=0, ddof=1) / np.sqrt(len(pixels)))
    return np.array(energy), np.array(error)


def screened_scene(mi, material: dict | None, film: dict, radius_mm: float, size_mm: float, *, spp: int, seed: int,
                   gap_fraction: float = 1e-2, shapes: dict | None = None, rr_depth: int = 200) -> dict:
    """The radial check's scene for one radius (``render_energy_within``): the slab ``size_mm``
    wide and half as deep (``material``'s cube, or ``shapes``), the black screen with a hole of
    ``radius_mm`` a gap above it, and the camera over 1e-3 mm (at most r / 100) at the centre."""
    gap = max(gap_fraction * radius_mm, 1.5e-5 * size_mm)
    return _slab_scene(mi, material, film, spp=spp, seed=seed, view_mm=min(1e-3, radius_mm * 1e-2), width_mm=size_mm,
                       depth_mm=size_mm / 2, rr_depth=rr_depth, extra={**(shapes or {}), "screen": _annulus(mi, radius_mm, size_mm, gap)})
