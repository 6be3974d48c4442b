"""``python -m benchmarks``: run time against error (Pareto sweeps) and the numerical stress sweep.

Writes into a folder it names (default benchmarks/results/pareto): points.csv (every point: time
after compilation, compile time, error against the same run's reference, baseline ratio, whether
it is on the Pareto front), one pareto_<sweep>.png per sweep, stress.json and summary.md (the
docs' tables). See benchmarks/pareto.py and benchmarks/stress.py for what is measured.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import jax

from benchmarks import pareto, stress

TITLES = {
    "profile_quadrature": "Profiles: Hankel quadrature (3 presets x 31 wavelengths x 256 radii)",
    "profile_radii": "Profiles: radii count (3 presets x 31 wavelengths)",
    "profile_wavelengths": "Profiles: wavelengths for RGB profiles (3 presets x 256 radii)",
    "colour": "Reflectance to colour (16,384 spectra)",
    "spectral_fit": "Spectral fits (1000 noise-free spectra)",
    "image_fit": "Image fits (256x256 round trip)",
    "planner": "Planner: what a request computes",
}


def summary(points, report, machine, date) -> str:
    lines = [f"Measured {date} on {machine} (`python -m benchmarks`).", ""]
    for sweep in TITLES:
        mine = [p for p in points if p.sweep == sweep]
        if not mine:
            continue
        front = {id(p) for p in pareto.pareto_front(mine)}
        lines += [f"**{TITLES[sweep]}** (error: {mine[0].error_unit})", "",
                  "| setting | time (s) | first call (s) | error | vs baseline | Pareto |", "|---|---|---|---|---|---|"]
        for p in mine:
            ratio = f"{p.speedup_vs_baseline:,.0f}x" if p.baseline_s == p.baseline_s else ""
            name = f"**{p.setting}**" if p.default else p.setting
            lines.append(f"| {name} | {p.time_s:.3g} | {p.compile_s:.2g} | {p.error:.2g} | {ratio} | {'yes' if id(p) in front else ''} |")
        if sweep == "planner" and len(mine) == 2:
            lines.append(f"\nReflectance only costs 1/{mine[0].time_s / mine[1].time_s:.0f} of reflectance plus profiles.")
        lines.append("")
    if report:
        lines += [
            f"**Stress sweep** ({report['float64']['points']:,} float64 + {report['float32']['points']:,} float32 model points, "
            f"{report['float64']['profile_points'] + report['float32']['profile_points']:,} profile values, "
            f"{report['float64']['fd_points']:,} finite-difference checks, {report['solvers']['solver_spectra']} hostile spectra and "
            f"{report['solvers']['solver_pixels']:,} hostile pixels; {report['seconds']:.0f} s): "
            f"**{report['violations']} violations**; outside the diffusion model's validity domain "
            f"(epidermis under one transport mean free path) {report['outside_validity']:,} property failures of the "
            f"diffusion approximation itself; negative profile tails of the model itself (flux-only exitance, confirmed "
            f"with a refined quadrature): {report['float64']['profile_negative_model']} float64 / "
            f"{report['float32']['profile_negative_model']} float32, at most "
            f"{max(report['float64']['profile_negative_model_worst_of_peak'], report['float32']['profile_negative_model_worst_of_peak']):.1e} of the peak.",
            "",
        ]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="benchmarks/results/pareto", help="output folder (default benchmarks/results/pareto)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per point (median; default 3)")
    parser.add_argument("--only", default=",".join(pareto.SWEEPS), help=f"comma-separated sweeps (default all: {','.join(pareto.SWEEPS)})")
    parser.add_argument("--stress-points", type=int, default=1_000_000, help="stress sweep model points per dtype (0: skip; default 1e6)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    machine = f"{platform.machine()} ({platform.processor() or 'cpu'}), {jax.device_count()} {jax.default_backend()} device(s), jax {jax.__version__}"
    date = time.strftime("%Y-%m-%d")
    points = []
    for name in args.only.split(","):
        if name not in pareto.SWEEPS:
            parser.error(f"unknown sweep {name!r}")
        start = time.perf_counter()
        print(f"sweep {name} ...", flush=True)
        new = pareto.SWEEPS[name](args.repeats)
        points += new
        pareto.write_csv(points, out / "points.csv")  # a long run keeps what it finished
        for sweep in sorted({p.sweep for p in new}):
            pareto.plot(points, sweep, out / f"pareto_{sweep}.png", TITLES[sweep])
        for p in new:
            print(f"  {p.setting:60s} {p.time_s:10.4g} s  error {p.error:.3g}")
        print(f"  ({time.perf_counter() - start:.0f} s)")
    reports = {}
    for name in stress.MODELS if args.stress_points else ():
        print(f"stress sweep of {name}, {args.stress_points:,} points per dtype ...", flush=True)
        start = time.perf_counter()
        # the solvers' hostile targets go through fit_spectra's and fit_pixels' own defaults: once is enough
        reports[name] = stress.sweep(args.stress_points, model=stress.MODELS[name](), solvers=name == "dj2006")
        reports[name]["seconds"] = time.perf_counter() - start
        reports[name]["machine"], reports[name]["date"] = machine, date
        (out / stress.result_file(name)).write_text(json.dumps(reports[name], indent=2))
        print(f"  violations {reports[name]['violations']}, outside validity {reports[name]['outside_validity']}")
    report = reports.get("dj2006")
    text = summary(points, report, machine, date)
    (out / "summary.md").write_text(text)
    (out / "run.json").write_text(json.dumps({"date": date, "machine": machine, "repeats": args.repeats}, indent=2))
    print(text)
    stress_files = "".join(f"{stress.result_file(name)}, " for name in reports)
    print(f"wrote {out}/: points.csv, pareto_*.png, {stress_files}summary.md")
    return 0 if all(r["violations"] == 0 for r in reports.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
