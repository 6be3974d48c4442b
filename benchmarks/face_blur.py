"""What a renderer's subsurface blur does to a fitted face, and what the deconvolved albedo gives back.

Run: python -m benchmarks.face_blur [--mm-per-pixel MM] [--out benchmarks/results]

Writes face_blur.json, face_blur.md and a figure, face_blur.png (capture, plain export and
recommended route as a renderer blurs them, and their CIEDE2000 maps against the capture).

Input: the real cross-polarised albedo capture in ``../shared/data/face-albedo/`` (501 x 798, its
head mask), fitted with ``fit_image``'s defaults. Its pixel size is not documented: by default
the mask's widest row above its middle (the head with its ears; below are the shoulders) is taken as
170 mm (stated in the results; the closed eyes' centres, about 165 pixels apart, give 0.38 mm per
pixel for a 63 mm interpupillary distance, close to it). Per channel, the
renderer's blur is the model's radial profile at the skin's median parameters on that pixel grid
(``skinfit.export.profile_kernel``), light entering uniformly over a texel.

Compared with the capture over the skin (``SUCCESS`` pixels of the face's skin region, more than
a kernel radius inside the mask), CIEDE2000 median and 95th percentile:

- the fit itself (its reconstruction, no blur): what the maps hold;
- the plain export as a renderer gives it under uniform light: the fit's albedo blurred once more;
- the recommended route: the capture deconvolved (``deconvolve_albedo``), fitted again with the
  same defaults, and blurred by the renderer.

The blur here is the model's profile, not a render: ``render_textures`` (Mitsuba 3) renders the
texture export itself, at about 3 ms per path on this 2-core CPU, which the per-pixel comparison
of a whole face (about 10^4 samples a pixel for ΔE below 1) does not fit.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import skinfit
from benchmarks._record import provenance
from skinfit.colorimetry import delta_e2000, linear_srgb_to_lab
from skinfit.export import blur_albedo, deconvolve_albedo, profile_kernel
from skinfit.fit import PixelStatus, fit_image
from skinfit.io import read_linear_rgb, read_mask
from skinfit.segmentation import FaceRegion

ROOT = Path(__file__).resolve().parents[1]
CAPTURE = ROOT.parent / "shared" / "data" / "face-albedo" / "face2_albedo.png"
MASK = ROOT.parent / "shared" / "data" / "face-albedo" / "face2_mask.png"
HEAD_WIDTH_MM = 170.0  # an adult head across its ears, about 16-18 cm: the assumed scale of the capture


def _erode(mask: np.ndarray, radius: int) -> np.ndarray:
    out = np.asarray(mask, dtype=bool).copy()
    for _ in range(radius):
        shrunk = out.copy()
        shrunk[1:] &= out[:-1]
        shrunk[:-1] &= out[1:]
        shrunk[:, 1:] &= out[:, :-1]
        shrunk[:, :-1] &= out[:, 1:]
        out = shrunk
    return out


def _delta_e_map(a: np.ndarray, b: np.ndarray, where: np.ndarray, gains) -> np.ndarray:
    """CIEDE2000 (h, w) between two linear-RGB images in the capture's units (gains divided out), NaN off ``where``."""
    lab = lambda rgb: np.asarray(linear_srgb_to_lab(np.maximum(rgb[where] / np.asarray(gains), 0.0)))  # noqa: E731
    out = np.full(where.shape, np.nan)
    out[where] = np.asarray(delta_e2000(lab(a), lab(b)))
    return out


def _delta_e(a: np.ndarray, b: np.ndarray, where: np.ndarray, gains) -> dict:
    d = _delta_e_map(a, b, where, gains)[where]
    return {"median": float(np.median(d)), "p95": float(np.percentile(d, 95)), "pixels": int(d.size)}


