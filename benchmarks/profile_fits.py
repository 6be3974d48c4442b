"""Renderer-profile fits: how well six Gaussians and Christensen-Burley follow the model's profiles.

Run: python -m benchmarks.profile_fits [--out benchmarks/results]

For the light, medium and dark presets (default model, 400-700 nm every 10 nm, linear sRGB under
D65), ``skinfit.renderer_profiles`` per RGB channel:

* the sum-of-six-Gaussians and Christensen-Burley fits' errors as fractions of the channel's
  energy: the largest misplaced energy max_r |E_fit(r) - E(r)| (``energy_error``) and the L1
  density error int 2 pi r |R - fit| dr (``density_l1_error``), as the export reports them, and
  both recomputed here from the model profile and the fitted forms on an independent, finer
  radius grid (``check``);
* the negative energy of the linear-sRGB profile (-int 2 pi r min(R, 0) dr, a fraction of the
  channel's energy) and the overshoot of its cumulative energy (max_r E(r) / R_d - 1): a
  non-negative sum of Gaussians holding the exact energy cannot misplace less than the overshoot;
* the scale applied to each row of the energy-bounded tables (RGB and spectral);
* the ratio of the largest to the smallest extinction coefficient of the per-channel medium.

It also summarises shipped measurements that the page quotes: the Blender Cycles drift curves
(``spectra/blender_cycles_<method>.json``, measured by ``benchmarks/measure_blender_drift.py``;
their date, Blender version and commit are copied): rendered albedo over base colour, and the
median energy radius Cycles renders per unit Subsurface Radius.

Writes benchmarks/results/profile_fits.json (values, date, machine, git commit) and
benchmarks/results/profile_fits.md, the table of docs/renderers.md (``profile-fits`` block).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import skinfit
from benchmarks._record import provenance
from skinfit import export
from skinfit.colorimetry import linear_srgb_weights
from skinfit.model import profile

ROOT = Path(__file__).resolve().parents[1]
PRESETS = ("light", "medium", "dark")
WAVELENGTHS_NM = np.arange(400.0, 701.0, 10.0)
CHANNELS = ("red", "green", "blue")
BLENDER_METHODS = ("RANDOM_WALK", "RANDOM_WALK_SKIN")  # the Cycles methods with a shipped drift curve


def _energy_weights(radii: np.ndarray) -> np.ndarray:
    """Weights of int 2 pi r f(r) dr on log-spaced radii (trapezoid in ln r)."""
    d = np.diff(np.log(radii))
    w = np.zeros_like(radii)
    w[:-1] += 0.5 * d
    w[1:] += 0.5 * d
    return 2 * np.pi * radii**2 * w


def _cumulative(radii: np.ndarray, f: np.ndarray) -> np.ndarray:
    """int_0^r 2 pi r' f(r') dr' (trapezoid in ln r, the part below the first radius as 2 pi r0^2 f(r0))."""
    g = 2 * np.pi * radii**2 * f
    return g[0] + np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * np.diff(np.log(radii)))])


def _gaussian_cumulative(radii, variances, weights):
    return (1.0 - np.exp(-radii[:, None] ** 2 / (2 * np.asarray(variances)))) @ np.asarray(weights)


def _burley_cumulative(radii, albedo, d):
    return albedo * (1.0 - 0.25 * np.exp(-radii / d) - 0.75 * np.exp(-radii / (3 * d)))


