"""Calibrate the shipped skin model on measured skin, cross-validate it, and check it on NIST.

    python -m benchmarks.calibrate_model [--data ../shared/data] [--folds 5] [--write-model]

Data (read from the shared folder, never shipped): the ISSA subset (Lu et al. 2025, Sci. Data,
DOI 10.1038/s41597-025-04857-5; face sites, d/8 spectrophotometer with the specular component
included, 400-700 nm every 10 nm) and the NIST skin set (DOI 10.18434/M38597; inner forearm).

Measurement model of the ISSA spectra: specular included at 8 degrees (``oil`` free per spectrum),
a triangular band-pass of 10 nm FWHM (spectrophotometers reporting every 10 nm), infinite port.
Per spectrum: melanin, melanin blend, haemoglobin and oil. Shared: the constants of
``skinfit.fit.DEFAULT_CONSTANTS`` on exact (tabulated) transport with g = 0.8.

Cross-validation: subjects (origin, subject) in ``--folds`` folds; each fold's spectra are fitted
through ``skinfit.fit_spectra`` with constants calibrated without it. Writes
``benchmarks/results/calibration.json`` and, with ``--write-model``, ``spectra/calibrated_model.json``
(the constants, their standard errors, the population prior, and this record).

    python -m benchmarks.calibrate_model --check

recalibrates on the current code without touching the shipped model or its record, and writes
``benchmarks/results/calibration_check.json``: each constant beside the shipped one, their difference
in units of the shipped subject-robust standard error, and the cross-validated errors of both runs.
The outer problem is flat along the epidermis's scattering (the fold constants spread by several
standard errors), so a rerun on changed code is expected to land within the standard errors, not on
the same digits: this is the check that the shipped model is reproducible to its stated uncertainty.

    python -m benchmarks.calibrate_model --compare-methods

calibrates the same constants twice from the same start, once on tabulated transport (the shipped
model's method) and once on DJ2005 multipole diffusion, each with the same subject folds, and writes
``benchmarks/results/calibration_methods.{json,md}``: the two sets of constants side by side, the
held-out error of each overall and per population group, and each model on NIST (another instrument
and body site, never used in the calibration).
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import subprocess
from pathlib import Path

import numpy as np

import skinfit
from benchmarks._record import provenance
from skinfit.fit import DEFAULT_CONSTANTS, FitStatus, calibrate_model, on_a_bound
from skinfit.io import FACE_SITES, read_issa, read_nist

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
WAVELENGTHS = np.arange(400.0, 701.0, 10.0)
MEASUREMENT = {"specular_included_deg": 8.0, "bandwidth_nm": 10.0}
#: NIST: directional-hemispherical, specular inside the sphere, a ~5 mm port, 3 nm sampling.
NIST_MEASUREMENT = {"specular_included_deg": 8.0, "port_radius_mm": 2.5}
MODEL_NAME = "skinfit-2026.12"


#: Epidermis thickness of the shipped model, mm: the 60 um epidermis of S. L. Jacques, "Optical properties
#: of biological tissues: a review", Phys. Med. Biol. 58 (2013) R37, Table 3 (melanosome volume fractions
#: are given for a 60 um epidermis); facial epidermis measures about 30-100 um. Reflectance cannot
#: separate it from the epidermis's scattering (see ``DEFAULT_CONSTANTS``).
EPIDERMIS_THICKNESS_MM = 0.06
#: Refractive index of the surface (the stratum corneum) for the specular lobe: 1.55 (G. J. Tearney et al.,
#: "Determination of the refractive index of highly scattering human tissue by optical coherence
#: tomography", Opt. Lett. 20 (1995) 2258: stratum corneum 1.55 in vivo). With oil free per spectrum
#: the spectra see only oil x the lobe's albedo, so the index is not calibrated.
SURFACE_IOR = 1.55


#: Constants the calibrated model sets (from the literature) rather than fits; listed in the summary.
SET_CONSTANTS = ("epidermis_thickness_mm", "epidermis_scattering.mie_power", "epidermis_scattering.rayleigh_mm",
                 "dermis_scattering.mie_power", "dermis_scattering.rayleigh_mm", "surface_ior")


def _constant(model, dotted: str) -> float:
    for part in dotted.split("."):
        model = getattr(model, part)
    return float(model)


#: The forward methods ``--compare-methods`` calibrates on: the shipped model's, and DJ2005 diffusion.
METHODS = {"transport": skinfit.Transport.tabulated, "diffusion": skinfit.Diffusion}


def start_model(method: str = "transport") -> skinfit.SkinModel:
    """Where the calibration starts: DJ2006's constants on ``method`` (default tabulated transport,
    g 0.8), with a 60 um epidermis whose scattering keeps DJ2006's optical thickness, and single power
    laws (Jacques 2013 Eq. 1) in place of DJ2006's Mie + Rayleigh sum."""
    dj = skinfit.SkinModel.dj2006()
    scale = dj.epidermis_thickness_mm / EPIDERMIS_THICKNESS_MM
    total = float(dj.epidermis_scattering.mie_mm + dj.epidermis_scattering.rayleigh_mm)
    return dj.replace(
        epidermis_thickness_mm=EPIDERMIS_THICKNESS_MM,
        epidermis_scattering=skinfit.model.ScatteringLaw(scale * total, 1.0, 0.0),
        dermis_scattering=skinfit.model.ScatteringLaw(0.5 * total, 1.0, 0.0),
        surface_ior=SURFACE_IOR,
        method=METHODS[method](),
    )