def figure(path: Path, capture, plain, recommended, where, gains) -> None:
    """Capture, plain export blurred, recommended route blurred (sRGB), and the CIEDE2000 maps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skinfit.colorimetry import srgb_encode

    fig, axes = plt.subplots(2, 3, figsize=(12, 10))
    images = [("capture", capture), ("plain export, blurred by the renderer", plain), ("deconvolved, refitted, blurred", recommended)]
    # the skin compared, the rest of each image the capture's
    for ax, (title, image) in zip(axes[0], images):
        shown = np.where(where[..., None], image, capture)  # off the compared skin: the capture
        ax.imshow(np.clip(np.asarray(srgb_encode(np.clip(shown / np.asarray(gains), 0, 1))), 0, 1))
        ax.set_title(title)
    axes[1, 0].imshow(where, cmap="gray")
    axes[1, 0].set_title("skin pixels compared")
    for ax, (title, image) in zip(axes[1, 1:], images[1:]):
        colours = plt.get_cmap("magma").copy()
        colours.set_bad("0.6")  # not compared: grey
        shown = ax.imshow(_delta_e_map(image, capture, where, gains), vmin=0, vmax=3, cmap=colours)
        ax.set_title("CIEDE2000 against the capture")
    fig.colorbar(shown, ax=axes[1, 1:], shrink=0.7)
    for ax in axes.ravel():
        ax.axis("off")
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mm-per-pixel", type=float, default=None, help="default: the head's widest row is 170 mm")
    parser.add_argument("--regularisation", type=float, default=1e-3)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    capture, _ = read_linear_rgb(CAPTURE)
    mask = np.asarray(read_mask(MASK)) > 0
    widest = int(mask[: mask.shape[0] // 2].sum(axis=1).max())
    mm_per_pixel = args.mm_per_pixel or HEAD_WIDTH_MM / widest
    started = time.perf_counter()
    fit = fit_image(capture, mask=mask)
    skin = fit.status == PixelStatus.SUCCESS
    if fit.region is not None:
        skin &= fit.region == FaceRegion.SKIN
    medians = {name: float(np.median(getattr(fit, name)[skin])) for name in ("melanin", "melanin_blend", "haemoglobin")}
    kernel = profile_kernel(skinfit.SkinParams(**medians), mm_per_pixel)
    radius = kernel.shape[0] // 2
    inner = skin & _erode(mask, radius)
    gains = fit.white_balance
    plain = blur_albedo(fit.fitted_linear_rgb, kernel, mask=skin)
    deconvolved = deconvolve_albedo(capture, kernel, mask=skin, regularisation=args.regularisation)
    refit = fit_image(deconvolved, mask=mask)
    recommended = blur_albedo(refit.fitted_linear_rgb, kernel, mask=skin)
    centre = kernel[radius, radius]
    record = {
        **provenance(),
        "model": skinfit.SkinModel.default().name,
        "capture": f"{CAPTURE.name} ({capture.shape[1]}x{capture.shape[0]}), mask {MASK.name}",
        "mm_per_pixel": mm_per_pixel,
        "pixel_size_from": "given" if args.mm_per_pixel else f"the head's widest row ({widest} px, with the ears) as {HEAD_WIDTH_MM:g} mm",
        "median_params": medians,
        "kernel_radius_pixels": radius,
        "kernel_centre_share_rgb": centre.tolist(),
        "regularisation": args.regularisation,
        "skin_pixels_compared": int(inner.sum()),
        "fit_vs_capture": _delta_e(fit.fitted_linear_rgb, capture, inner, gains),
        "plain_export_blurred_vs_capture": _delta_e(plain, capture, inner, gains),
        "deconvolved_refit_blurred_vs_capture": _delta_e(recommended, capture, inner, gains),
        "deconvolved_refit_vs_deconvolved": _delta_e(refit.fitted_linear_rgb, deconvolved, inner & (refit.status == PixelStatus.SUCCESS), refit.white_balance),
        "melanin_median": {"fit": medians["melanin"], "deconvolved_refit": float(np.median(refit.melanin[inner]))},
        "haemoglobin_median": {"fit": medians["haemoglobin"], "deconvolved_refit": float(np.median(refit.haemoglobin[inner]))},
        "seconds": time.perf_counter() - started,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "face_blur.json").write_text(json.dumps(record, indent=1), encoding="utf-8")
    (args.out / "face_blur.md").write_text(markdown(record), encoding="utf-8")
    figure(args.out / "face_blur.png", capture, plain, recommended, inner, gains)
    print(markdown(record))
    return record


def markdown(record: dict) -> str:
    rows = [("the fit's reconstruction (no renderer blur)", "fit_vs_capture"),
            ("plain export, blurred by the renderer", "plain_export_blurred_vs_capture"),
            ("deconvolved capture refitted, blurred by the renderer", "deconvolved_refit_blurred_vs_capture")]
    share = " / ".join(f"{v:.2f}" for v in record["kernel_centre_share_rgb"])
    lines = [f"Fitted face against its capture (`python -m benchmarks.face_blur`, {record['date']}, {record['machine']}): "
             f"{record['capture']}, {record['mm_per_pixel']:.3f} mm per pixel ({record['pixel_size_from']}); "
             f"the renderer's blur keeps {share} of a texel's light in the texel (R / G / B), kernel radius "
             f"{record['kernel_radius_pixels']} pixels; {record['skin_pixels_compared']} skin pixels.", "",
             "| compared with the capture | CIEDE2000 median | p95 |", "|---|---|---|"]
    lines += [f"| {name} | {record[key]['median']:.3f} | {record[key]['p95']:.2f} |" for name, key in rows]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
