"""Renderer exports rendered in real renderers: Mitsuba 3 (always) and Blender Cycles (if given).

Run: python -m benchmarks.renderers [--blender-python PYTHON_WITH_BPY] [--random 20] [--quick]

For the calibrated default model and DJ2006, the three presets and ``--random`` parameter sets
(C_m log-uniform 0.002-0.5, beta_m uniform, C_h log-uniform 0.002-0.2, seed 2026):

- **Mitsuba 3** (``scalar_rgb``, ``volpathmis``, the reference slab of ``skinfit.export``): the
  exported per-channel medium (exact transport) against the model's linear-sRGB albedo, with the
  render's standard error; beside it, in the same run, the medium matched through diffusion
  theory (the classical dipole of a semi-infinite medium, which earlier exports used), which a
  path tracer renders too dark.
- **Mitsuba 3 spectral** (``scalar_spectral``): the ``medium`` preset's per-wavelength medium at six
  wavelengths against the model's reflectance.
- **Radial check** (default model, presets): the energy within 0.1, 0.5, 1 and 2 mm of a narrow
  beam as a fraction of the whole, for the model's profile, for Mitsuba's render of the export
  (reciprocity through a screen) and for skinfit's Monte Carlo of the exported medium.
- **Blender Cycles** (``--blender-python``, ``benchmarks/blender_cycles.py``): the Principled BSDF
  export (base colour compensated for the measured drift, ``RANDOM_WALK``) against the target, and
  the uncompensated base colour = target albedo.

Writes benchmarks/results/renderers.{json,md} (the table in docs/renderers.md is the .md).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import skinfit
from benchmarks._record import provenance
from skinfit import export
from skinfit.colorimetry import delta_e2000, linear_srgb_to_lab, linear_srgb_weights
from skinfit.model import dipole_energy, monte_carlo_reflectance

ROOT = Path(__file__).resolve().parents[1]
RADII_MM = (0.1, 0.5, 1.0, 2.0)
SPECTRAL_CHECK_NM = (420.0, 480.0, 540.0, 580.0, 620.0, 680.0)


def parameter_sets(n: int) -> dict:
    rng = np.random.default_rng(2026)
    sets = {name: skinfit.preset(name) for name in skinfit.PRESET_NAMES}
    for k in range(n):
        sets[f"random {k:02d}"] = skinfit.SkinParams(float(np.exp(rng.uniform(np.log(0.002), np.log(0.5)))), float(rng.uniform(0, 1)),
                                                     float(np.exp(rng.uniform(np.log(0.002), np.log(0.2)))))
    return sets


def diffusion_matched_albedo(albedo: np.ndarray, ior: float = 1.4) -> np.ndarray:
    """Single-scattering albedo (g = 0) of the semi-infinite medium whose classical dipole
    reflectance (entry Fresnel included) is ``albedo``: how the media were matched before."""
    grid = 1.0 - np.geomspace(1e-7, 1.0, 6000)[::-1][:-1]
    entry = 1.0 - ((ior - 1) / (ior + 1)) ** 2
    reflect = entry * np.asarray(dipole_energy(1.0 - grid, grid, ior, np.inf))
    return np.interp(albedo, reflect, grid)


def _render(material, spp):
    start = time.perf_counter()
    rendered, error = export.render_albedo(material, spp=spp)
    return rendered, error, time.perf_counter() - start


def _delta_e(a, b) -> float:
    return float(delta_e2000(linear_srgb_to_lab(np.asarray(a)), linear_srgb_to_lab(np.asarray(b))))


def mitsuba_rgb(sets: dict, model, spp_presets: int, spp_random: int) -> dict:
    out = {}
    for name, params in sets.items():
        start = time.perf_counter()
        result = export.renderer_profiles(params, model=model)
        export_s = time.perf_counter() - start
        spp = spp_presets if name in skinfit.PRESET_NAMES else spp_random
        rendered, error, render_s = _render(export.mitsuba_material(export.mitsuba_medium(result.medium), 1.4), spp)
        old = result.medium.__class__(result.medium.conventions, result.rgb_albedo, result.medium.median_radius_mm,
                                      diffusion_matched_albedo(result.rgb_albedo), result.medium.extinction_per_mm)
        old_rendered, old_error, _ = _render(export.mitsuba_material(export.mitsuba_medium(old), 1.4), spp)
        out[name] = {
            "params": {f: float(getattr(params, f)) for f in ("melanin", "melanin_blend", "haemoglobin")},
            "target": result.rgb_albedo.tolist(), "rendered": rendered.tolist(), "error": error.tolist(),
            "ratio": (rendered / result.rgb_albedo).tolist(), "dE2000": _delta_e(rendered, result.rgb_albedo),
            "diffusion_matched_ratio": (old_rendered / result.rgb_albedo).tolist(),
            "diffusion_matched_dE2000": _delta_e(old_rendered, result.rgb_albedo),
            "spp": spp, "export_s": round(export_s, 2), "render_s": round(render_s, 2),
        }
        print(f"  {name}: ratio {np.round(out[name]['ratio'], 4)} ± {np.round(error / result.rgb_albedo, 4)}, dE {out[name]['dE2000']:.3f}; "
              f"diffusion-matched {np.round(out[name]['diffusion_matched_ratio'], 3)}", flush=True)
    return out


def mitsuba_spectral(model, spp: int) -> dict:
    wavelengths = np.arange(360.0, 831.0, 10.0)
    result = export.renderer_profiles(skinfit.preset("medium"), wavelengths, model=model)
    material = export.mitsuba_material(export.mitsuba_spectral_medium(wavelengths, result.spectral_medium), 1.4)
    checked = np.array(SPECTRAL_CHECK_NM)
    rendered, error = export.render_spectral_albedo(material, checked, spp=spp)
    target = np.interp(checked, wavelengths, result.reflectance)
    return {"wavelengths_nm": checked.tolist(), "target": target.tolist(), "rendered": rendered.tolist(), "error": error.tolist(),
            "ratio": (rendered / target).tolist(), "spp": spp}


def radial(model, spp: int, photons: int) -> dict:
    out = {}
    radii = np.array(RADII_MM)
    for name in skinfit.PRESET_NAMES:
        result = export.renderer_profiles(skinfit.preset(name), model=model)
        lam = result.wavelengths_nm
        captured = np.stack([np.asarray(skinfit.model.captured_reflectance(skinfit.preset(name), lam, r, model=model)) for r in radii])
        model_fraction = (captured @ linear_srgb_weights(lam).T) / result.rgb_albedo
        material = export.mitsuba_material(export.mitsuba_medium(result.medium), 1.4)
        total, total_error = export.render_albedo(material, spp=spp)
        within, within_error = export.render_energy_within(material, radii, spp=spp)
        m = result.medium
        mc = []
        for i in range(3):
            layer = skinfit.model.Layer(absorption=float(m.absorption_per_mm[i]), reduced_scattering=float(m.reduced_scattering_per_mm[i]),
                                  thickness=float("inf"), ior=1.4)
            run = monte_carlo_reflectance([layer], photons=photons, seed=i, radii_mm=radii)
            mc.append(run.reflectance_within / run.reflectance)
        out[name] = {"radii_mm": radii.tolist(), "model": model_fraction.tolist(), "mitsuba": (within / total).tolist(),
                     "mitsuba_error": (within_error / total).tolist(), "monte_carlo_of_export": np.array(mc).T.tolist(),
                     "median_radius_mm": m.median_radius_mm.tolist()}
        print(f"  radial {name}: model {np.round(model_fraction.mean(1), 3)}, Mitsuba {np.round((within / total).mean(1), 3)}", flush=True)
    return out


def _blender_jobs(sets: dict, spp: int):
    jobs, names, radial_jobs = [], [], []
    for name, params in sets.items():
        result = export.renderer_profiles(params)
        principled = export.blender_principled(result)
        common = {"radius_mm": principled["Subsurface Radius"], "spp": spp, "method": principled["subsurface_method"], "ior": 1.4}
        jobs += [{**common, "base_colour": principled["Base Color"][:3], "target": result.rgb_albedo.tolist()},
                 {**common, "base_colour": result.rgb_albedo.tolist(), "target": result.rgb_albedo.tolist()}]
        names.append(name)
        if name in skinfit.PRESET_NAMES:
            screened = {**common, "base_colour": principled["Base Color"][:3], "slab_mm": [40.0, 20.0], "preset": name}
            radial_jobs += [screened] + [{**screened, "screen_radius_mm": r} for r in RADII_MM]
    return jobs, names, radial_jobs


def blender(sets: dict, blender_python: str, spp: int) -> dict:
    jobs, names, radial_jobs = _blender_jobs(sets, spp)
    jobs = jobs + radial_jobs
    with tempfile.TemporaryDirectory() as folder:
        jobs_path, out_path = Path(folder) / "jobs.json", Path(folder) / "out.json"
        jobs_path.write_text(json.dumps({"jobs": jobs}))
        subprocess.run([blender_python, str(ROOT / "benchmarks" / "blender_cycles.py"), str(jobs_path), str(out_path)], check=True,
                       stdout=subprocess.DEVNULL)
        rendered = json.loads(out_path.read_text())
    out = {"blender": rendered["blender"], "method": jobs[0]["method"], "spp": spp, "sets": {}}
    for k, name in enumerate(names):
        compensated, plain = rendered["results"][2 * k], rendered["results"][2 * k + 1]
        target = np.array(compensated["target"])
        out["sets"][name] = {"target": target.tolist(), "ratio": (np.array(compensated["albedo"]) / target).tolist(),
                             "error": (np.array(compensated["error"]) / target).tolist(),
                             "dE2000": _delta_e(compensated["albedo"], target),
                             "uncompensated_ratio": (np.array(plain["albedo"]) / target).tolist()}
        print(f"  Blender {name}: ratio {np.round(out['sets'][name]['ratio'], 4)}, uncompensated {np.round(out['sets'][name]['uncompensated_ratio'], 3)}",
              flush=True)
    radial_rows = rendered["results"][2 * len(names):]
    out["radial"] = {}
    for k, name in enumerate(skinfit.PRESET_NAMES):
        rows = radial_rows[k * (1 + len(RADII_MM)):(k + 1) * (1 + len(RADII_MM))]
        total = np.array(rows[0]["albedo"])
        out["radial"][name] = {"radii_mm": list(RADII_MM), "fraction": [(np.array(r["albedo"]) / total).tolist() for r in rows[1:]]}
    return out


def _summary(rows: dict) -> tuple[float, float]:
    worst = max(max(abs(r - 1) for r in row["ratio"]) for row in rows.values())
    return worst, max(row["dE2000"] for row in rows.values())


def markdown(record) -> str:
    """The renderer table of docs/renderers.md (kept equal to it by tests/test_readme.py)."""
    lines = [f"Exports rendered (`python -m benchmarks.renderers`, {record['date']}, {record['machine']}; Mitsuba {record['mitsuba']}, "
             "`volpathmis`, slab 400 × 400 × 100 mm under a white environment, normal view, specular subtracted): rendered / model "
             "linear-sRGB albedo per channel, with the render's standard error, and CIEDE2000:", "",
             "| model | set | Mitsuba 3 R / G / B | CIEDE2000 | diffusion-matched medium (before) | Blender Cycles R / G / B |",
             "|---|---|---|---|---|---|"]
    for model_name, block in record["models"].items():
        cycles = record.get("blender", {}).get("sets", {}) if model_name == record["default_model"] else {}
        for name in skinfit.PRESET_NAMES:
            row = block["mitsuba"][name]
            ratio = " / ".join(f"{r:.3f}" for r in row["ratio"])
            error = max(e / t for e, t in zip(row["error"], row["target"]))
            blender_cell = " / ".join(f"{r:.3f}" for r in cycles[name]["ratio"]) if name in cycles else "—"
            lines.append(f"| {model_name} | {name} | {ratio} (± {error:.3f}) | {row['dE2000']:.2f} | "
                         f"{' / '.join(f'{r:.3f}' for r in row['diffusion_matched_ratio'])} (ΔE {row['diffusion_matched_dE2000']:.2f}) | {blender_cell} |")
        randoms = {k: v for k, v in block["mitsuba"].items() if k.startswith("random")}
        if randoms:
            worst, de = _summary(randoms)
            cycles_random = {k: v for k, v in cycles.items() if k.startswith("random")}
            cycles_worst = max(max(abs(r - 1) for r in v["ratio"]) for v in cycles_random.values()) if cycles_random else None
            cycles_cell = f"worst channel {100 * cycles_worst:.1f} % off" if cycles_random else "—"
            lines.append(f"| {model_name} | {len(randoms)} random sets | worst channel {100 * worst:.1f} % off | max {de:.2f} | — | {cycles_cell} |")
    spectral = record["models"][record["default_model"]]["spectral"]
    lines += ["", "Spectral export (medium preset, `scalar_spectral`, 2 nm bands): rendered / model reflectance "
              + ", ".join(f"{w:.0f} nm {r:.3f}" for w, r in zip(spectral["wavelengths_nm"], spectral["ratio"])) + "."]
    if "blender" in record:
        lines += ["", f"Blender {record['blender']['blender']} Cycles, Principled BSDF `{record['blender']['method']}`, base colour compensated "
                  "for the drift measured by `benchmarks/measure_blender_drift.py` (uncompensated, base colour = target: "
                  + ", ".join(f"{n} {' / '.join(f'{r:.3f}' for r in record['blender']['sets'][n]['uncompensated_ratio'])}" for n in skinfit.PRESET_NAMES)
                  + ")."]
    lines += ["", "Radial check (default model): fraction of the diffuse energy within 0.1 / 0.5 / 1 / 2 mm of a narrow beam, green "
              "channel (model profile vs Mitsuba render of the export vs skinfit's Monte Carlo of the export):", "",
              "| preset | model | Mitsuba 3 | Monte Carlo of the export | Blender Cycles |", "|---|---|---|---|---|"]
    cycles_radial = record.get("blender", {}).get("radial", {})
    for name, row in record["models"][record["default_model"]]["radial"].items():
        cell = lambda values: " / ".join(f"{v[1]:.3f}" for v in values)  # noqa: E731
        cycles_cell = cell(cycles_radial[name]["fraction"]) if name in cycles_radial else "—"
        lines.append(f"| {name} | {cell(row['model'])} | {cell(row['mitsuba'])} | {cell(row['monte_carlo_of_export'])} | {cycles_cell} |")
    return "\n".join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--blender-python", default=None)
    parser.add_argument("--random", type=int, default=20)
    parser.add_argument("--quick", action="store_true", help="fewer samples (a smoke run)")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    parser.add_argument("--markdown-only", action="store_true", help="rewrite renderers.md from the saved renderers.json")
    args = parser.parse_args(argv)
    out = Path(args.out)
    if args.markdown_only:
        (out / "renderers.md").write_text(markdown(json.loads((out / "renderers.json").read_text())) + "\n")
        return
    import mitsuba

    scale = 8 if args.quick else 1
    sets = parameter_sets(args.random)
    default = skinfit.SkinModel.default()
    record = {**provenance(), "mitsuba": mitsuba.__version__, "default_model": default.name, "models": {}}
    for model in (default, skinfit.SkinModel.dj2006()):
        print(f"{model.name}:", flush=True)
        block = {"mitsuba": mitsuba_rgb(sets, model, 65536 // scale, 16384 // scale)}
        if model is default:
            block["spectral"] = mitsuba_spectral(model, 32768 // scale)
            print(f"  spectral ratios {np.round(block['spectral']['ratio'], 4)}", flush=True)
            block["radial"] = radial(model, 16384 // scale, 400_000 // scale)
        record["models"][model.name] = block
    if args.blender_python:
        record["blender"] = blender(sets, args.blender_python, 16384 // scale)
    out.mkdir(parents=True, exist_ok=True)
    (out / "renderers.json").write_text(json.dumps(record, indent=1))
    (out / "renderers.md").write_text(markdown(record) + "\n")
    print(markdown(record))


if __name__ == "__main__":
    main()