def face_spectra(data: Path):
    archive = read_issa(data / "issa-subset" / "issa_subset.csv")
    face = archive.select([r["body_site"] in FACE_SITES for r in archive.records]).complete(WAVELENGTHS)
    return face


QUANTILES = (5, 25, 50, 75, 95)


def by_label(fit, labels, measured) -> dict:
    """Per label (population group or body site): parameter quantiles, bound fraction, fit quality
    and the mean residual by wavelength (fitted - measured)."""
    out = {}
    bound = on_a_bound(fit)
    for label in sorted(set(labels)):
        at = labels == label
        out[label] = {
            "spectra": int(at.sum()),
            "quantiles": {n: [float(np.percentile(fit.parameters[n][at], q)) for q in QUANTILES] for n in fit.free},
            "on_bound_fraction": float(bound[at].mean()),
            "rms_median": float(np.median(fit.rms_residual[at])),
            "delta_e2000_median": float(np.median(fit.delta_e2000[at])),
            "delta_e2000_p95": float(np.percentile(fit.delta_e2000[at], 95)),
            "success_fraction": float(np.mean(fit.status[at] == FitStatus.SUCCESS)),
            "mean_residual": np.mean(fit.fitted[at] - measured[at], axis=0).tolist(),
        }
    return out


def report(face, model, data: Path) -> dict:
    """What the shipped model does on the face spectra (in sample), by group and site, beside DJ2006."""
    groups = np.array([f"{r['origin']}: {r['ethnic_group']}" for r in face.records])
    sites = np.array([r["body_site"] for r in face.records])
    out = {"quantiles": list(QUANTILES)}
    fits = {
        "dj2006": skinfit.fit_spectra(WAVELENGTHS, face.reflectance, model=skinfit.SkinModel.dj2006(), progress=False, **MEASUREMENT),
        "calibrated": skinfit.fit_spectra(WAVELENGTHS, face.reflectance, model=model, progress=False, **MEASUREMENT),
        "calibrated_maximum_likelihood": skinfit.fit_spectra(WAVELENGTHS, face.reflectance, model=model, prior=False, progress=False,
                                                             **MEASUREMENT),
    }
    for label, fit in fits.items():
        residual = fit.fitted - face.reflectance
        out[label] = {
            "rms_median": float(np.median(fit.rms_residual)),
            "delta_e2000_median": float(np.median(fit.delta_e2000)),
            "delta_e2000_p95": float(np.percentile(fit.delta_e2000, 95)),
            "success_fraction": float(np.mean(fit.status == FitStatus.SUCCESS)),
            "max_steps": int(np.sum(fit.status == FitStatus.MAX_STEPS)),
            "on_bound_fraction": float(on_a_bound(fit).mean()),
            "mean_residual": residual.mean(axis=0).tolist(),
            "sd_residual": residual.std(axis=0).tolist(),
            "groups": by_label(fit, groups, face.reflectance),
            "sites": by_label(fit, sites, face.reflectance),
        }
    out["nist"] = nist_check(data, model)
    return out


