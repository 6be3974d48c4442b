"""Image fits over the whole parameter box, on renders by an independent colour pipeline.

Run: python -m benchmarks.fit_image_box [--size 160] [--out benchmarks/results]

For each model (DJ2006 and the package default) smooth maps span the model's whole skin box
(``skinfit.fit.skin_box``: the colour table's box up to ``MELANIN_MAX`` 0.5 and ``HAEMOGLOBIN_MAX``
0.15, narrowed by the population prior where the model has one; from 0.001 at the least), both
log-spaced along the image's two axes with a gentle wave so that every value meets several
shadings, and a shading field 0.5-1 across the diagonal. The spectra are the model's
(``skinfit.diffuse_reflectance``, 360-830 nm in 5 nm steps); their colour is colour-science's
(``colour.msds_to_XYZ`` under D65, CIE 1931 2 degrees, then ``XYZ_to_RGB`` to linear sRGB), not
skinfit's colour code. Fitted by ``fit_image`` with ``white_balance="none"`` and the blend of the
render, priors off (``prior=False``) and with the defaults' priors; reported: relative errors of
melanin and haemoglobin (median, p99; p99 where the colour identifies the value; the share
of pixels whose two-standard-error interval holds the truth) and the statuses of the pixels.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import skinfit
from benchmarks._record import provenance
from skinfit.colorimetry import HAEMOGLOBIN_MAX, MELANIN_MAX
from skinfit.fit import population_blend, skin_box

#: Box of the render: the colour table's, from 0.001.
LOWEST = 0.001
RENDER_WAVELENGTHS_NM = np.arange(360.0, 831.0, 5.0)
MODELS = {"dj2006": skinfit.SkinModel.dj2006, "default": skinfit.SkinModel.default}


def box_maps(size: int, box: dict | None = None):
    """Melanin (log-spaced along x), haemoglobin (along y) and shading maps (size, size) over
    ``box`` ({name: (low, high)}; default: the colour table's, from ``LOWEST``): smooth
    everywhere, each value of the box crossed by shadings 0.5-1."""
    box = box or {"melanin": (LOWEST, MELANIN_MAX), "haemoglobin": (LOWEST, HAEMOGLOBIN_MAX)}
    y, x = np.mgrid[0:size, 0:size] / (size - 1)
    wave = 0.03 * np.sin(6.0 * np.pi * y) * np.sin(4.0 * np.pi * x)  # in the log, so smooth and inside the box

    def spread(name, t):
        low, high = np.log(max(LOWEST, box[name][0])), np.log(box[name][1])
        return np.exp(low + (high - low) * np.clip(t, 0.0, 1.0))

    melanin, haemoglobin = spread("melanin", x + wave), spread("haemoglobin", y - wave)
    shading = 0.5 + 0.25 * (x + (1.0 - y)) + 0.02 * np.sin(5.0 * x + 3.0 * y)
    return melanin, haemoglobin, np.clip(shading, 0.5, 1.0)


def colour_science_render(melanin, haemoglobin, shading, melanin_blend: float, model) -> np.ndarray:
    """Linear sRGB (h, w, 3): the model's spectra, colour-science's colour."""
    params = skinfit.SkinParams(melanin.ravel(), np.full(melanin.size, melanin_blend), haemoglobin.ravel())
    spectra = np.asarray(skinfit.diffuse_reflectance(params, RENDER_WAVELENGTHS_NM, model=model))
    return colour_science_linear_srgb(spectra, RENDER_WAVELENGTHS_NM).reshape(*melanin.shape, 3) * shading[..., None]


def colour_science_linear_srgb(spectra: np.ndarray, wavelengths_nm: np.ndarray) -> np.ndarray:
    """Linear sRGB (n, 3) of reflectance spectra (n, m) on an even grid, by colour-science alone
    (CIE 1931 2 degrees, D65, integration), not skinfit's colour code."""
    import colour

    shape = colour.SpectralShape(wavelengths_nm[0], wavelengths_nm[-1], float(wavelengths_nm[1] - wavelengths_nm[0]))
    msds = colour.MultiSpectralDistributions(np.asarray(spectra).T, wavelengths_nm)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    xyz = colour.msds_to_XYZ(msds, cmfs, colour.SDS_ILLUMINANTS["D65"].copy().align(shape), method="Integration") / 100.0
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    return colour.XYZ_to_RGB(xyz, srgb, illuminant=srgb.whitepoint, chromatic_adaptation_transform=None, apply_cctf_encoding=False)


def relative_errors(fit, truth: dict) -> dict:
    fitted = fit.status == skinfit.PixelStatus.SUCCESS
    out = {}
    for name in ("melanin", "haemoglobin"):
        value, se, true = getattr(fit, name)[fitted], getattr(fit, f"{name}_se")[fitted], truth[name][fitted]
        error = np.abs(value / true - 1.0)
        # where the colour sets the value (the standard error below it and below a quarter of the
        # box, as NOT_SKIN judges), and whether the standard errors cover the misses
        identified = se < np.minimum(0.25 * {"melanin": MELANIN_MAX, "haemoglobin": HAEMOGLOBIN_MAX}[name], value)
        covered = np.abs(value - true) <= 2.0 * se
        out[name] = {"median": float(np.median(error)), "p99": float(np.percentile(error, 99)),
                     "identified_fraction": float(np.mean(identified)),
                     "p99_where_identified": float(np.percentile(error[identified], 99)) if identified.any() else None,
                     "within_2se_fraction": float(np.mean(covered)),
                     "within_2se_of_misses_over_10pc": float(np.mean(covered[error > 0.1])) if np.any(error > 0.1) else None} if error.size else None
    shading = np.abs(fit.shading[fitted] / truth["shading"][fitted] - 1.0)
    out["shading"] = {"median": float(np.median(shading)), "p99": float(np.percentile(shading, 99))} if shading.size else None
    return out


def statuses(fit) -> dict:
    return {status.name: int(np.sum(fit.status == status)) for status in skinfit.PixelStatus if np.any(fit.status == status)}


def run_model(name: str, size: int) -> dict:
    model = MODELS[name]()
    blend = population_blend(model)
    box = skin_box(model)
    melanin, haemoglobin, shading = box_maps(size, box)
    truth = {"melanin": melanin, "haemoglobin": haemoglobin, "shading": shading}
    rgb = colour_science_render(melanin, haemoglobin, shading, blend, model)
    rows = {}
    for label, options in (("priors_off", {"prior": False}), ("default_priors", {})):
        fit = skinfit.fit_image(rgb, white_balance="none", melanin_blend=blend, model=model, segmentation="none", progress=False, **options)
        rows[label] = {"statuses": statuses(fit), "fitted_fraction": float(np.mean(fit.status == skinfit.PixelStatus.SUCCESS)),
                       "relative_error": relative_errors(fit, truth), "seconds": fit.seconds}
        bad = fit.status != skinfit.PixelStatus.SUCCESS
        if bad.any():  # where in the box the failures sit
            rows[label]["failed_melanin_range"] = [float(melanin[bad].min()), float(melanin[bad].max())]
            rows[label]["failed_haemoglobin_range"] = [float(haemoglobin[bad].min()), float(haemoglobin[bad].max())]
    return {"model": model.name, "melanin_blend": blend, "box": {k: [max(LOWEST, low), high] for k, (low, high) in box.items()}, **rows}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=160)
    parser.add_argument("--models", nargs="+", default=list(MODELS), choices=list(MODELS))
    parser.add_argument("--out", default="benchmarks/results")
    args = parser.parse_args(argv)
    result = {**provenance(), "image": f"{args.size}x{args.size} over each model's skin box, shading 0.5-1, colour by colour-science",
              "models": {name: run_model(name, args.size) for name in args.models}}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fit_image_box.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
