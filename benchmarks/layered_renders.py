"""The two-layer Mitsuba export (``--format mitsuba-layered``) rendered in Mitsuba 3 and checked.

Run: python -m benchmarks.layered_renders [--random 20] [--quick]

For the default model, the three presets and ``--random`` parameter sets (those of
``benchmarks.renderers``: seed 2026), per linear-sRGB channel:

- **albedo**: Mitsuba's render of the layered export (``render_layered_albedo``) against the model's
  transport reflectance (its target), relative difference with the render's standard error;
- **radial energy** at 0.1 / 0.5 / 1 / 2 mm as a fraction of the channel's albedo: Mitsuba's render
  (``render_layered_energy_within``) against skinfit's Monte Carlo of the same two-layer stack
  (``LayeredMedium.monte_carlo_energy_within``), in points; beside them the model's own profile
  (multipole, ``captured_reflectance``), which is what the single-medium export was matched to.
- the **spectral** layered export of the ``medium`` preset at six wavelengths: albedo against the
  model's transport reflectance.

Writes benchmarks/results/layered_renders.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import skinfit
from benchmarks._record import provenance
from benchmarks.renderers import RADII_MM, SPECTRAL_CHECK_NM, parameter_sets
from skinfit import export
from skinfit.colorimetry import linear_srgb_weights

ROOT = Path(__file__).resolve().parents[1]


def rgb_row(params, spp: int, photons: int, seed: int = 0) -> dict:
    radii = np.array(RADII_MM)
    layered = export.layered_medium(params)
    # a dark channel's render error is absolute (the specular choice, the few paths that return):
    # more samples where the darkest channel is below 0.06 (up to 8x)
    spp = int(spp * np.clip(0.06 / float(np.min(layered.albedo)), 1.0, 8.0))
    rendered, rendered_error = export.render_layered_albedo(layered, spp=spp, seed=seed)
    within, within_error = export.render_layered_energy_within(layered, radii, spp=spp, seed=seed)
    mc, mc_error = layered.monte_carlo_energy_within(radii, photons=photons, seed=10 * seed)
    lam = np.arange(400.0, 701.0, 10.0)
    captured = np.stack([np.asarray(skinfit.model.captured_reflectance(params, lam, r)) for r in radii])
    model_fraction = (captured @ linear_srgb_weights(lam).T) / (linear_srgb_weights(lam) @ np.asarray(skinfit.diffuse_reflectance(params, lam)))
    albedo = layered.albedo
    return {
        "parameters": layered.metadata["parameters"], "samples_per_pixel": spp,
        "albedo_model": albedo.tolist(), "albedo_mitsuba": rendered.tolist(), "albedo_mitsuba_error": rendered_error.tolist(),
        "albedo_relative_difference": (rendered / albedo - 1).tolist(),
        "absorption_factor": layered.absorption_factor.tolist(),
        "radii_mm": radii.tolist(),
        "fraction_mitsuba": (within / albedo).tolist(), "fraction_mitsuba_error": (within_error / albedo).tolist(),
        "fraction_monte_carlo": (mc / albedo).tolist(), "fraction_monte_carlo_error": (mc_error / albedo).tolist(),
        "fraction_model_profile": model_fraction.tolist(),
        "radial_difference_points": (100 * (within - mc) / albedo).tolist(),
    }


def spectral_row(params, spp: int, seed: int = 0) -> dict:
    layered = export.layered_medium(params, np.array(SPECTRAL_CHECK_NM), spectral=True)
    rendered, error = export.render_layered_albedo(layered, spp=spp, seed=seed)
    return {"wavelengths_nm": list(SPECTRAL_CHECK_NM), "albedo_model": layered.albedo.tolist(), "albedo_mitsuba": rendered.tolist(),
            "albedo_mitsuba_error": error.tolist(), "albedo_relative_difference": (rendered / layered.albedo - 1).tolist()}


def _z(row) -> tuple[np.ndarray, np.ndarray]:
    """The differences in standard errors, albedo (render) and radial (render and Monte Carlo): |z|
    above 3 is a bias, not noise."""
    albedo = (np.array(row["albedo_mitsuba"]) - np.array(row["albedo_model"])) / np.array(row["albedo_mitsuba_error"])
    radial = ((np.array(row["fraction_mitsuba"]) - np.array(row["fraction_monte_carlo"]))
              / np.hypot(row["fraction_mitsuba_error"], row["fraction_monte_carlo_error"]))
    return albedo, radial


def markdown(record) -> str:
    rows = record["rgb"]
    lines = [f"Layered Mitsuba export, {record['date']}, {record['machine']}, "
             f"commit {record['git_commit'][:12]}; {record['settings']}",
             "", "| set | albedo R / G / B, model | Mitsuba / model - 1 (%) | largest radial difference, Mitsuba - Monte Carlo (points) "
             "| largest \\|z\\| (albedo, radial) |",
             "|---|---|---|---|---|"]
    for name, row in rows.items():
        rel = " / ".join(f"{100 * v:+.2f}" for v in row["albedo_relative_difference"])
        z = f"{np.max(np.abs(_z(row)[0])):.1f}, {np.max(np.abs(_z(row)[1])):.1f}"
        lines.append(f"| {name} | {' / '.join(f'{v:.4f}' for v in row['albedo_model'])} | {rel} | "
                     f"{np.max(np.abs(row['radial_difference_points'])):.2f} | {z} |")
    worst_albedo = max(np.max(np.abs(r["albedo_relative_difference"])) for r in rows.values())
    worst_radial = max(np.max(np.abs(r["radial_difference_points"])) for r in rows.values())
    lines += ["", f"Largest |albedo difference| {100 * worst_albedo:.2f} %; largest |radial difference| {worst_radial:.2f} points "
              f"over {len(rows)} sets and {len(RADII_MM)} radii."]
    light = rows.get("light")
    if light:
        lines += ["", "Light preset, fraction of each channel's energy within 0.1 / 0.5 / 1 / 2 mm (R, G, B):", "",
                  "| radius (mm) | model profile (multipole) | layered export in Mitsuba | Monte Carlo of the stack |", "|---|---|---|---|"]
        for k, r in enumerate(light["radii_mm"]):
            cell = lambda key: " / ".join(f"{v:.3f}" for v in light[key][k])  # noqa: E731
            lines.append(f"| {r:g} | {cell('fraction_model_profile')} | {cell('fraction_mitsuba')} | {cell('fraction_monte_carlo')} |")
    spectral = record.get("spectral")
    if spectral:
        lines += ["", "Spectral layered export, medium preset: Mitsuba / model - 1 (%) at "
                  + ", ".join(f"{w:g}" for w in spectral["wavelengths_nm"]) + " nm: "
                  + ", ".join(f"{100 * v:+.2f}" for v in spectral["albedo_relative_difference"])]
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--random", type=int, default=20)
    parser.add_argument("--quick", action="store_true", help="presets only, fewer samples")
    parser.add_argument("--seed", type=int, default=0, help="renders' and Monte Carlo's seeds (another seed: independent samples)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    sets = parameter_sets(0 if args.quick else args.random)
    spp, photons = (1024, 50_000) if args.quick else (4096, 200_000)
    record = {**provenance(), "settings": f"{spp} samples per pixel (16 pixels; up to 8x for dark channels), "
                                                      f"{photons} Monte Carlo photons per channel, seed {args.seed}",
              "rgb": {}}
    started = time.perf_counter()
    args.out.mkdir(parents=True, exist_ok=True)
    partial = args.out / "layered_renders.json.partial"  # each finished set kept if a long run stops
    for name, params in sets.items():
        row = rgb_row(params, spp, photons, args.seed)
        record["rgb"][name] = row
        partial.write_text(json.dumps(record, indent=1), encoding="utf-8")
        print(f"{name}: albedo {np.round(100 * np.array(row['albedo_relative_difference']), 2)} %, radial "
              f"{np.round(np.max(np.abs(row['radial_difference_points'])), 2)} points ({time.perf_counter() - started:.0f} s)", flush=True)
    record["spectral"] = spectral_row(skinfit.preset("medium"), spp, args.seed)
    record["seconds"] = time.perf_counter() - started
    (args.out / "layered_renders.json").write_text(json.dumps(record, indent=1), encoding="utf-8")
    partial.unlink(missing_ok=True)
    (args.out / "layered_renders.md").write_text(markdown(record), encoding="utf-8")
    print(markdown(record))
    return record


if __name__ == "__main__":
    main()
