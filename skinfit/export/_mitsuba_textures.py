"""Per-texel skin media rendered back in Mitsuba 3: what a renderer makes of fitted maps.

``render_textures`` lays the media of ``renderer_textures`` (one homogeneous medium per texel,
each matched with exact transport to the texel's albedo and median energy radius) over a slab
``mm_per_pixel`` per texel, lights it with a uniform white environment, views it at normal
incidence with an orthographic camera of one pixel per texel, and subtracts the boundary's
specular reflection F0: each pixel is then the diffuse reflectance the renderer gives that texel
with its neighbours around it (by reciprocity, as in ``render_albedo``).

Light that enters at one texel leaves at others, so the render is the texels' albedos blurred by
the skin's own profile (about a millimetre in red). A capture of real skin already holds that
blur: fitted per pixel and rendered again, it is blurred twice. ``deconvolve_albedo``
(``skinfit.export``) gives the albedo whose render is the capture.
"""

from __future__ import annotations

import numpy as np

from .._validate import SkinfitInputError
from ._media import DEFAULT_CONVENTIONS, RendererConventions
from ._mitsuba import _mitsuba, mitsuba_heterogeneous_medium, write_mitsuba_volume


def _stack(textures: dict, name: str) -> np.ndarray:
    try:
        return np.stack([np.asarray(textures[f"{name}.{c}"], dtype=float) for c in "RGB"], axis=-1)
    except KeyError as error:
        raise SkinfitInputError(f"textures need {name}.R/.G/.B (skinfit.export.renderer_textures)") from error


def textures_depth_mm(textures: dict, conventions: RendererConventions = DEFAULT_CONVENTIONS, diffusion_lengths: float = 20.0) -> float:
    """A slab depth (mm) of ``diffusion_lengths`` times the longest diffusion length of any texel
    and channel, 1 / sqrt(3 sigma_a sigma_t') (deep enough that the floor does not show)."""
    sigma_t, albedo = _stack(textures, "sigma_t"), _stack(textures, "ss_albedo")
    g = conventions.anisotropy
    sigma_a = np.maximum((1.0 - albedo) * sigma_t, 1e-12)
    reduced = sigma_t * (1.0 - albedo * g)
    return float(diffusion_lengths * np.max(1.0 / np.sqrt(3.0 * sigma_a * reduced)))


def render_textures(textures: dict, mm_per_pixel: float, *, spp: int = 256, seed: int = 0, folder=None,
                    conventions: RendererConventions = DEFAULT_CONVENTIONS, depth_mm: float | None = None,
                    rr_depth: int = 5000, variant: str = "scalar_rgb") -> np.ndarray:
    """The diffuse albedo (h, w, 3) Mitsuba renders for ``renderer_textures``' media laid out at
    ``mm_per_pixel`` (row 0 at the top, as the maps), under a uniform white environment at normal
    view, the specular F0 subtracted. ``folder`` keeps the grids (else a temporary one).
    Russian roulette from ``rr_depth`` (a bright red path scatters thousands of times)."""
    import tempfile
    from pathlib import Path

    if not mm_per_pixel > 0:
        raise SkinfitInputError(f"mm_per_pixel must be positive, got {mm_per_pixel!r}")
    sigma_t = _stack(textures, "sigma_t")
    h, w, _ = sigma_t.shape
    depth = textures_depth_mm(textures, conventions) if depth_mm is None else float(depth_mm)
    width, height = w * mm_per_pixel, h * mm_per_pixel
    mi = _mitsuba(variant)
    transform = mi.ScalarTransform4f
    with tempfile.TemporaryDirectory() as scratch:
        where = Path(folder or scratch)
        peak = float(sigma_t.max())
        # grids' y = 0 is the maps' row 0; the camera's up is +y, so row 0 goes at the top (y = +height/2)
        write_mitsuba_volume(where / "sigma_t.vol", (sigma_t / peak)[::-1])
        write_mitsuba_volume(where / "albedo.vol", _stack(textures, "ss_albedo")[::-1])
        grid = transform().translate([-width / 2, -height / 2, -depth]) @ transform().scale([width, height, depth])
        medium = mitsuba_heterogeneous_medium(where / "sigma_t.vol", where / "albedo.vol", peak, conventions.anisotropy, to_world=grid)
        scene = {
            "type": "scene",
            "integrator": {"type": "volpathmis", "max_depth": -1, "rr_depth": int(rr_depth)},
            "sensor": {"type": "orthographic",
                       "to_world": transform().look_at(origin=[0, 0, 10], target=[0, 0, 0], up=[0, 1, 0])
                       @ transform().scale([width / 2, width / 2, 1]),  # x spans the film's width; y follows its aspect
                       "film": {"type": "hdrfilm", "width": int(w), "height": int(h), "rfilter": {"type": "box"},
                                "pixel_format": "rgb", "component_format": "float32"},
                       "sampler": {"type": "multijitter", "sample_count": int(spp), "seed": int(seed)}},
            "environment": {"type": "constant", "radiance": 1.0},
            "slab": {"type": "cube", "to_world": transform().translate([0, 0, -depth / 2]) @ transform().scale([width / 2, height / 2, depth / 2]),
                     "bsdf": {"type": "dielectric", "int_ior": float(conventions.ior), "ext_ior": 1.0}, "interior": medium},
        }
        image = np.asarray(mi.render(mi.load_dict(scene)), dtype=float)
    return image - conventions.specular
