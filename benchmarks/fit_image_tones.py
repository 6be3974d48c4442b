"""Image fits by skin tone: measured face spectra of each population group, rendered by colour-science
into albedo images, against the spectral fit of the same spectra.

Run: python -m benchmarks.fit_image_tones [--people 64] [--out benchmarks/results]

Needs ``../shared/data/issa-subset/`` (ISSA, d/8 with specular included; not shipped). Per group, up to
``--people`` subjects with a cheek spectrum (one each), less its specular part as the spectral fit
estimates it (an albedo capture sees none): each person an 8 x 8 patch of an image, under a
smooth shading 0.75-1 across the image; the colour is colour-science's (CIE 1931 2 degrees, D65, linear
sRGB), not skinfit's. Fitted by ``fit_image`` with the defaults but ``white_balance="none"`` (the render
is calibrated) and no segmentation (no faces in the image: each patch is given as a person of its
own through ``blend_regions``, so that each gets its own blend, as each face of a photo does), once
as a photo (``input_type="photo"``, the shading free per pixel) and once as an albedo capture
(``input_type="albedo"``, one shading scale for the image).
Reference: ``fit_spectra`` of the same spectra (default model, ``specular_included_deg=8``,
``bandwidth_nm=10``). Per person: the median of the patch's SUCCESS pixels, and its median standard
error. Reported per group: pixels fitted, the image melanin's relative error against the spectral
value (median bias, median and 90th percentile of its size), and the share of people whose spectral
value lies within two standard errors of the image value. Also per group: the model's colour
discrepancy on these skins (the relative linear sRGB difference between a measured spectrum and its
spectral fit, both by colour-science), against which ``skinfit.fit.MODEL_DISCREPANCY`` was set.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import skinfit
from benchmarks._record import provenance
from benchmarks.fit_image_box import colour_science_linear_srgb

ISSA = Path(__file__).resolve().parents[2] / "shared/data/issa-subset/issa_subset.csv"
WAVELENGTHS = np.arange(400.0, 701.0, 10.0)
MEASUREMENT = {"specular_included_deg": 8.0, "bandwidth_nm": 10.0}
PATCH = 8


def people(archive, group: str, limit: int) -> np.ndarray:
    """Cheek spectra (n, 31) of up to ``limit`` subjects of a group, one each, at WAVELENGTHS."""
    keep = np.isin(archive.wavelengths_nm, WAVELENGTHS)
    rows, seen = [], set()
    for i, record in enumerate(archive.records):
        if record["ethnic_group"] == group and record["body_site"] == "cheek" and record["subject"] not in seen \
                and np.all(np.isfinite(archive.reflectance[i, keep])):
            rows.append(i)
            seen.add(record["subject"])
        if len(rows) == limit:
            break
    return archive.reflectance[rows][:, keep]


def render_patches(spectra: np.ndarray):
    """Linear sRGB image of one 8 x 8 patch per spectrum under a smooth shading 0.75-1, and the
    (row, column) slice of each patch."""
    linear = colour_science_linear_srgb(spectra, WAVELENGTHS)
    side = int(np.ceil(np.sqrt(len(spectra))))
    image, mask = np.zeros((side * PATCH, side * PATCH, 3)), np.zeros((side * PATCH, side * PATCH), bool)
    y, x = np.mgrid[0 : side * PATCH, 0 : side * PATCH] / (side * PATCH - 1)
    shading = 0.75 + 0.25 * (0.5 * x + 0.5 * (1 - y))
    patches = []
    for k in range(len(spectra)):
        a, b = divmod(k, side)
        where = (slice(a * PATCH, (a + 1) * PATCH), slice(b * PATCH, (b + 1) * PATCH))
        image[where] = linear[k]
        mask[where] = True
        patches.append(where)
    return image * shading[..., None], mask, patches


def per_person(fit, patches):
    values, errors = [], []
    for where in patches:
        ok = fit.status[where] == skinfit.PixelStatus.SUCCESS
        values.append(np.median(fit.melanin[where][ok]) if ok.any() else np.nan)
        errors.append(np.median(fit.melanin_se[where][ok]) if ok.any() else np.nan)
    return np.array(values), np.array(errors)


def summarise(fit, mask, patches, spectral) -> dict:
    value, se = per_person(fit, patches)
    done = np.isfinite(value)
    relative = value[done] / spectral[done] - 1.0
    covered = np.abs(value[done] - spectral[done]) <= 2.0 * se[done]
    return {"pixels_fitted": float(np.mean(fit.status[mask] == skinfit.PixelStatus.SUCCESS)),
            "people_fitted": int(done.sum()),
            "melanin_bias_median": float(np.median(relative)), "melanin_error_median": float(np.median(np.abs(relative))),
            "melanin_error_p90": float(np.percentile(np.abs(relative), 90)),
            "spectral_within_2se": float(np.mean(covered)), "melanin_se_relative_median": float(np.median(se[done] / value[done])),
            "shading_median": float(np.median(fit.shading[fit.status == skinfit.PixelStatus.SUCCESS])),
            "shading_scale": fit.shading_scale}


def groups(archive) -> list[str]:
    """The population groups with cheek spectra."""
    return sorted({r["ethnic_group"] for r in archive.records if r["body_site"] == "cheek"})


def measure_group(archive, group: str, limit: int) -> dict:
    """One group's row: up to ``limit`` people fitted as spectra, rendered as albedo patches and
    fitted as a photo and as an albedo capture (see the module docstring)."""
    spectra = people(archive, group, limit)
    fitted = skinfit.fit_spectra(WAVELENGTHS, spectra, progress=False, **MEASUREMENT)
    spectral = np.asarray(fitted.parameters["melanin"])
    # an albedo capture sees no surface reflection: the measured (SCI) spectrum less the spectral
    # fit's own estimate of its specular part (the fitted SCI spectrum less its diffuse part;
    # ~0.03 in the blue, two thirds of a dark cheek's reflectance there)
    diffuse = np.asarray(skinfit.diffuse_reflectance(fitted.skin_params(), WAVELENGTHS))
    albedo = np.clip(spectra - (np.asarray(fitted.fitted) - diffuse), 0.0, None)
    image, mask, patches = render_patches(albedo)
    labels = np.zeros(mask.shape, np.int16)
    for k, where in enumerate(patches):
        labels[where] = k + 1
    measured, modelled = colour_science_linear_srgb(spectra, WAVELENGTHS), colour_science_linear_srgb(np.asarray(fitted.fitted), WAVELENGTHS)
    discrepancy = np.linalg.norm(measured - modelled, axis=-1) / np.linalg.norm(measured, axis=-1)
    blend = np.asarray(fitted.parameters["melanin_blend"])
    row = {"people": len(spectra), "spectral_melanin_median": float(np.median(spectral)),
           "spectral_blend_median": float(np.median(blend)),
           "spectral_blend_on_a_bound": float(np.mean((blend <= 1e-3) | (blend >= 1 - 1e-3))),
           "specular_part_at_450nm_median": float(np.median((np.asarray(fitted.fitted) - diffuse)[:, 5])),
           "model_colour_discrepancy_median": float(np.median(discrepancy)),
           "model_colour_discrepancy_p90": float(np.percentile(discrepancy, 90))}
    for input_type in ("photo", "albedo"):
        fit = skinfit.fit_image(image, mask=mask, white_balance="none", input_type=input_type, blend_regions=labels, progress=False)
        row[input_type] = summarise(fit, mask, patches, spectral)
        image_blend = np.array([b["melanin_blend"] for b in sorted(fit.blends, key=lambda b: b["label"])])
        row[input_type].update(seconds=fit.seconds, image_blend_median=float(np.median(image_blend)),
                               image_blend_sd_median=float(np.median([b["sd"] for b in fit.blends])),
                               dark_box_people=int(sum(b["dark_box"] for b in fit.blends)),
                               blend_abs_error_median=float(np.median(np.abs(image_blend - blend))) if len(image_blend) == len(blend) else None)
    return row


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--people", type=int, default=64)
    parser.add_argument("--out", default="benchmarks/results")
    args = parser.parse_args(argv)
    archive = skinfit.read_issa(ISSA)
    result = {**provenance(), "people_per_group": args.people, "groups": {}}
    for group in groups(archive):
        row = measure_group(archive, group, args.people)
        result["groups"][group] = row
        print(group, json.dumps(row))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fit_image_tones.json").write_text(json.dumps(result, indent=2) + "\n")
    (out / "fit_image_tones.md").write_text(table(result) + "\n")


def table(result: dict) -> str:
    """The docs' table: per group and input, pixels fitted, the melanin's bias and error against the
    spectral fit, and how often two standard errors hold the spectral value."""
    lines = [f"ISSA cheeks by group (`python -m benchmarks.fit_image_tones`, {result['date']}, {result['machine']}; "
             f"{result['people_per_group']} people per group at most, rendered as albedo by colour-science, white balance none, "
             "each person's blend estimated from their own patch); image melanin against the spectral fit's:", "",
             "| group | people | spectral C_m / blend (on a bound) | input | pixels fitted | bias (median) | error median / p90 | within 2 se | image blend (median sd) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for group, row in result["groups"].items():
        for kind in ("photo", "albedo"):
            r = row[kind]
            head = (f"{group} | {row['people']} | {row['spectral_melanin_median']:.3f} / {row['spectral_blend_median']:.2f} "
                    f"({100 * row['spectral_blend_on_a_bound']:.0f} %)") if kind == "photo" else " | | "
            lines.append(f"| {head} | {kind} | {100 * r['pixels_fitted']:.1f} % | {100 * r['melanin_bias_median']:+.1f} % | "
                         f"{100 * r['melanin_error_median']:.1f} % / {100 * r['melanin_error_p90']:.1f} % | {100 * r['spectral_within_2se']:.0f} % | "
                         f"{r['image_blend_median']:.2f} ({r['image_blend_sd_median']:.2f}) |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
