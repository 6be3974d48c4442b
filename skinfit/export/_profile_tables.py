"""Profile tables for renderers and tools: spectral and RGB radial profiles with their provenance.

A table holds R(r, lambda) in mm^-2 on the requested radii, the linear-sRGB profiles obtained with
the same colour weights as ``colorimetry``, and the totals they integrate to. Files record units,
parameters and options: CSV (comment header), NPZ (arrays plus a JSON metadata string) and EXR (two
parts: "spectral", one row per wavelength, and "rgb", one row, with metadata attributes).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from .._validate import SkinfitInputError
from .._version import __version__
from ..colorimetry import DEFAULT_ILLUMINANT, linear_srgb_weights
from ..model import (
    HankelQuadrature,
    SkinParams,
    diffuse_reflectance,
    model_with_options,
    normal_fresnel_reflectance,
    profile,
)

TABLE_FORMATS = (".csv", ".npz", ".exr")


@dataclasses.dataclass(frozen=True)
class ProfileTable:
    """Radial profiles of one parameter set.

    Attributes:
        wavelengths_nm: (n_wavelengths,)
        radii_mm: (n_radii,)
        spectral: (n_wavelengths, n_radii) R(r, lambda) in mm^-2; integrates to R12(0).
        rgb: (3, n_radii) linear-sRGB profiles in mm^-2 (same colour weights as the reflectance).
        reflectance: (n_wavelengths,) diffuse reflectance (1 - F0) R12(0).
        metadata: parameters, options, units and provenance (JSON-serialisable).
    """

    wavelengths_nm: np.ndarray
    radii_mm: np.ndarray
    spectral: np.ndarray
    rgb: np.ndarray
    reflectance: np.ndarray
    metadata: dict


def profile_table(
    params: SkinParams,
    wavelengths_nm,
    radii_mm,
    *,
    illuminant: str = DEFAULT_ILLUMINANT,
    label: str = "",
    quadrature: HankelQuadrature = HankelQuadrature(),
    **model_options,
) -> ProfileTable:
    """Compute a ``ProfileTable`` for one (scalar) parameter set.

    ``model_options`` (adding, blood_oxygenation, epidermis_thickness_mm, ior) are those of
    ``diffuse_reflectance``.
    """
    if params.shape != ():
        raise SkinfitInputError("profile_table takes one parameter set (scalar SkinParams fields)")
    lam = np.asarray(wavelengths_nm, dtype=float)
    radii = np.asarray(radii_mm, dtype=float)
    spectral = np.asarray(profile(params, lam, radii, quadrature=quadrature, **model_options))
    reflectance = np.asarray(diffuse_reflectance(params, lam, **model_options))
    rgb = linear_srgb_weights(lam, illuminant) @ spectral
    resolved = model_with_options(model_options.get("model"), ior=model_options.get("ior"))
    ior = float(np.mean(np.asarray(resolved.ior)))
    metadata = {
        "generator": f"skinfit {__version__}",
        "model": resolved.description,
        "label": label,
        "parameters": {
            "melanin": float(params.melanin),
            "melanin_blend": float(params.melanin_blend),
            "haemoglobin": float(params.haemoglobin),
        },
        "options": {k: (v if isinstance(v, (str, float, int)) else repr(v)) for k, v in model_options.items() if k != "model"},
        "quadrature": dataclasses.asdict(quadrature),
        "units": {"wavelength": "nm", "radius": "mm", "profile": "mm^-2"},
        "profile_normalisation": (
            "integral of 2 pi r R(r) dr equals R12(0), the diffuse reflectance before the entry Fresnel "
            f"factor; multiply by 1 - F0 = {1.0 - float(normal_fresnel_reflectance(ior)):.6f} "
            "to integrate to the diffuse reflectance"
        ),
        "rgb": f"linear sRGB, illuminant {illuminant}, CIE 1931 2 degree observer (white = 1)",
    }
    return ProfileTable(lam, radii, spectral, rgb, reflectance, metadata)


def write_table(table: ProfileTable, path: str | Path) -> Path:
    """Write a table; the format follows the extension (.csv, .npz or .exr)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in TABLE_FORMATS:
        raise SkinfitInputError(f"unknown table format {path.suffix!r}; use one of {', '.join(TABLE_FORMATS)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    {".csv": write_csv, ".npz": _write_npz, ".exr": _write_exr}[suffix](table, path)
    return path


def write_csv(table: ProfileTable, path: Path) -> None:
    header = [f"# {line}" for line in json.dumps(table.metadata, indent=1).splitlines()]
    header.append(
        "# columns: radius_mm, then R(r) in mm^-2 per wavelength (R_<nm>nm), then linear sRGB profiles"
    )
    names = ["radius_mm"] + [f"R_{w:g}nm" for w in table.wavelengths_nm] + ["R_red", "R_green", "R_blue"]
    data = np.column_stack([table.radii_mm, table.spectral.T, table.rgb.T])
    body = "\n".join(",".join(f"{v:.10g}" for v in row) for row in data)
    path.write_text("\n".join(header + [",".join(names), body]) + "\n", encoding="utf-8")


def _write_npz(table: ProfileTable, path: Path) -> None:
    np.savez_compressed(
        path,
        wavelengths_nm=table.wavelengths_nm,
        radii_mm=table.radii_mm,
        spectral=table.spectral,
        rgb=table.rgb,
        reflectance=table.reflectance,
        metadata=json.dumps(table.metadata),
    )


def _write_exr(table: ProfileTable, path: Path) -> None:
    import OpenImageIO as oiio

    n_wavelengths, n_radii = table.spectral.shape
    spectral_spec = oiio.ImageSpec(n_radii, n_wavelengths, 1, "float")
    spectral_spec.channelnames = ("R",)
    rgb_spec = oiio.ImageSpec(n_radii, 1, 3, "float")
    rgb_spec.channelnames = ("R", "G", "B")
    for spec, name in ((spectral_spec, "spectral"), (rgb_spec, "rgb")):
        spec.attribute("name", name)
        spec.full_width, spec.full_height = n_radii, n_wavelengths  # parts must share a display window
        spec.attribute("skinfit:wavelengths_nm", ",".join(f"{w:g}" for w in table.wavelengths_nm))
        spec.attribute("skinfit:radii_mm", ",".join(f"{r:.10g}" for r in table.radii_mm))
        spec.attribute("skinfit:reflectance", ",".join(f"{v:.10g}" for v in table.reflectance))
        spec.attribute("skinfit:metadata", json.dumps(table.metadata))
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), [spectral_spec, rgb_spec]):
        raise OSError(f"cannot write {path}: {oiio.geterror() if out is None else out.geterror()}")
    try:
        ok = out.write_image(np.ascontiguousarray(table.spectral[:, :, None], dtype=np.float32))
        ok = ok and out.open(str(path), rgb_spec, "AppendSubimage")
        ok = ok and out.write_image(np.ascontiguousarray(table.rgb.T[None, :, :], dtype=np.float32))
        if not ok:
            raise OSError(f"cannot write {path}: {out.geterror()}")
    finally:
        out.close()


def read_exr_table(path: str | Path) -> ProfileTable:
    """Read back an EXR profile table written by ``write_table``."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise SkinfitInputError(f"cannot read {path}: {oiio.geterror()}")
    try:
        spec = inp.spec()
        wavelengths = np.array([float(v) for v in spec.getattribute("skinfit:wavelengths_nm").split(",")])
        radii = np.array([float(v) for v in spec.getattribute("skinfit:radii_mm").split(",")])
        reflectance = np.array([float(v) for v in spec.getattribute("skinfit:reflectance").split(",")])
        metadata = json.loads(spec.getattribute("skinfit:metadata"))
        spectral = np.asarray(inp.read_image("float"))[:, :, 0]
        inp.seek_subimage(1, 0)
        rgb = np.asarray(inp.read_image("float"))[0].T
    finally:
        inp.close()
    return ProfileTable(wavelengths, radii, spectral, rgb, reflectance, metadata)
