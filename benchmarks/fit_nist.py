"""The 100 NIST subject averages fitted with DJ2006's constants: chromophores only, then extended.

    python -m benchmarks.fit_nist [--out benchmarks/results]

The two fits of ``notebooks/02_fit_spectra.py``, with the same calls: the NIST skin reflectance set's
subject averages (``data/nist_skin_reflectance_250-1000nm.csv``, inner forearm) at 400-700 nm every
10 nm, fitted with ``SkinModel.dj2006()`` and no measurement model, first with the defaults (melanin,
blend, haemoglobin free), then with oxygenation, epidermis thickness, scattering scale and a
specular offset also free. Writes ``benchmarks/results/fit_nist.json``: per fit the medians and
worsts of the RMS residual and CIEDE2000 (D65), the status counts, the subjects at β_m = 0, how many
subjects have each extended parameter on a bound (as the notebook counts them) and every subject's
residuals and free parameters; plus the repeat spread (RMS of the three repeats around their average), the floor no fit
can be expected to beat.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import skinfit
from benchmarks._record import provenance
from skinfit.fit import VARIABLES
from skinfit.io import read_nist

ROOT = Path(__file__).resolve().parents[1]
NIST = ROOT / "data" / "nist_skin_reflectance_250-1000nm.csv"
WAVELENGTHS = np.arange(400.0, 701.0, 10.0)
#: The extended fit's free parameters (notebook 02).
EXTENDED_FREE = ("melanin", "melanin_blend", "haemoglobin", "blood_oxygenation", "epidermis_thickness_mm",
                 "scattering_scale", "specular_offset")
#: Parameters whose bounds the notebook checks in the extended fit.
BOUND_CHECKED = ("scattering_scale", "epidermis_thickness_mm", "melanin_blend")


def on_bound(values: np.ndarray, key: str) -> np.ndarray:
    """Within 0.1 % of the parameter's range of either bound (the notebook's test)."""
    var = VARIABLES[key]
    span = var.high - var.low
    return (values - var.low < 1e-3 * span) | (var.high - values < 1e-3 * span)


def summary(fit, seconds: float) -> dict:
    ok = fit.status == skinfit.FitStatus.SUCCESS
    return {
        "free": list(fit.free),
        "seconds_first_call": seconds,
        "status_counts": {s.name: int(np.sum(fit.status == s)) for s in skinfit.FitStatus},
        "success": int(ok.sum()),
        "rms_median": float(np.median(fit.rms_residual)),
        "rms_max": float(np.max(fit.rms_residual)),
        "dE2000_median": float(np.median(fit.delta_e2000)),
        "dE2000_max": float(np.max(fit.delta_e2000)),
        "melanin_blend_zero": int(np.sum(fit.parameters["melanin_blend"] == 0.0)),
        "melanin_blend_below_0.01": int(np.sum(fit.parameters["melanin_blend"] < 0.01)),
        "melanin_blend_max": float(np.max(fit.parameters["melanin_blend"])),
        "parameter_medians": {key: float(np.median(v)) for key, v in fit.parameters.items()},
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    nist = read_nist(NIST)
    average = np.stack([np.interp(WAVELENGTHS, nist.wavelengths_nm, s) for s in nist.average])
    repeats = np.stack([[np.interp(WAVELENGTHS, nist.wavelengths_nm, r) for r in subject] for subject in nist.repeats])
    repeat_rms = np.sqrt(np.mean((repeats - average[:, None, :]) ** 2, axis=(1, 2)))

    dj2006 = skinfit.SkinModel.dj2006()
    start = time.perf_counter()
    fixed = skinfit.fit_spectra(WAVELENGTHS, average, model=dj2006, progress=False)
    fixed_s = time.perf_counter() - start
    start = time.perf_counter()
    extended = skinfit.fit_spectra(WAVELENGTHS, average, model=dj2006, free=EXTENDED_FREE, progress=False)
    extended_s = time.perf_counter() - start

    fits = {"dj2006": summary(fixed, fixed_s), "extended": summary(extended, extended_s)}
    fits["extended"]["on_bound"] = {key: int(on_bound(extended.parameters[key], key).sum()) for key in BOUND_CHECKED}
    high = VARIABLES["scattering_scale"].high
    fits["extended"]["scattering_scale_bound"] = float(high)
    fits["extended"]["scattering_scale_at_upper_bound_fraction"] = float(np.mean(on_bound(extended.parameters["scattering_scale"], "scattering_scale")
                                                                           & (extended.parameters["scattering_scale"] > 0.5 * high)))
    record = {
        **provenance(),
        "model": dj2006.name,
        "data": "NIST skin reflectance (DOI 10.18434/M38597), subject averages, 400-700 nm every 10 nm",
        "spectra": len(average),
        "repeat_rms_median": float(np.median(repeat_rms)),
        "repeat_rms_max": float(np.max(repeat_rms)),
        "fits": fits,
        "subjects": [
            {
                "subject": subject,
                "repeat_rms": float(repeat_rms[i]),
                **{f"{name}_{key}": float(v) for name, fit in (("dj2006", fixed), ("extended", extended))
                   for key, v in (("rms", fit.rms_residual[i]), ("dE2000", fit.delta_e2000[i]))},
                **{f"dj2006_{key}": float(fixed.parameters[key][i]) for key in fixed.free},
                **{f"extended_{key}": float(extended.parameters[key][i]) for key in extended.free},
                "dj2006_status": skinfit.FitStatus(int(fixed.status[i])).name,
                "extended_status": skinfit.FitStatus(int(extended.status[i])).name,
            }
            for i, subject in enumerate(nist.subjects)
        ],
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fit_nist.json").write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    print(f"repeat spread: median {record['repeat_rms_median']:.4f}, max {record['repeat_rms_max']:.4f}")
    for name, s in fits.items():
        print(f"{name:9s}: {s['success']} / {len(average)} success ({s['seconds_first_call']:.1f} s); RMS median {s['rms_median']:.4f}, "
              f"worst {s['rms_max']:.4f}; CIEDE2000 median {s['dE2000_median']:.2f}, worst {s['dE2000_max']:.2f}; "
              f"blend 0: {s['melanin_blend_zero']}, < 0.01: {s['melanin_blend_below_0.01']}")
    print(f"extended on a bound: {fits['extended']['on_bound']}; scattering scale at {high:g}: "
          f"{100 * fits['extended']['scattering_scale_at_upper_bound_fraction']:.0f} %")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
