"""Spectral-fit benchmark: skinfit.fit_spectra against scipy.optimize.least_squares on NumPy.

Run: python -m benchmarks.fit_spectra [--n 10000] [--scipy-n 300] [--out benchmarks/results]
Both fit the same noise-free spectra (the forward model at random parameters in the box
C_m 0.001-0.5, beta_m 0-1, C_h 0.001-0.1; 400-700 nm every 10 nm). The baseline is what users
write today: least_squares (trf, bounds [0, 1]) per spectrum on a NumPy port of the same model,
started from a fixed typical skin (C_m 0.05, beta_m 0.5, C_h 0.02); it is timed on a subset and
scaled per spectrum. Prints and saves times after compilation (median of --repeats runs), ratios
and parameter errors.
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
from benchmarks.forward_model import chromophore_table, numpy_reflectance
from skinfit.fit import fit_spectra

#: These timings compare skinfit with NumPy/SciPy ports of Donner & Jensen 2006's diffusion model, so
#: they evaluate that model (the calibrated default is re-measured by benchmarks.fit_measured).
MODEL = skinfit.SkinModel.dj2006()

KEYS = ("melanin", "melanin_blend", "haemoglobin")


def box_spectra(n, rng):
    """Wavelengths (400-700 nm / 10 nm), n random (C_m, beta_m, C_h) in the issue's box
    (0.001-0.5, 0-1, 0.001-0.1) and their model spectra."""
    wl = np.arange(400.0, 701.0, 10.0)
    true = np.column_stack([rng.uniform(0.001, 0.5, n), rng.uniform(0, 1, n), rng.uniform(0.001, 0.1, n)])
    return wl, true, np.asarray(skinfit.diffuse_reflectance(skinfit.SkinParams(*true.T), wl, model=MODEL))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=10_000)
    parser.add_argument("--scipy-n", type=int, default=300)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default="benchmarks/results")
    args = parser.parse_args(argv)
    wl, true, spectra = box_spectra(args.n, np.random.default_rng(7))

    start = time.perf_counter()
    fit_spectra(wl, spectra, model=MODEL, progress=False)
    first = time.perf_counter() - start
    times = []
    for _ in range(args.repeats):  # the machine is shared: report the median of a few runs
        start = time.perf_counter()
        fit = fit_spectra(wl, spectra, model=MODEL, progress=False)
        times.append(time.perf_counter() - start)
    ours = float(np.median(times))
    got = np.column_stack([fit.parameters[k] for k in KEYS])
    err = np.abs(got - true).max(axis=1)

    table = chromophore_table(wl)
    m = min(args.scipy_n, args.n)
    start = time.perf_counter()
    scipy_err = []
    for i in range(m):
        res = scipy.optimize.least_squares(
            lambda x: numpy_reflectance(x[0], x[1], x[2], table) - spectra[i], x0=[0.05, 0.5, 0.02], bounds=([0, 0, 0], [1, 1, 1]),
            xtol=1e-12, ftol=1e-12, gtol=1e-12,
        )
        scipy_err.append(np.abs(res.x - true[i]).max())
    baseline = (time.perf_counter() - start) / m
    scipy_err = np.array(scipy_err)

    result = {
        **provenance(),
        "spectra": args.n,
        "first_call_s_incl_compile": first,
        "skinfit_s": ours,
        "skinfit_runs_s": times,
        "skinfit_us_per_spectrum": 1e6 * ours / args.n,
        "skinfit_success": int(np.sum(fit.status == 0)),
        "skinfit_max_error": float(err.max()),
        "skinfit_within_1e-6": int(np.sum(err <= 1e-6)),
        "scipy_us_per_spectrum": 1e6 * baseline,
        "scipy_subset": m,
        "scipy_within_1e-6": float(np.mean(scipy_err <= 1e-6)),
        "speedup": baseline * args.n / ours,
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fit_spectra.json").write_text(json.dumps(result, indent=2))
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
