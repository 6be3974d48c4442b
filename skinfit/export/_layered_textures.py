"""Fitted maps as the model's two layers per texel: grids of each layer for Mitsuba 3.

``layered_textures`` gives every texel of fitted maps the RGB stack of ``layered_medium``
(epidermis and dermis absorption and scattering per linear-sRGB channel, matched by
adding-doubling to the texel's transport albedo). Solving that stack per texel costs about a
second, so the stacks are solved on a ``grid`` x ``grid`` table over the maps' melanin and
haemoglobin (log-spaced, at the maps' median melanin blend and oil) and each texel's coefficients
interpolated bilinearly in their logarithms. The texel albedo of the stack is then the table's
to within the interpolation (``LayeredTextures.albedo`` is the model's exact albedo per texel).

``write_mitsuba_layered_textures`` writes them as ``.vol`` grids (sigma_t over its peak and the
single-scattering albedo, per layer) with an XML of two ``heterogeneous`` media;
``mitsuba_layered_texture_shapes`` gives the same as ``load_dict`` entries over a flat patch.
Mitsuba's grids live in world space: they lay the maps over a flat patch, one texel per
``mm_per_pixel``; a curved mesh needs its renderer's texture-space media, which Mitsuba 3 lacks.
The stacks are checked against ``layered_medium`` and adding-doubling and Mitsuba is checked to load
them in place; no render has checked the grids' albedo (delta tracking in Mitsuba's heterogeneous
medium converges too slowly on CPU for that: docs/renderers.md).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from .._validate import SkinfitInputError
from .._version import __version__
from ..colorimetry import DEFAULT_ILLUMINANT, render_maps
from ..model import SkinParams
from ._layered import layered_medium
from ._mitsuba import _phase, _phase_xml, write_mitsuba_volume
from ._mitsuba_layered import DERMIS, EPIDERMIS, mitsuba_layered_surface, surface_xml
from ._renderers import _bilinear

#: The dermis under a patch: this many of its longest diffusion lengths deep (as the layered checks).
DERMIS_DIFFUSION_LENGTHS = 80.0
_LAYER_FIELDS = ("epidermis_absorption_per_mm", "epidermis_scattering_per_mm", "dermis_absorption_per_mm", "dermis_scattering_per_mm")


@dataclasses.dataclass(frozen=True)
class LayeredTextures:
    """Per-texel two-layer media (module docstring); each coefficient (h, w, 3) in mm^-1, per
    linear-sRGB channel (scattering not reduced)."""

    epidermis_absorption_per_mm: np.ndarray
    epidermis_scattering_per_mm: np.ndarray
    dermis_absorption_per_mm: np.ndarray
    dermis_scattering_per_mm: np.ndarray
    albedo: np.ndarray  # (h, w, 3) the model's linear-sRGB diffuse albedo per texel (its own method, no oil)
    epidermis_thickness_mm: float
    anisotropy: float
    ior: float
    oil: float
    metadata: dict

    @property
    def shape(self) -> tuple[int, int]:
        return self.albedo.shape[:2]

    def diffusion_length_mm(self) -> float:
        """The longest diffusion length 1 / sqrt(3 sigma_a (sigma_a + sigma_s')) of the dermis, mm."""
        a = self.dermis_absorption_per_mm
        reduced = self.dermis_scattering_per_mm * (1.0 - self.anisotropy)
        return float(np.max(1.0 / np.sqrt(3.0 * np.maximum(a, 1e-9) * (a + reduced))))


def layered_textures(maps: dict, *, grid: int = 12, illuminant: str = DEFAULT_ILLUMINANT, model=None,
                     progress: bool = False) -> LayeredTextures:
    """Per-texel stacks of fitted maps (``melanin``, ``haemoglobin``, optionally ``melanin_blend``
    and ``oil``, (h, w) arrays, e.g. ``skinfit.fit_image(...).maps()``): module docstring. Texels
    outside the skin (zero maps) get the stack of the maps' lowest values."""
    if grid < 2:
        raise SkinfitInputError(f"grid must be at least 2, got {grid}")
    try:
        melanin, haemoglobin = (np.asarray(maps[k], dtype=float) for k in ("melanin", "haemoglobin"))
    except KeyError as error:
        raise SkinfitInputError("maps must hold (h, w) melanin and haemoglobin arrays") from error
    if melanin.shape != haemoglobin.shape or melanin.ndim != 2:
        raise SkinfitInputError("maps must hold (h, w) melanin and haemoglobin arrays of one shape")
    fitted = (melanin > 0) & (haemoglobin > 0)
    if not fitted.any():
        raise SkinfitInputError("the maps hold no fitted texel (melanin and haemoglobin > 0)")
    blend = float(np.median(np.asarray(maps.get("melanin_blend", 0.7), dtype=float).reshape(-1)))
    oil = float(np.median(np.asarray(maps.get("oil", 0.0), dtype=float).reshape(-1)))
    c_m = np.clip(melanin, melanin[fitted].min(), None)
    c_h = np.clip(haemoglobin, haemoglobin[fitted].min(), None)
    # an axis the maps hold one value on needs two nodes, not ``grid``
    axis = lambda c: np.geomspace(c.min(), max(c.max(), c.min() * 1.001), grid if c.max() > c.min() * 1.001 else 2)  # noqa: E731
    axis_m, axis_h = axis(c_m), axis(c_h)
    table = np.empty((axis_m.size, axis_h.size, len(_LAYER_FIELDS) * 3))
    first = None
    for i, m in enumerate(axis_m):
        for j, h in enumerate(axis_h):
            stack = layered_medium(SkinParams(float(m), blend, float(h), oil), illuminant=illuminant, model=model)
            table[i, j] = np.log(np.concatenate([getattr(stack, name) for name in _LAYER_FIELDS]))
            first = first or stack
        if progress:
            print(f"layered textures: {i + 1}/{axis_m.size} rows of the table", flush=True)
    x = np.interp(np.log(c_m), np.log(axis_m), np.arange(axis_m.size))
    y = np.interp(np.log(c_h), np.log(axis_h), np.arange(axis_h.size))
    coefficients = np.exp(_bilinear(table, x, y)).reshape(*melanin.shape, len(_LAYER_FIELDS), 3)
    albedo = render_maps(c_m, c_h, np.ones_like(c_m), melanin_blend=blend, illuminant=illuminant, model=model)
    metadata = {"generator": f"skinfit {__version__}", "model": first.metadata["model"], "melanin_blend": blend, "oil": oil,
                "table": f"{axis_m.size} x {axis_h.size} stacks over melanin {axis_m[0]:.4g}-{axis_m[-1]:.4g}, haemoglobin {axis_h[0]:.4g}-{axis_h[-1]:.4g} "
                         "(log-spaced), coefficients bilinear in their logarithms"}
    return LayeredTextures(*(coefficients[..., k, :] for k in range(len(_LAYER_FIELDS))), np.asarray(albedo, dtype=float),
                           first.epidermis_thickness_mm, first.anisotropy, first.ior, oil, metadata)


def _grids(textures: LayeredTextures, mm_per_scene_unit: float) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
    """Per layer: (sigma_t over its peak, single-scattering albedo, peak per scene unit), rows flipped so
    that the maps' row 0 lies at +y (the top, for a camera whose up is +y)."""
    out = {}
    for layer in (EPIDERMIS, DERMIS):
        a = getattr(textures, f"{layer}_absorption_per_mm")
        s = getattr(textures, f"{layer}_scattering_per_mm")
        sigma_t = (a + s) * mm_per_scene_unit
        peak = float(sigma_t.max())
        out[layer] = ((sigma_t / peak)[::-1], (s / (a + s))[::-1], peak)
    return out


def _write_grids(textures: LayeredTextures, folder: Path, mm_per_scene_unit: float) -> dict[str, float]:
    """Write each layer's sigma_t and albedo grids into ``folder``; returns each layer's peak sigma_t (per scene unit)."""
    peaks = {}
    for layer, (sigma_t, albedo, peak) in _grids(textures, mm_per_scene_unit).items():
        write_mitsuba_volume(folder / f"{layer}_sigma_t.vol", sigma_t)
        write_mitsuba_volume(folder / f"{layer}_albedo.vol", albedo)
        peaks[layer] = peak
    return peaks


def _placements(textures: LayeredTextures, mm_per_pixel: float, depth_mm: float, mm_per_scene_unit: float):
    """(width, height, epidermis thickness, depth) in scene units and each layer's grid box (origin, size)."""
    h, w = textures.shape
    width, height = w * mm_per_pixel / mm_per_scene_unit, h * mm_per_pixel / mm_per_scene_unit
    thickness, depth = textures.epidermis_thickness_mm / mm_per_scene_unit, depth_mm / mm_per_scene_unit
    boxes = {EPIDERMIS: ([-width / 2, -height / 2, -thickness], [width, height, thickness]),
             DERMIS: ([-width / 2, -height / 2, -depth], [width, height, depth - thickness])}
    return width, height, thickness, depth, boxes


def _depth(textures: LayeredTextures, depth_mm: float | None) -> float:
    return max(10.0, DERMIS_DIFFUSION_LENGTHS * textures.diffusion_length_mm()) if depth_mm is None else float(depth_mm)


def mitsuba_layered_texture_shapes(mi, textures: LayeredTextures, folder, *, mm_per_pixel: float, depth_mm: float | None = None,
                                   mm_per_scene_unit: float = 1.0) -> dict:
    """Scene entries for ``mitsuba.load_dict``: the grids written into ``folder``, the two
    ``heterogeneous`` media (ids ``epidermis``, ``dermis``) placed over a flat patch of
    ``mm_per_pixel`` per texel (top at z = 0, row 0 at +y), and the surface, interface and floor
    rectangles of ``mitsuba_layered_shapes``."""
    if not mm_per_pixel > 0:
        raise SkinfitInputError(f"mm_per_pixel must be positive, got {mm_per_pixel!r}")
    folder = Path(folder)
    transform = mi.ScalarTransform4f
    width, height, thickness, depth, boxes = _placements(textures, mm_per_pixel, _depth(textures, depth_mm), mm_per_scene_unit)
    entries = {}
    for layer, peak in _write_grids(textures, folder, mm_per_scene_unit).items():
        origin, size = boxes[layer]
        box = transform().translate(origin) @ transform().scale(size)
        entries[layer] = {"type": "heterogeneous", "id": layer, "scale": peak, "phase": _phase(textures.anisotropy),
                          "sigma_t": {"type": "gridvolume", "filename": str(folder / f"{layer}_sigma_t.vol"), "to_world": box},
                          "albedo": {"type": "gridvolume", "filename": str(folder / f"{layer}_albedo.vol"), "to_world": box}}
    plane = lambda z: transform().translate([0, 0, z]) @ transform().scale([width / 2, height / 2, 1])  # noqa: E731
    ref = lambda name: {"type": "ref", "id": name}  # noqa: E731
    surface = mitsuba_layered_surface(textures)  # it reads the stack's ior and oil
    return {
        **entries,
        "skin_surface": {"type": "rectangle", "to_world": plane(0.0), "bsdf": surface, "interior": ref(EPIDERMIS)},
        "skin_interface": {"type": "rectangle", "to_world": plane(-thickness), "bsdf": {"type": "null"},
                           "interior": ref(DERMIS), "exterior": ref(EPIDERMIS)},
        "skin_floor": {"type": "rectangle", "to_world": plane(-depth), "bsdf": {"type": "diffuse", "reflectance": 0.0},
                       "exterior": ref(DERMIS)},
    }


def _transform_xml(origin, size) -> str:
    return (f'<transform name="to_world"><scale x="{size[0]:.8g}" y="{size[1]:.8g}" z="{size[2]:.8g}"/>'
            f'<translate x="{origin[0]:.8g}" y="{origin[1]:.8g}" z="{origin[2]:.8g}"/></transform>')


def write_mitsuba_layered_textures(textures: LayeredTextures, folder, *, mm_per_pixel: float, depth_mm: float | None = None,
                                   mm_per_scene_unit: float = 1.0) -> Path:
    """Write ``epidermis_sigma_t.vol``, ``epidermis_albedo.vol``, ``dermis_sigma_t.vol``,
    ``dermis_albedo.vol`` and ``skin_layers.xml`` (the two ``heterogeneous`` media placed over a
    flat patch, ``mm_per_pixel`` per texel, the surface and interface BSDFs and how to use them)
    into ``folder``. Returns the XML's path."""
    if not mm_per_pixel > 0:
        raise SkinfitInputError(f"mm_per_pixel must be positive, got {mm_per_pixel!r}")
    folder = Path(folder)
    depth = _depth(textures, depth_mm)
    width, height, thickness, depth_units, boxes = _placements(textures, mm_per_pixel, depth, mm_per_scene_unit)
    lines = [f"<!-- {line.replace('--', '- -')} -->" for line in [
        f"{textures.metadata['generator']}: fitted maps as the model's two layers per texel ({textures.metadata['model']})",
        f"per-texel stacks: {textures.metadata['table']}; melanin blend {textures.metadata['melanin_blend']:.3g}, oil {textures.oil:g}",
        f"patch: {textures.shape[1]} x {textures.shape[0]} texels, {mm_per_pixel:g} mm each; top at z = 0, the maps' row 0 at +y; "
        f"epidermis {textures.epidermis_thickness_mm:g} mm thick, dermis to {depth:.4g} mm deep (a black floor below)",
        f"Henyey-Greenstein g {textures.anisotropy:g}; smooth dielectric surface of index {textures.ior:g} under air"
        + ("" if textures.oil == 0 else f", a share {textures.oil:g} of it the model's rough oil lobe") + "; layers index-matched",
        f"coefficients per scene unit ({mm_per_scene_unit:g} mm); the grids are in world space (a flat patch, not a curved mesh)",
        "use: a rectangle at z = 0 with <ref id=\"skin_surface\"/> <ref name=\"interior\" id=\"epidermis\"/>, one at the epidermis' depth "
        "with <ref id=\"skin_interface\"/> <ref name=\"interior\" id=\"dermis\"/> <ref name=\"exterior\" id=\"epidermis\"/>; "
        "volpathmis, max_depth -1, rr_depth 5000 or more"]]
    lines += surface_xml(mitsuba_layered_surface(textures))
    for layer, peak in _write_grids(textures, folder, mm_per_scene_unit).items():
        placed = _transform_xml(*boxes[layer])
        lines += [f'<medium type="heterogeneous" id={quoteattr(layer)}>',
                  f'    <volume type="gridvolume" name="albedo"><string name="filename" value="{layer}_albedo.vol"/>{placed}</volume>',
                  f'    <volume type="gridvolume" name="sigma_t"><string name="filename" value="{layer}_sigma_t.vol"/>{placed}</volume>',
                  f'    <float name="scale" value="{peak:.8g}"/>',
                  f"    {_phase_xml(textures.anisotropy)}", "</medium>"]
    path = folder / "skin_layers.xml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
