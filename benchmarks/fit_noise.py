"""Bias and scatter of fitted parameters under 0.5 % multiplicative noise.

Run: python -m benchmarks.fit_noise [--n 1000] [--noise 0.005] [--out benchmarks/results]
The forward model at random parameters in the box C_m 0.001-0.5, beta_m 0-1, C_h 0.001-0.1
(400-700 nm every 10 nm), times (1 + noise * N(0, 1)) per wavelength, fitted with the three
chromophores free. Reports, per parameter, the median and spread of (fitted - true) in absolute
and relative terms, and how often the reported standard error covers the error (|err| <= SE).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import skinfit
from benchmarks._record import provenance
from benchmarks.fit_spectra import box_spectra

#: The saved noise results are for Donner & Jensen 2006's diffusion model (the calibrated default's fits of
#: measured spectra are in benchmarks.fit_measured).
MODEL = skinfit.SkinModel.dj2006()

KEYS = ("melanin", "melanin_blend", "haemoglobin")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--noise", type=float, default=0.005)
    parser.add_argument("--out", default="benchmarks/results")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(11)
    wl, true, clean = box_spectra(args.n, rng)
    noisy = clean * (1 + args.noise * rng.standard_normal(clean.shape))
    fit = skinfit.fit_spectra(wl, noisy, model=MODEL, progress=False)
    result = {**provenance(), "spectra": args.n, "noise": args.noise,
              "status_counts": {s.name: int(np.sum(fit.status == s)) for s in skinfit.FitStatus}}
    for i, key in enumerate(KEYS):
        err = fit.parameters[key] - true[:, i]
        rel = err / true[:, i]
        result[key] = {
            "median_error": float(np.median(err)),
            "mad_error": float(np.median(np.abs(err - np.median(err)))),
            "median_relative_error": float(np.median(rel)),
            "p16_p84_relative_error": [float(np.percentile(rel, 16)), float(np.percentile(rel, 84))],
            "se_covers_error": float(np.mean(np.abs(err) <= fit.standard_errors[key])),
        }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fit_noise.json").write_text(json.dumps(result, indent=2))
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