def nist_check(data: Path, model) -> dict:
    nist = read_nist(data / "nist-skin-reflectance" / "M38597.csv")
    lam = nist.wavelengths_nm
    grid = WAVELENGTHS
    resample = lambda s: np.stack([np.interp(grid, lam, row) for row in s])  # noqa: E731
    average = resample(nist.average)
    repeats = np.stack([resample(r) for r in nist.repeats])  # (subjects, 3, m)
    spread = np.sqrt(np.mean((repeats - repeats.mean(axis=1, keepdims=True)) ** 2, axis=(1, 2)))
    out = {"repeat_spread_rms_median": float(np.median(spread))}
    for label, m in (("dj2006", skinfit.SkinModel.dj2006()), ("calibrated", model)):
        fit = skinfit.fit_spectra(grid, average, model=m, progress=False, **NIST_MEASUREMENT)
        out[label] = {"rms_median": float(np.median(fit.rms_residual)), "rms_max": float(fit.rms_residual.max()),
                      "delta_e2000_median": float(np.median(fit.delta_e2000)), "delta_e2000_p95": float(np.percentile(fit.delta_e2000, 95)),
                      "melanin_median": float(np.median(fit.parameters["melanin"])),
                      "haemoglobin_median": float(np.median(fit.parameters["haemoglobin"])),
                      "success": int(np.sum(fit.status == FitStatus.SUCCESS)), "max_steps": int(np.sum(fit.status == FitStatus.MAX_STEPS))}
    return out


def summary_markdown(record: dict) -> str:
    """The calibration table of docs/model.md, from the saved record (a test keeps the two equal)."""
    rep, cv = record["report"], record["cross_validation"]
    lines = [
        f"Measured {record['date']} ({record['machine']}), commit {record['commit']}: "
        f"`python -m benchmarks.calibrate_model --write-model`, {record['data']['issa_face']['spectra']} ISSA face spectra of "
        f"{record['data']['issa_face']['subjects']} subjects, calibration {record['calibration_seconds'] / 60:.1f} min.",
        "",
        "| ISSA face spectra (d/8, specular included, 400-700 nm) | CIEDE2000 median | p95 | RMS median | SUCCESS | MAX_STEPS | any variable on a bound |",
        "|---|---|---|---|---|---|---|",
    ]

    def row(label, part):
        return (f"| {label} | {part['delta_e2000_median']:.2f} | {part['delta_e2000_p95']:.2f} | {part['rms_median']:.4f} | "
                f"{100 * part['success_fraction']:.1f} % | {part['max_steps']} | {100 * part['on_bound_fraction']:.1f} % |")

    lines.append(row("DJ2006 constants, in sample", rep["dj2006"]))
    lines.append(row(f"calibrated, held out ({cv['folds']} subject folds), prior (default)", cv["with_prior"]))
    lines.append(row(f"calibrated, held out ({cv['folds']} subject folds), maximum likelihood", cv["maximum_likelihood"]))
    lines.append(row("calibrated, in sample, prior (default)", rep["calibrated"]))
    lines += ["", "| constant | DJ2006 | calibrated | subject-robust s.e. |", "|---|---|---|---|"]
    dj = skinfit.SkinModel.dj2006()
    for name, value in record["constants"].items():
        lines.append(f"| `{name}` | {_constant(dj, name):.4g} | {value:.4g} | {record['standard_errors'][name]:.2g} |")
    start = start_model()
    for name in SET_CONSTANTS:
        lines.append(f"| `{name}` | {_constant(dj, name):.4g} | {_constant(start, name):.4g} | set, not calibrated |")
    lines += ["", "| population group (origin) | spectra | melanin median | haemoglobin median (5-95 %) | blend median | on a bound | CIEDE2000 median / p95 |",
              "|---|---|---|---|---|---|---|"]
    for label, g in rep["calibrated"]["groups"].items():
        q = g["quantiles"]
        lines.append(f"| {label} | {g['spectra']} | {100 * q['melanin'][2]:.1f} % | {100 * q['haemoglobin'][2]:.1f} % "
                     f"({100 * q['haemoglobin'][0]:.1f}-{100 * q['haemoglobin'][4]:.1f}) | {q['melanin_blend'][2]:.2f} | "
                     f"{100 * g['on_bound_fraction']:.1f} % | {g['delta_e2000_median']:.2f} / {g['delta_e2000_p95']:.2f} |")
    nist = rep["nist"]
    lines += ["", f"NIST (100 subjects, inner forearm, another instrument; port 2.5 mm, specular included): RMS median "
                  f"{nist['calibrated']['rms_median']:.4f} (DJ2006 {nist['dj2006']['rms_median']:.4f}) against a repeat spread of "
                  f"{nist['repeat_spread_rms_median']:.4f}; CIEDE2000 median {nist['calibrated']['delta_e2000_median']:.2f} "
                  f"(DJ2006 {nist['dj2006']['delta_e2000_median']:.2f})."]
    return "\n".join(lines) + "\n"


