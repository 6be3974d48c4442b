"""Spectral fits on realistic input: noisy, measured and out-of-box spectra, for each free set users use.

    python -m benchmarks.fit_realistic [--data ../shared/data] [--issa 1000] [--scipy-n 100] [--out benchmarks/results]

The noise-free spectra of ``benchmarks.fit_spectra`` are the easy case. This benchmark times
``skinfit.fit_spectra`` (first call, compilation included, then the median and the minimum of at
least ``--repeats`` calls and at least ``--min-seconds`` of them, in one process) and records its
statuses and accuracy on:

- ``synthetic``: the model's own spectra at random parameters in the box (C_m 0.001-0.5, β_m 0-1,
  C_h 0.001-0.1), noise-free, with 0.2 % and with 1 % multiplicative Gaussian noise;
- ``out of box``: spectra from parameters beyond the warm-start table's box (C_m 0.5-0.9, C_h 0.1-0.3);
- ``NIST``: the 100 subject averages of the NIST forearm set (shipped in ``data/``);
- ``ISSA``: ``--issa`` face spectra of the ISSA subset (d/8, specular included; read from the shared
  data folder, never shipped), the same draw as ``benchmarks.fit_measured``;

all at 400-700 nm every 10 nm, with DJ2006's constants (diffusion) and with the calibrated default
model (tabulated transport, population prior), for the free sets:

- ``chromophores``: melanin, blend, haemoglobin;
- ``+ oil``: and oil, with the specular part included at 8° (the ISSA instrument's geometry);
- ``extended``: the chromophores, blood oxygenation, epidermis thickness, scattering scale and a
  specular offset (notebook 02's extended fit).

Baseline, timed in the same run on the first ``--scipy-n`` spectra of each data set (DJ2006, chromophores):
``scipy.optimize.least_squares`` (trf, bounds) on the NumPy port of DJ2006 of ``benchmarks.forward_model``,
started from a typical skin, as in ``benchmarks.fit_spectra``; its spectra are fitted in parts
interleaved with the timed skinfit calls of the same row, so that the ratio compares the two under
the same load of this shared machine. Writes ``fit_realistic.json`` and
``fit_realistic.md`` (the table of docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import scipy.optimize

import skinfit
from benchmarks._record import provenance
from benchmarks._timing import first_and_repeated
from benchmarks.fit_measured import measured_spectra
from benchmarks.forward_model import chromophore_table, numpy_reflectance
from skinfit.io import read_nist

ROOT = Path(__file__).resolve().parents[1]
WAVELENGTHS = np.arange(400.0, 701.0, 10.0)
CHROMOPHORES = ("melanin", "melanin_blend", "haemoglobin")
FREE_SETS = {
    "chromophores": {"free": CHROMOPHORES},
    "+ oil": {"free": (*CHROMOPHORES, "oil"), "specular_included_deg": 8.0},
    "extended": {"free": (*CHROMOPHORES, "blood_oxygenation", "epidermis_thickness_mm", "scattering_scale", "specular_offset")},
}


def synthetic(model, n: int, noise: float, rng, box=((0.001, 0.5), (0.0, 1.0), (0.001, 0.1))) -> tuple[np.ndarray, np.ndarray]:
    """(true parameters (n, 3), spectra (n, m)) of ``model`` with multiplicative noise of relative sd ``noise``."""
    true = np.column_stack([rng.uniform(*box[0], n), rng.uniform(*box[1], n), rng.uniform(*box[2], n)])
    spectra = np.asarray(skinfit.diffuse_reflectance(skinfit.SkinParams(*true.T), WAVELENGTHS, model=model))
    return true, spectra * (1.0 + noise * rng.standard_normal(spectra.shape))


def nist_spectra() -> np.ndarray:
    nist = read_nist(ROOT / "data" / "nist_skin_reflectance_250-1000nm.csv")
    return np.stack([np.interp(WAVELENGTHS, nist.wavelengths_nm, s) for s in nist.average])


def timed(spectra: np.ndarray, model, repeats: int, min_seconds: float, baseline: "ScipyBaseline | None" = None,
          **options) -> tuple[dict, object]:
    """A row: skinfit's times and the fit's quality (``baseline``: interleaved with the timed calls)."""
    between = None if baseline is None else baseline.fit_part
    fit, first, times = first_and_repeated(
        lambda: skinfit.fit_spectra(WAVELENGTHS, spectra, model=model, progress=False, **options),
        repeats=repeats, min_seconds=min_seconds, between=between)
    median = float(np.median(times))
    return {
        "spectra": len(spectra),
        "first_call_s": first,
        "median_s": median,
        "min_s": float(np.min(times)),
        "timed_calls": len(times),
        "us_per_spectrum": 1e6 * median / len(spectra),
        "us_per_spectrum_min": 1e6 * float(np.min(times)) / len(spectra),
        "status_counts": {s.name: int(np.sum(fit.status == s)) for s in skinfit.FitStatus},
        "iterations_median": float(np.median(fit.iterations)),
        "iterations_max": int(np.max(fit.iterations)),
        "rms_median": float(np.median(fit.rms_residual)),
        "delta_e2000_median": float(np.median(fit.delta_e2000)),
        "delta_e2000_p95": float(np.percentile(fit.delta_e2000, 95)),
    }, fit


class ScipyBaseline:
    """``least_squares`` per spectrum on the NumPy port of DJ2006 (chromophores), as in
    ``benchmarks.fit_spectra``, over the first n spectra, fitted in parts (``fit_part``)."""

    def __init__(self, spectra: np.ndarray, n: int):
        self.table = chromophore_table(WAVELENGTHS)
        self.spectra = spectra[: min(n, len(spectra))]
        self.done, self.seconds = 0, 0.0

    def fit_part(self, parts: int) -> None:
        """Fit the next 1/parts of the spectra (parts: how many parts the whole is split into)."""
        stop = min(len(self.spectra), self.done + int(np.ceil(len(self.spectra) / parts)))
        start = time.perf_counter()
        for target in self.spectra[self.done : stop]:
            scipy.optimize.least_squares(lambda x: numpy_reflectance(x[0], x[1], x[2], self.table) - target, x0=[0.05, 0.5, 0.02],
                                         bounds=([0, 0, 0], [1, 1, 1]), xtol=1e-12, ftol=1e-12, gtol=1e-12)
        self.seconds += time.perf_counter() - start
        self.done = stop

    def result(self) -> dict:
        self.fit_part(1)  # whatever the interleaved parts left
        return {"spectra": self.done, "us_per_spectrum": 1e6 * self.seconds / self.done}


CACHE_PROBE = """
import time
import skinfit
from benchmarks.fit_realistic import WAVELENGTHS, nist_spectra
spectra = nist_spectra()
t1 = time.perf_counter()
skinfit.fit_spectra(WAVELENGTHS, spectra, progress=False)
print(time.perf_counter() - t1)
"""


def compilation_cache_effect() -> dict:
    """The first fit of the 100 NIST spectra (default model, defaults) in a fresh process: without the
    persistent cache, then twice with it in an empty folder (the first run fills it, the second reads it)."""
    import os
    import subprocess
    import sys
    import tempfile

    out = {}
    with tempfile.TemporaryDirectory() as folder:
        for label, environment in (("no_cache", {"SKINFIT_COMPILATION_CACHE": "0"}),
                                   ("cache_filled", {"SKINFIT_COMPILATION_CACHE": "1", "SKINFIT_CACHE_DIR": folder}),
                                   ("cache_read", {"SKINFIT_COMPILATION_CACHE": "1", "SKINFIT_CACHE_DIR": folder})):
            env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
            env.update(environment)
            done = subprocess.run([sys.executable, "-c", CACHE_PROBE], env=env, cwd=ROOT, capture_output=True, text=True, check=True)
            out[f"first_fit_s_{label}"] = float(done.stdout.strip().splitlines()[-1])
    return out


def cases(data: Path, issa: int, synthetic_n: int, rng) -> list[tuple[str, np.ndarray, np.ndarray | None, bool]]:
    """(data set, spectra, true chromophores or None, synthetic of DJ2006) rows."""
    dj = skinfit.SkinModel.dj2006()
    out = []
    for label, noise in (("synthetic, noise-free", 0.0), ("synthetic, 0.2 % noise", 0.002), ("synthetic, 1 % noise", 0.01)):
        true, spectra = synthetic(dj, synthetic_n, noise, rng)
        out.append((label, spectra, true, True))
    true, spectra = synthetic(dj, synthetic_n, 0.0, rng, box=((0.5, 0.9), (0.0, 1.0), (0.1, 0.3)))
    out.append(("out of box (C_m 0.5-0.9, C_h 0.1-0.3)", spectra, true, True))
    out.append(("NIST forearm, 100 subjects", nist_spectra(), None, False))
    issa_path = data / "issa-subset" / "issa_subset.csv"
    if issa and issa_path.exists():
        out.append((f"ISSA faces, {issa} spectra", measured_spectra(data, issa), None, False))
    return out


def summary_markdown(record: dict) -> str:
    lines = [f"Measured {record['date']} on {record['machine']} (`python -m benchmarks.fit_realistic`): time per spectrum after "
             f"compilation (median of at least {record['repeats']} calls and {record.get('min_seconds', 0):g} s of them), the first call "
             "(compilation included), MAX_STEPS of all statuses, median iterations, CIEDE2000 median / p95; SciPy: `least_squares` "
             "on the NumPy port of DJ2006, chromophores, same spectra, its fits interleaved with the timed calls.",
             "",
             "| data | model | free | µs / spectrum | first call | MAX_STEPS | iterations | CIEDE2000 | vs SciPy |",
             "|---|---|---|---|---|---|---|---|---|"]
    for row in record["rows"]:
        ratio = f"{row['scipy_over_skinfit']:.0f}x" if "scipy_over_skinfit" in row else ""
        lines.append(f"| {row['data']} | {row['model']} | {row['free']} | {row['us_per_spectrum']:,.0f} | {row['first_call_s']:.1f} s | "
                     f"{row['status_counts']['MAX_STEPS']} / {row['spectra']:,} | {row['iterations_median']:.0f} | "
                     f"{row['delta_e2000_median']:.2f} / {row['delta_e2000_p95']:.2f} | {ratio} |")
    cache = record.get("compilation_cache")
    if cache:
        lines += ["", f"First fit of the 100 NIST spectra in a fresh process (default model, compilation included): "
                      f"{cache['first_fit_s_no_cache']:.1f} s without the persistent compilation cache, "
                      f"{cache['first_fit_s_cache_filled']:.1f} s filling it, {cache['first_fit_s_cache_read']:.1f} s reading it."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    parser.add_argument("--issa", type=int, default=1000, help="ISSA face spectra (0: none)")
    parser.add_argument("--synthetic", type=int, default=1000, help="spectra per synthetic set")
    parser.add_argument("--scipy-n", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3, help="timed calls per row, at least")
    parser.add_argument("--min-seconds", type=float, default=2.0, help="seconds of timed calls per row, at least")
    parser.add_argument("--models", default="dj2006,calibrated")
    parser.add_argument("--free-sets", default=",".join(FREE_SETS))
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    parser.add_argument("--no-cache-probe", action="store_true", help="skip the persistent-cache timing (three fresh processes)")
    args = parser.parse_args(argv)
    models = {"dj2006": skinfit.SkinModel.dj2006(), "calibrated": skinfit.SkinModel.default()}
    models = {k: models[k] for k in args.models.split(",")}
    rows = []
    for label, spectra, true, own in cases(Path(args.data), args.issa, args.synthetic, np.random.default_rng(2026)):
        free_sets = args.free_sets.split(",")
        for model_key, model in models.items():
            for free_key in free_sets:
                if own and (model_key != "dj2006" or free_key != "chromophores"):
                    continue  # the synthetic sets are DJ2006 chromophore spectra: one row each
                compared = model_key == "dj2006" and free_key == "chromophores" and args.scipy_n > 0
                baseline = ScipyBaseline(spectra, args.scipy_n) if compared else None
                row, fit = timed(spectra, model, args.repeats, args.min_seconds, baseline, **FREE_SETS[free_key])
                row.update(data=label, model=model.name, free=free_key)
                if true is not None:
                    got = np.column_stack([fit.parameters[k] for k in CHROMOPHORES])
                    row["max_parameter_error_median"] = float(np.median(np.abs(got - true).max(axis=1)))
                if baseline is not None:
                    scipy_result = baseline.result()
                    row["scipy_us_per_spectrum"] = scipy_result["us_per_spectrum"]
                    row["scipy_spectra"] = scipy_result["spectra"]
                    row["scipy_over_skinfit"] = scipy_result["us_per_spectrum"] / row["us_per_spectrum"]
                rows.append(row)
                print(f"{label:40s} {model.name:16s} {free_key:13s} {row['us_per_spectrum']:8.0f} us (min {row['us_per_spectrum_min']:.0f}, "
                      f"{row['timed_calls']} calls; first {row['first_call_s']:.1f} s) "
                      f"MAX_STEPS {row['status_counts']['MAX_STEPS']:4d} it {row['iterations_median']:.0f} "
                      f"dE {row['delta_e2000_median']:.2f}" + (f" scipy x{row['scipy_over_skinfit']:.0f}" if "scipy_over_skinfit" in row else ""),
                      flush=True)
    record = {**provenance(), "wavelengths_nm": [400, 700, 10], "repeats": args.repeats, "min_seconds": args.min_seconds, "rows": rows}
    if not args.no_cache_probe:
        record["compilation_cache"] = compilation_cache_effect()
        print(record["compilation_cache"], flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fit_realistic.json").write_text(json.dumps(record, indent=1) + "\n")
    (out / "fit_realistic.md").write_text(summary_markdown(record))
    print(summary_markdown(record))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
