"""The albedo capture's head mask against an independent skin-colour rule: which pixels the fit calls skin.

    python -m benchmarks.capture_skin_rule [--out benchmarks/results]

The capture's mask (``../shared/data/face-albedo/face2_mask.png``) covers the head: hair, brows,
closed eyes, lips and some background as well as skin, so the share of the mask that ``fit_image``
marks ``SUCCESS`` (``benchmarks.fit_photos``) mixes both. This splits the mask with the YCbCr
skin-colour rule that made the demo's skin mask (``benchmarks.demo_skin_mask.skin_colour``, on the
8-bit sRGB values; no skin model, so not circular) and fits the capture as ``benchmarks.fit_photos``
does (``fit_image`` with its defaults). Writes ``benchmarks/results/capture_skin_rule.json``: the
share of the mask the rule passes, and the share of ``SUCCESS`` (and every status) among the pixels
it passes and among the rest.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from PIL import Image

import skinfit
from benchmarks._record import provenance
from benchmarks.demo_skin_mask import skin_colour
from benchmarks.fit_photos import INPUTS, read_input
from skinfit.fit import PixelStatus, fit_image

ROOT = Path(__file__).resolve().parents[1]
CAPTURE = "albedo capture (501x798, head mask)"


def statuses(status: np.ndarray) -> dict:
    return {s.name: int(np.sum(status == s)) for s in PixelStatus if np.any(status == s)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    loaded = read_input(CAPTURE)
    if loaded is None:
        return 1
    rgb, mask = loaded
    image = INPUTS[CAPTURE][0]
    rule = skin_colour(np.asarray(Image.open(image).convert("RGB")))
    start = time.perf_counter()
    fit = fit_image(rgb, mask=mask, progress=False)  # as benchmarks.fit_photos.measure
    seconds = time.perf_counter() - start
    success = fit.status == PixelStatus.SUCCESS
    passes, rest = mask & rule, mask & ~rule
    record = {
        **provenance(),
        "model": skinfit.SkinModel.default().name,
        "input": CAPTURE,
        "image": str(image.relative_to(ROOT.parent)),
        "rule": "YCbCr (ITU-R BT.601) Cr 135-180, Cb 85-135, luma > 80 of 255 on the 8-bit sRGB values (benchmarks.demo_skin_mask.skin_colour)",
        "fit": "fit_image defaults (as benchmarks.fit_photos)",
        "fit_s_incl_compile": seconds,
        "white_balance": list(fit.white_balance),
        "mask_pixels": int(mask.sum()),
        "rule_pixels_in_mask": int(passes.sum()),
        "mask_fraction_passing_rule": float(passes.sum() / mask.sum()),
        "success_fraction_passing_rule": float(success[passes].mean()),
        "success_fraction_rest_of_mask": float(success[rest].mean()),
        "success_fraction_mask": float(success[mask].mean()),
        "statuses_passing_rule": statuses(fit.status[passes]),
        "statuses_rest_of_mask": statuses(fit.status[rest]),
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "capture_skin_rule.json").write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    print(f"{CAPTURE}: {100 * record['mask_fraction_passing_rule']:.1f} % of the mask passes the rule; SUCCESS "
          f"{100 * record['success_fraction_passing_rule']:.1f} % of those, {100 * record['success_fraction_rest_of_mask']:.1f} % of the rest "
          f"(whole mask {100 * record['success_fraction_mask']:.1f} %); fit {seconds:.1f} s with compilation")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