def model_record(record: dict) -> dict:
    """What the shipped model file keeps of the calibration: how it was obtained and its cross-validated
    error, without the per-group report (that stays in ``benchmarks/results/calibration.json``)."""
    return {k: v for k, v in record.items() if k != "report"}


def write_summary(record: dict) -> None:
    (RESULTS / "calibration_summary.md").write_text(summary_markdown(record), encoding="utf-8")


def write_check(calibration, folds: int) -> dict:
    """Compare a recalibration on the current code with the shipped model (``--check``)."""
    shipped = json.loads((RESULTS / "calibration.json").read_text(encoding="utf-8"))
    cv = calibration.record().get("cross_validation")
    constants = {}
    for name, value in calibration.constants.items():
        se = shipped["standard_errors"][name]
        constants[name] = {"shipped": shipped["constants"][name], "recalibrated": value,
                           "shipped_standard_error": se, "recalibrated_standard_error": calibration.standard_errors[name],
                           "difference_in_standard_errors": (value - shipped["constants"][name]) / se}
    held_out = {}
    for part in ("with_prior", "maximum_likelihood"):
        if cv is not None:
            held_out[part] = {k: {"shipped": shipped["cross_validation"][part][k], "recalibrated": cv[part][k]}
                              for k in ("delta_e2000_median", "delta_e2000_p95", "rms_median", "max_steps", "success_fraction")}
    record = {
        **provenance(),
        "shipped_model_made_at": shipped["commit"],
        "spectra": int(len(calibration.fit.status)),
        "outer_steps": len(calibration.history),
        "outer_cost": {"shipped": shipped["outer_cost"][-1], "recalibrated": calibration.history[-1]},
        "folds": folds,
        "calibration_seconds": calibration.seconds,
        "constants": constants,
        "max_abs_difference_in_standard_errors": max(abs(c["difference_in_standard_errors"]) for c in constants.values()),
        "held_out": held_out,
        "reproduce": "python -m benchmarks.calibrate_model --check",
    }
    path = RESULTS / "calibration_check.json"
    path.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    for name, c in constants.items():
        print(f"  {name:36s} shipped {c['shipped']:.5g}, now {c['recalibrated']:.5g} ({c['difference_in_standard_errors']:+.2f} s.e.)")
    print(f"wrote {path}")
    return record


def held_out_by_group(cv: dict, groups: np.ndarray) -> dict:
    """Held-out CIEDE2000 median / p95 and RMS median per population group (with the prior)."""
    out = {}
    for label in sorted(set(groups), key=lambda g: (int(g.split(":")[0]) if g.split(":")[0].isdigit() else 0, g)):  # archive order
        at = groups == label
        out[label] = {"spectra": int(at.sum()), "delta_e2000_median": float(np.median(cv["delta_e2000"][at])),
                      "delta_e2000_p95": float(np.percentile(cv["delta_e2000"][at], 95)),
                      "rms_median": float(np.median(cv["rms_residual"][at]))}
    return out


