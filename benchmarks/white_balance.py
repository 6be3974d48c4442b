"""The automatic white balance of ``fit_image``: what it costs per image, and what it does to a rendering.

    python -m benchmarks.white_balance [--repeats 3] [--size 256] [--out benchmarks/results]

- Cost: on each real input of ``benchmarks.fit_photos`` (with its mask), ``fit_image`` with its
  defaults (``white_balance="auto"``: the gains searched from the skin pixels) against the same fit
  with those gains given, both compiled; the difference of the medians of ``--repeats`` calls is the
  search's time.
- A rendering of the model: the smooth maps of ``benchmarks.fit_image`` (melanin 0.2-40 %,
  haemoglobin 0.2-8 %, shading 0.5-1; ``--size`` pixels square) rendered through the calibrated
  model with no cast (true gains 1, 1, 1), at the blend ``fit_image`` assumes (the population prior's
  mean) and at ``render_maps``' default 0.7, then fitted with the defaults: the gains the search
  picks, and the fitted melanin's median against the truth's.

Writes ``benchmarks/results/white_balance.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import skinfit
from benchmarks._record import provenance
from benchmarks._timing import first_and_median
from benchmarks.fit_image import smooth_maps
from benchmarks.fit_photos import INPUTS, read_input
from skinfit import render_maps
from skinfit.fit import PixelStatus, fit_image

ROOT = Path(__file__).resolve().parents[1]


def search_cost(rgb, mask, repeats: int) -> dict:
    # each timing: a first (compiling) call, then the median of ``repeats``
    auto, _, with_search = first_and_median(lambda: fit_image(rgb, mask=mask, progress=False), repeats=repeats)
    gains = auto.white_balance
    _, _, given = first_and_median(lambda: fit_image(rgb, mask=mask, white_balance=gains, progress=False), repeats=repeats)
    skin = mask if mask is not None else auto.region == 1  # no mask given: the faces found
    return {"pixels": int(rgb.shape[0] * rgb.shape[1]), "mask_pixels": int(skin.sum()), "white_balance": list(gains),
            "white_balance_sd": auto.white_balance_sd,
            "melanin_blend": auto.summary()["melanin_blend"],
            "s_with_search": with_search, "s_gains_given": given, "search_s": with_search - given}


def rendering(size: int, blend: float) -> dict:
    melanin, haemoglobin, shading = smooth_maps(size)
    rgb = render_maps(melanin, haemoglobin, shading, model=skinfit.SkinModel.default(), melanin_blend=blend)
    fitted = {}
    for name, white_balance in (("auto", "auto"), ("none", "none")):
        fit = fit_image(rgb, white_balance=white_balance, melanin_blend=blend, segmentation="none", progress=False)
        ok = fit.status == PixelStatus.SUCCESS
        fitted[name] = {"white_balance": list(fit.white_balance), "success_fraction": float(ok.mean()),
                        "melanin_median": float(np.median(fit.melanin[ok])), "haemoglobin_median": float(np.median(fit.haemoglobin[ok]))}
    return {"size": size, "melanin_blend": blend, "true_melanin_median": float(np.median(melanin)),
            "true_haemoglobin_median": float(np.median(haemoglobin)), "fits": fitted}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    model = skinfit.SkinModel.default()
    costs = {}
    for name in INPUTS:
        loaded = read_input(name)
        if loaded is None:
            continue
        costs[name] = search_cost(*loaded, args.repeats)
        c = costs[name]
        print(f"{name}: search {c['search_s']:.2f} s ({c['s_with_search']:.2f} s with it, {c['s_gains_given']:.2f} s with the gains given), "
              f"gains {', '.join(f'{g:.2f}' for g in c['white_balance'])}", flush=True)
    # the blend fit_image assumes when none is given (the population prior's mean), as the fits above used
    population_blend = next(iter(costs.values()))["melanin_blend"]
    renderings = {}
    for label, blend in (("population_blend", population_blend), ("blend_0.7", 0.7)):
        renderings[label] = r = rendering(args.size, blend)
        auto, none = r["fits"]["auto"], r["fits"]["none"]
        print(f"rendering (blend {blend}): gains {', '.join(f'{g:.2f}' for g in auto['white_balance'])}; melanin median "
              f"{auto['melanin_median']:.4f} (auto) / {none['melanin_median']:.4f} (none) / {r['true_melanin_median']:.4f} (truth)", flush=True)
    search = [c["search_s"] for c in costs.values()]
    record = {
        **provenance(),
        "model": model.name,
        "repeats": args.repeats,
        "search_cost": costs,
        "search_s_median": float(np.median(search)) if search else None,
        "search_s_range": [float(min(search)), float(max(search))] if search else None,
        "rendering": renderings,
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "white_balance.json").write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
