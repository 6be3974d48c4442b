"""Measure how Blender Cycles' Principled BSDF random walk renders a base colour, for compensation.

Run: python -m benchmarks.measure_blender_drift --blender-python /path/to/python-with-bpy
     [--method RANDOM_WALK_SKIN] [--spp 8192]

Cycles inverts the Principled BSDF's base colour into a medium itself, and what it renders differs
from the base colour (Blender 4.2 LTS: 7-23 % darker at 1 mm radius, more for dark colours). This
script renders the reference slab of ``benchmarks/blender_cycles.py`` for 60 base colours from
0.002 to 0.95 (three per render, one per channel; Cycles' channels are independent, checked by
two renders that share a channel) at ``--spp`` samples, and writes the curve, rendered diffuse
albedo against base colour with its standard error, to spectra/blender_cycles_<method>.json,
which ``skinfit.export.blender_principled`` inverts. The rendered albedo of a semi-infinite
slab is independent of the radius (checked here at 1 and 10 mm); below ~0.1 mm x 0.001 scene
units Cycles falls back to a diffuse surface, which this curve does not describe.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks._record import provenance

ROOT = Path(__file__).resolve().parents[1]


def render(blender_python: str, jobs: list[dict]) -> dict:
    with tempfile.TemporaryDirectory() as folder:
        jobs_path, out_path = Path(folder) / "jobs.json", Path(folder) / "out.json"
        jobs_path.write_text(json.dumps({"jobs": jobs}))
        subprocess.run([blender_python, str(ROOT / "benchmarks" / "blender_cycles.py"), str(jobs_path), str(out_path)], check=True,
                       stdout=subprocess.DEVNULL)
        return json.loads(out_path.read_text())


def radial_scale(args) -> dict:
    """k(base colour): Cycles' median energy radius over its Subsurface Radius."""
    base = np.geomspace(0.003, 0.95, 24).reshape(-1, 3)
    rho = np.geomspace(0.005, 1.0, 13)
    common = {"radius_mm": [1.0, 1.0, 1.0], "spp": args.spp // 2, "method": args.method, "ior": args.ior, "anisotropy": 0.0,
              "slab_mm": [20.0, 10.0]}
    jobs = [{**common, "base_colour": row.tolist(), **({} if r is None else {"screen_radius_mm": float(r)})} for r in [None, *rho] for row in base]
    results = render(args.blender_python, jobs)["results"]
    energy = np.array([r["albedo"] for r in results]).reshape(1 + rho.size, -1)  # (radii + total, base colours)
    fraction = np.maximum.accumulate(energy[1:] / energy[0], axis=0)
    median = np.array([float(np.exp(np.interp(0.5, f, np.log(rho)))) for f in fraction.T])
    if np.any(fraction[0] >= 0.5) or np.any(fraction[-1] <= 0.5):
        sys.exit("the median energy radius lies outside the screened radii")
    return {"base_colour": base.ravel().tolist(), "median_over_radius": median.tolist(), "screen_radii_mm": rho.tolist(),
            "fraction_within": fraction.T.tolist(), "subsurface_radius_mm": 1.0, "slab_mm": common["slab_mm"]}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--blender-python", required=True)
    parser.add_argument("--method", default="RANDOM_WALK_SKIN", choices=("RANDOM_WALK", "RANDOM_WALK_SKIN"))
    parser.add_argument("--spp", type=int, default=8192)
    parser.add_argument("--ior", type=float, default=1.4)
    args = parser.parse_args(argv)
    base = np.geomspace(0.002, 0.95, 60).reshape(-1, 3)
    common = {"radius_mm": [1.0, 1.0, 1.0], "spp": args.spp, "method": args.method, "ior": args.ior, "anisotropy": 0.0}
    jobs = [{**common, "base_colour": row.tolist()} for row in base]
    checks = [{**common, "base_colour": [float(base[10, 0]), 0.5, 0.5]},  # channel independence
              {**common, "radius_mm": [10.0, 10.0, 10.0], "base_colour": base[10].tolist()}]  # radius independence
    out = render(args.blender_python, jobs + checks)
    results = out["results"]
    albedo = np.array([r["albedo"] for r in results[: len(jobs)]]).ravel()
    error = np.array([r["error"] for r in results[: len(jobs)]]).ravel()
    record = {
        **provenance(), "blender": out["blender"], "method": args.method, "ior": args.ior, "anisotropy": 0.0, "spp": args.spp,
        "scene": "slab 400 x 400 x 100 mm, uniform white world, orthographic camera at normal view, 4 x 4 pixels over 2 mm, "
                 "radius 1 mm (Subsurface Scale 0.001, scene in metres), specular of a black base colour subtracted",
        "base_colour": base.ravel().tolist(), "rendered_albedo": albedo.tolist(), "rendered_error": error.tolist(),
        "check_channel_independence": {"rendered": results[len(jobs)]["albedo"][0], "in_curve": float(albedo[30]), "error": float(error[30])},
        "check_radius_10mm": {"rendered": results[len(jobs) + 1]["albedo"], "in_curve": albedo[30:33].tolist()},
    }
    record["radial"] = radial_scale(args)
    if np.any(np.diff(albedo) <= 0):
        sys.exit("the rendered albedo is not increasing in the base colour: more samples?")
    path = ROOT / "spectra" / f"blender_cycles_{args.method.lower()}.json"
    path.write_text(json.dumps(record, indent=0), encoding="utf-8")
    ratio = albedo / base.ravel()
    k = np.array(record["radial"]["median_over_radius"])
    print(f"median energy radius / Subsurface Radius from {k.min():.4f} to {k.max():.4f}")
    print(f"Blender {out['blender']} {args.method}: rendered / base colour from {ratio.min():.3f} to {ratio.max():.3f}; "
          f"checks {record['check_channel_independence']} {record['check_radius_10mm']}; wrote {path}")


if __name__ == "__main__":
    main()