def compare_methods(face, data: Path, folds: int, max_steps: int) -> dict:
    """Calibrate on each of ``METHODS`` from the same start and folds; write calibration_methods.*."""
    groups = np.array([f"{r['origin']}: {r['ethnic_group']}" for r in face.records])
    record = {**provenance(), "spectra": len(face.reflectance), "subjects": len(set(face.subjects)), "folds": folds,
              "outer_max_steps": max_steps, "methods": {}, "reproduce": "python -m benchmarks.calibrate_model --compare-methods"}
    for method in METHODS:
        print(f"calibrating on {method}")
        calibration = calibrate_model(WAVELENGTHS, face.reflectance, model=start_model(method), constants=DEFAULT_CONSTANTS,
                                      groups=face.subjects, folds=folds, max_steps=max_steps, name=f"{MODEL_NAME}-{method}",
                                      **MEASUREMENT)
        summary = calibration.record()
        nist = nist_check(data, calibration.model)
        record["methods"][method] = {
            "constants": calibration.constants, "standard_errors": calibration.standard_errors,
            "outer_cost": calibration.history[-1], "outer_steps": len(calibration.history),
            "calibration_seconds": calibration.seconds, "in_sample": summary["in_sample"],
            "held_out": summary["cross_validation"]["with_prior"],
            "held_out_maximum_likelihood": summary["cross_validation"]["maximum_likelihood"],
            "held_out_by_group": held_out_by_group(calibration.cross_validation, groups),
            "nist": nist["calibrated"], "nist_repeat_spread_rms_median": nist["repeat_spread_rms_median"],
        }
        print(f"  held out: CIEDE2000 median {summary['cross_validation']['with_prior']['delta_e2000_median']:.3f}")
    (RESULTS / "calibration_methods.json").write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    (RESULTS / "calibration_methods.md").write_text(methods_markdown(record), encoding="utf-8")
    print(f"wrote {RESULTS / 'calibration_methods.json'} and calibration_methods.md")
    return record


