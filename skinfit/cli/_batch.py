"""One fitted image written to a folder: the job of ``skinfit fit-image``, a batch and a Dask worker.

``fit_image_to_folder`` fits one image and writes ``<stem>_reconstructed.png``, ``<stem>_dE2000.png``,
``<stem>_skin_mask.png``, ``<stem>_regions.png`` (the face regions over the photo) and, last and atomically (its presence marks the image done, so an
interrupted batch keeps every finished image and a rerun skips them), ``<stem>_maps.exr``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .. import _scratch as scratch
from ..colorimetry import srgb_encode
from ..fit import fit_image
from ..io import read_linear_rgb, write_exr, write_png
from ._plots import region_overlay


def fit_image_to_folder(path, out: Path, options: dict) -> str:
    """Fit one image and write its outputs into ``out``; returns the summary line."""
    stem = Path(path).stem
    fit = fit_image(path, **options)
    # under the region overlay: float32 (a third of float64's decoding, beside the fit's maps)
    photo = read_linear_rgb(path, options.get("input_space"), np.float32)[0] if fit.region is not None else None
    maps_path = write_fit(fit, out, f"{stem}_", str(path), options.get("illuminant", "D65"), photo)
    summary = fit.summary()
    return (
        f"{path}: {_skin_text(fit)}, {summary['fitted']} of {summary['pixels']} pixels fitted ({100 * summary['fitted_fraction']:.1f} %), "
        f"CIEDE2000 median {summary['median_dE2000']:.3g}, 95th percentile {summary['p95_dE2000']:.3g}, "
        f"blend {blend_text(fit)}, white balance {white_balance_text(fit)}, "
        f"model {summary['model']}, {summary['seconds']:.1f} s -> {maps_path}"
    )


def _skin_text(fit) -> str:
    if fit.skin_from == "faces":
        return f"{fit.faces} face{'s' if fit.faces != 1 else ''}"
    return "no face found" if fit.faces == 0 else f"skin from the {fit.skin_from}"


def blend_text(fit) -> str:
    """The blend, with its sd where estimated per face: '0.425 (+-0.26)'; for up to
    ``_LISTED_FACES`` faces each face's, for more their median and range (the summary and the
    EXR's ``melanin_blend_sd`` hold every face's)."""
    if not fit.blends:
        return f"{fit.summary()['melanin_blend']:.3g}"
    if len(fit.blends) > _LISTED_FACES:
        blends, sds = np.array([b["melanin_blend"] for b in fit.blends]), np.array([b["sd"] for b in fit.blends])
        return (f"median {np.median(blends):.3g} (range {blends.min():.3g}-{blends.max():.3g}, "
                f"median +-{np.median(sds):.2g}) over {len(blends)} faces")
    return ", ".join(f"{b['melanin_blend']:.3g} (+-{b['sd']:.2g})" for b in fit.blends)


#: Faces whose blends the printed line lists one by one.
_LISTED_FACES = 6


def white_balance_text(fit) -> str:
    """The gains, with their relative standard errors where fitted: '0.780 1.000 1.070 (+-4 %, 0 %, 3 %)'."""
    text = " ".join(f"{g:.3f}" for g in fit.white_balance)
    if fit.white_balance_sd:
        text += " (+-" + ", ".join(f"{100 * s:.0f} %" for s in fit.white_balance_sd) + ")"
    return text


def write_fit(fit, out: Path, prefix: str, source: str, illuminant: str, photo: np.ndarray | None = None) -> Path:
    """Write ``<prefix>reconstructed.png``, ``<prefix>dE2000.png``, ``<prefix>skin_mask.png``,
    ``<prefix>regions.png`` (where faces were segmented; over ``photo``, linear sRGB, if given)
    and, last (atomically, so that its presence marks the image done), ``<prefix>maps.exr``;
    returns the maps path."""
    # each picture is made a band of rows at a time as it is written: no full-size copies beside the maps
    under = fit.fitted_linear_rgb if photo is None else photo
    write_png(out / f"{prefix}reconstructed.png", scratch.Rows(fit.fitted_linear_rgb.shape, lambda rows: encoded_srgb(fit.fitted_linear_rgb[rows])))
    write_png(out / f"{prefix}dE2000.png", scratch.Rows((*fit.residual_dE2000.shape, 3), lambda rows: delta_e_image(fit.residual_dE2000[rows])))
    write_png(out / f"{prefix}skin_mask.png", fit.skin_mask[..., None])  # one channel, 0 or 255
    if fit.region is not None:
        write_png(out / f"{prefix}regions.png",
                  scratch.Rows(under.shape, lambda rows: region_overlay(encoded_srgb(np.asarray(under[rows], np.float32)), fit.region[rows])))
    attributes = {
        "skinfit:source": source,
        "skinfit:illuminant": illuminant,
        "skinfit:white_balance": " ".join(f"{g:.9g}" for g in fit.white_balance),
        **({"skinfit:white_balance_sd": " ".join(f"{g:.4g}" for g in fit.white_balance_sd)} if fit.white_balance_sd else {}),
        "skinfit:input_encoding": fit.input_encoding,
        "skinfit:skin_from": fit.skin_from,
        "skinfit:model": fit.model_name,
        "skinfit:summary": json.dumps(fit.summary()),
    }
    maps_path = out / f"{prefix}maps.exr"
    write_exr(maps_path, fit.maps(), attributes)
    return maps_path


def encoded_srgb(linear: np.ndarray, rows: int = 256) -> np.ndarray:
    """sRGB-encoded float32 copy of a linear image (clipped to [0, 1]), in bands of rows: a
    4096 x 4096 image through JAX at once would hold several float64 copies."""
    encoded = np.empty(linear.shape, np.float32)
    for top in range(0, linear.shape[0], rows):
        encoded[top : top + rows] = np.asarray(srgb_encode(np.clip(linear[top : top + rows], 0.0, 1.0).astype(np.float32)))
    return encoded


def delta_e_image(delta_e: np.ndarray) -> np.ndarray:
    """CIEDE2000 map as a colour image: black 0 -> yellow 2 (clipped)."""
    t = np.clip(delta_e / 2.0, 0.0, 1.0).astype(np.float32)[..., None]
    return t * np.array([1.0, 0.85, 0.1], np.float32)