def preset_fits(name: str) -> dict:
    params = skinfit.preset(name)
    result = skinfit.renderer_profiles(params, WAVELENGTHS_NM)
    # independent check: the model profile on a finer grid over the fits' range (up to twice the table radius)
    radii = np.geomspace(1e-5, 2 * result.max_radius_mm, 8000)
    rgb = linear_srgb_weights(WAVELENGTHS_NM) @ np.asarray(profile(params, WAVELENGTHS_NM, radii, entry_fresnel=True))
    w = _energy_weights(radii)
    channels = {}
    for i, c in enumerate(CHANNELS):
        albedo = float(result.rgb_albedo[i])
        target, energy = rgb[i], _cumulative(radii, rgb[i])
        g, b = result.gaussians[c], result.burley[c]
        g_fit = export.gaussian_sum(radii, g["variances_mm2"], g["weights"])
        b_fit = export.burley_profile(radii, albedo, b["shape_mm"])
        channels[c] = {
            "albedo": albedo,
            "gaussians": {"energy_error": g["energy_error"], "density_l1_error": g["density_l1_error"],
                          "check": {"energy_error": float(np.max(np.abs(_gaussian_cumulative(radii, g["variances_mm2"], g["weights"]) - energy)) / albedo),
                                    "density_l1_error": float(np.sum(w * np.abs(target - g_fit)) / albedo)}},
            "burley": {"shape_mm": b["shape_mm"], "energy_error": b["energy_error"], "density_l1_error": b["density_l1_error"],
                       "check": {"energy_error": float(np.max(np.abs(_burley_cumulative(radii, albedo, b["shape_mm"]) - energy)) / albedo),
                                 "density_l1_error": float(np.sum(w * np.abs(target - b_fit)) / albedo)}},
            "negative_energy": float(-np.sum(w * np.minimum(target, 0.0)) / albedo),
            "energy_overshoot": float(max(energy.max() / albedo - 1.0, 0.0)),
        }
    extinction = np.asarray(result.medium.extinction_per_mm)
    return {
        "params": {f: float(getattr(params, f)) for f in ("melanin", "melanin_blend", "haemoglobin")},
        "model_description": result.metadata["model"],
        "max_radius_mm": result.max_radius_mm,
        "channels": channels,
        "row_scale": {"rgb": result.metadata["rgb_scale"], "spectral": result.metadata["spectral_scale"],
                      "rgb_max_deviation": float(np.max(np.abs(np.asarray(result.metadata["rgb_scale"]) - 1.0))),
                      "spectral_max_deviation": float(np.max(np.abs(np.asarray(result.metadata["spectral_scale"]) - 1.0)))},
        "medium_extinction_per_mm": extinction.tolist(),
        "medium_extinction_ratio": float(extinction.max() / extinction.min()),
    }


def blender_summary(method: str) -> dict:
    drift = export.blender_drift(method)
    ratio = np.asarray(drift["rendered_albedo"]) / np.asarray(drift["base_colour"])
    k = np.asarray(drift["radial"]["median_over_radius"])
    return {key: drift[key] for key in ("date", "machine", "git_commit", "blender", "method", "spp")} | {
        "rendered_over_base_colour": {"min": float(ratio.min()), "max": float(ratio.max()),
                                      "base_colour_range": [min(drift["base_colour"]), max(drift["base_colour"])]},
        "median_radius_over_subsurface_radius": {"min": float(k.min()), "max": float(k.max()),
                                                 "base_colour_range": [min(drift["radial"]["base_colour"]), max(drift["radial"]["base_colour"])]},
    }


def table(record: dict) -> str:
    def pct(x, decimals):
        return f"{100 * x:.{decimals}f}"

    lines = [f"Fit errors (`python -m benchmarks.profile_fits`, {record['date']}, {record['machine']}; default model "
             f"{record['model']}, 400-700 nm every 10 nm, linear sRGB under D65): largest misplaced energy, L1 density "
             f"error in brackets, as percentages of the channel's energy (**bold**: above 1 %):",
             "",
             "| preset | channel | 6 Gaussians | Burley |",
             "|---|---|---|---|"]
    for name in PRESETS:
        ch = record["presets"][name]["channels"]
        gauss, burley = [], []
        for c in CHANNELS:
            e = pct(ch[c]["gaussians"]["energy_error"], 2)
            gauss.append(f"{'**' + e + '**' if ch[c]['gaussians']['energy_error'] > 0.01 else e} ({pct(ch[c]['gaussians']['density_l1_error'], 1)})")
            burley.append(f"{pct(ch[c]['burley']['energy_error'], 1)} ({pct(ch[c]['burley']['density_l1_error'], 0)})")
        lines.append(f"| {name} | R / G / B | {' / '.join(gauss)} % | {' / '.join(burley)} % |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    presets = {}
    for name in PRESETS:
        presets[name] = preset_fits(name)
        print(name, json.dumps({c: [round(100 * v[k]["energy_error"], 3) for k in ("gaussians", "burley")]
                                for c, v in presets[name]["channels"].items()}), flush=True)
    record = {**provenance(), "model": skinfit.SkinModel.default().name, "model_description": presets[PRESETS[0]]["model_description"],
              "wavelengths_nm": WAVELENGTHS_NM.tolist(),
              "illuminant": "D65", "presets": presets,
              "rgb_row_scale_max_deviation": max(p["row_scale"]["rgb_max_deviation"] for p in presets.values()),
              "spectral_row_scale_max_deviation": max(p["row_scale"]["spectral_max_deviation"] for p in presets.values()),
              "medium_extinction_ratio_max": max(p["medium_extinction_ratio"] for p in presets.values()),
              "blender_drift": {m: blender_summary(m) for m in BLENDER_METHODS}}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "profile_fits.json").write_text(json.dumps(record, indent=1), encoding="utf-8")
    text = table(record)
    (out / "profile_fits.md").write_text(text, encoding="utf-8")
    print(text)
    print(f"wrote {out / 'profile_fits.json'} and {out / 'profile_fits.md'}")


if __name__ == "__main__":
    main()