def methods_markdown(record: dict) -> str:
    """The transport-against-diffusion table of docs/model.md, from the saved record."""
    t, d = record["methods"]["transport"], record["methods"]["diffusion"]
    lines = [
        f"Measured {record['date']} ({record['machine']}), `{record['reproduce']}`: the same constants calibrated from the same "
        f"start on {record['spectra']:,} ISSA face spectra of {record['subjects']} subjects, held out in {record['folds']} subject folds.",
        "",
        "| | tabulated transport (shipped) | DJ2005 diffusion |",
        "|---|---|---|",
    ]
    for name in t["constants"]:
        lines.append(f"| `{name}` | {t['constants'][name]:.4g} ± {t['standard_errors'][name]:.2g} | "
                     f"{d['constants'][name]:.4g} ± {d['standard_errors'][name]:.2g} |")
    lines.append(f"| outer cost (steps) | {t['outer_cost']:.4f} ({t['outer_steps']}) | {d['outer_cost']:.4f} ({d['outer_steps']}) |")
    for label, key in (("held out, CIEDE2000 median / p95", "held_out"), ("held out, maximum likelihood, CIEDE2000 median / p95",
                                                                           "held_out_maximum_likelihood")):
        lines.append(f"| {label} | {t[key]['delta_e2000_median']:.3f} / {t[key]['delta_e2000_p95']:.2f} | "
                     f"{d[key]['delta_e2000_median']:.3f} / {d[key]['delta_e2000_p95']:.2f} |")
    lines.append(f"| held out, RMS median | {t['held_out']['rms_median']:.4f} | {d['held_out']['rms_median']:.4f} |")
    lines.append(f"| held out, MAX_STEPS | {t['held_out']['max_steps']} | {d['held_out']['max_steps']} |")
    for label in t["held_out_by_group"]:
        a, b = t["held_out_by_group"][label], d["held_out_by_group"][label]
        lines.append(f"| held out, {label} ({a['spectra']} spectra), CIEDE2000 median / p95 | {a['delta_e2000_median']:.3f} / "
                     f"{a['delta_e2000_p95']:.2f} | {b['delta_e2000_median']:.3f} / {b['delta_e2000_p95']:.2f} |")
    lines.append(f"| NIST forearm (never calibrated on), CIEDE2000 median / p95 | {t['nist']['delta_e2000_median']:.3f} / "
                 f"{t['nist']['delta_e2000_p95']:.2f} | {d['nist']['delta_e2000_median']:.3f} / {d['nist']['delta_e2000_p95']:.2f} |")
    lines.append(f"| NIST forearm, RMS median (repeat spread {t['nist_repeat_spread_rms_median']:.4f}) | {t['nist']['rms_median']:.4f} | "
                 f"{d['nist']['rms_median']:.4f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"), help="the shared data folder")
    parser.add_argument("--folds", type=int, default=5, help="subject folds for cross-validation (0: none)")
    parser.add_argument("--max-steps", type=int, default=40, help="outer Levenberg-Marquardt steps")
    parser.add_argument("--subsample", type=int, default=0, help="use this many face spectra (0: all), for a quick run")
    parser.add_argument("--write-model", action="store_true", help="write spectra/calibrated_model.json")
    parser.add_argument("--model-out", default=None, help="also write the model to this JSON file")
    parser.add_argument("--report-only", action="store_true", help="only redo the report of the shipped model (no calibration)")
    parser.add_argument("--check", action="store_true",
                        help="recalibrate on the current code and compare with the shipped model (writes calibration_check.json only)")
    parser.add_argument("--compare-methods", action="store_true",
                        help="calibrate on tabulated transport and on diffusion; write calibration_methods.{json,md} only")
    args = parser.parse_args(argv)
    data = Path(args.data)

    face = face_spectra(data)
    if args.subsample:
        keep = np.random.default_rng(0).choice(len(face.reflectance), args.subsample, replace=False)
        face = face.select(np.sort(keep))
    print(f"ISSA subset, face sites: {len(face.reflectance)} spectra of {len(set(face.subjects))} subjects")

    if args.report_only:  # the shipped model's report, keeping the saved calibration record
        path = RESULTS / "calibration.json"
        record = json.loads(path.read_text(encoding="utf-8"))
        record["report"] = report(face, skinfit.SkinModel.calibrated(), data)
        path.write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
        write_summary(record)
        print(f"wrote the report into {path} and calibration_summary.md")
        return 0
    if args.compare_methods:
        compare_methods(face, data, args.folds, args.max_steps)
        return 0

    calibration = calibrate_model(WAVELENGTHS, face.reflectance, model=start_model(), constants=DEFAULT_CONSTANTS,
                                  groups=face.subjects, folds=args.folds, max_steps=args.max_steps, name=MODEL_NAME, **MEASUREMENT)
    seconds = calibration.seconds
    print(f"calibrated on {len(face.reflectance)} spectra in {seconds:.0f} s")
    for name, value in calibration.constants.items():
        print(f"  {name:36s} {value:10.5g} +- {calibration.standard_errors[name]:.2g} (Gauss-Newton +- {calibration.naive_standard_errors[name]:.2g})")
    model = calibration.model
    if args.check:
        write_check(calibration, args.folds)
        return 0

    cv = calibration.record().get("cross_validation")
    if cv is not None:
        for label, part in (("with the prior (default)", cv["with_prior"]), ("maximum likelihood", cv["maximum_likelihood"])):
            print(f"cross-validated ({args.folds} subject folds), {label}: CIEDE2000 median {part['delta_e2000_median']:.3f}, "
                  f"p95 {part['delta_e2000_p95']:.3f}, RMS median {part['rms_median']:.4f}, success {100 * part['success_fraction']:.1f} %, "
                  f"MAX_STEPS {part['max_steps']}, on a bound {100 * part['on_bound_fraction']:.1f} %")

    results = report(face, model, data)
    nist = results["nist"]
    print(f"NIST (forearm, port 2.5 mm): RMS median {nist['calibrated']['rms_median']:.4f} (DJ2006 {nist['dj2006']['rms_median']:.4f}; "
          f"repeat spread {nist['repeat_spread_rms_median']:.4f})")

    record = {
        "model": MODEL_NAME,
        "date": datetime.date.today().isoformat(),
        "commit": subprocess.run(["git", "describe", "--always", "--dirty"], capture_output=True, text=True, cwd=ROOT).stdout.strip(),
        "machine": f"{platform.machine()}, {platform.processor() or 'cpu'}, python {platform.python_version()}",
        "data": {"issa_face": {"spectra": len(face.reflectance), "subjects": len(set(face.subjects)), "sites": list(FACE_SITES),
                               "wavelengths_nm": [400, 700, 10]},
                 "measurement": MEASUREMENT, "source": "ISSA subset (Lu et al. 2025, DOI 10.1038/s41597-025-04857-5)"},
        "calibration_seconds": seconds,
        "start": "SkinModel.dj2006(method=Transport.tabulated())",
        **{k: v for k, v in calibration.record().items() if k != "cross_validation"},
        "cross_validation": cv,
        "report": results,
        "reproduce": "python -m benchmarks.calibrate_model --write-model",
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "calibration.json").write_text(json.dumps(record, indent=2) + "\n", encoding="utf-8")
    write_summary(record)
    print(f"wrote {RESULTS / 'calibration.json'} and calibration_summary.md")
    shipped_record = model_record(record)
    if args.model_out:
        model.save(args.model_out, calibration=shipped_record)
    if args.write_model:
        path = ROOT / "spectra" / "calibrated_model.json"
        model.save(path, calibration=shipped_record)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
