"""Build the shipped renderer medium table (n 1.4, g 0) and measure it against its references.

Run: python -m benchmarks.build_medium_table [--photons 200000] [--no-build] [--check-photons 100000]

1. Build: ``skinfit.export.build_medium_table()``: R(a) by adding-doubling (32 streams) and
   the median energy radius c(a) by the radially resolved Monte Carlo, written to
   spectra/renderer_medium_n1.400_g0.00.json; ``--no-build`` measures the file that is there.
2. Colour inversion: a(R) of the table against the direct adding-doubling at the midpoints
   between the curve's nodes (relative error in R after the round trip).
3. Median radius: c(a) of the table at albedos between the Monte Carlo nodes against fresh Monte
   Carlo runs (another seed), in units of their standard error.

Writes benchmarks/results/medium_table.json (with date, machine, git commit).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from benchmarks._record import provenance
from skinfit import export

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "spectra" / export._file_name(export.DEFAULT_CONVENTIONS)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--photons", type=int, default=export.MEDIAN_PHOTONS)
    parser.add_argument("--check-photons", type=int, default=100_000)
    parser.add_argument("--no-build", action="store_true")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    result = {**provenance(), "ior": export.DEFAULT_CONVENTIONS.ior, "anisotropy": export.DEFAULT_CONVENTIONS.anisotropy, "streams": export.MEDIUM_STREAMS}
    if args.no_build:
        table = export.load_medium_table(SHIPPED.read_text(encoding="utf-8"))
    else:
        start = time.perf_counter()
        table = export.build_medium_table(photons=args.photons)
        result["build_s"] = round(time.perf_counter() - start, 1)
        export.save_medium_table(table, SHIPPED)
    result["photons"] = table.photons
    result["median_relative_error"] = {"max": float(table.median_error.max()), "median": float(np.median(table.median_error))}

    mid = 0.5 * (table.albedo_logit[:-1] + table.albedo_logit[1:])
    albedo = 1.0 / (1.0 + np.exp(-mid))
    albedo = albedo[albedo <= 1.0 - table.median_absorption[0]]
    direct = export.semi_infinite_reflectance(albedo)
    round_trip = export.semi_infinite_reflectance(table.single_scattering_albedo(direct))
    error = np.abs(round_trip / direct - 1.0)
    result["colour_inversion"] = {"points": int(albedo.size), "max_relative_error": float(error.max()),
                                  "median_relative_error": float(np.median(error))}
    print(json.dumps(result["colour_inversion"]), flush=True)

    between = np.sqrt(table.median_absorption[:-1] * table.median_absorption[1:])[::3]
    checks = []
    for k, q in enumerate(between):
        c, se = export.median_of_unit_medium(1.0 - q, photons=args.check_photons, seed=1000 + k)
        interpolated = float(table.unit_median_radius(1.0 - q))
        node_se = float(np.interp(np.log(q), np.log(table.median_absorption), table.median_error))
        checks.append({"one_minus_albedo": float(q), "monte_carlo": c, "monte_carlo_relative_se": se, "table": interpolated,
                       "relative_difference": interpolated / c - 1.0, "z": (interpolated / c - 1.0) / np.hypot(se, node_se)})
        print(json.dumps(checks[-1]), flush=True)
    result["median_check"] = checks
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "medium_table.json").write_text(json.dumps(result, indent=1), encoding="utf-8")
    print(f"wrote {out / 'medium_table.json'}")


if __name__ == "__main__":
    main()
