# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # 05 · The calibrated model: what changed, and is the skin it finds real?
#
# skinfit's default model keeps the form of Donner & Jensen 2006 (epidermis over dermis, melanin,
# melanin blend, haemoglobin, oil) with constants calibrated on measured face spectra: the ISSA
# subset (Lu et al. 2025, DOI 10.1038/s41597-025-04857-5; d/8 spectrophotometer, specular included,
# 400-700 nm every 10 nm), by `python -m benchmarks.calibrate_model`. That script saved its record in
# `benchmarks/results/calibration.json`; this notebook reads it (the measured data are not shipped).
# Where `../shared/data` is present it also fits a sample of the spectra live.

# %%
import json
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import skinfit
from skinfit.fit import prior_table

# the repository: from notebooks/ in Jupyter, docs/notebooks/ in the site build, or run as a script
HERE = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()
ROOT = next(p for p in [HERE, *HERE.parents] if (p / "pyproject.toml").is_file())
record = json.loads((ROOT / "benchmarks" / "results" / "calibration.json").read_text())
report = record["report"]
model = skinfit.SkinModel.calibrated()
wl = np.arange(400.0, 701.0, 10.0)
print(model.description)

# %% [markdown]
# ## The constants
# Calibrated jointly over all face spectra (each spectrum keeps its own melanin, blend, haemoglobin
# and oil) by variable projection. The errors are subject-robust (a sandwich over the 1,156
# subjects); the Gauss-Newton ones assume independent residuals and are smaller. Fixed: the
# epidermis thickness (60 um; reflectance sees only the epidermis's optical thickness
# sigma_s' d, not d itself), the Mie powers (1), the surface index (1.55, stratum corneum).

# %%
dj = skinfit.SkinModel.dj2006()
rows = [("epidermis thickness (mm)", float(dj.epidermis_thickness_mm), float(model.epidermis_thickness_mm), None)]
for name, value in record["constants"].items():
    getter = name.split(".")
    ref = dj
    for part in getter:
        ref = getattr(ref, part)
    rows.append((name, float(ref), value, record["standard_errors"][name]))
print(f"{'constant':40s} {'DJ2006':>10s} {'calibrated':>12s} {'+-':>8s}")
for name, before, after, error in rows:
    print(f"{name:40s} {before:10.4g} {after:12.4g} {'' if error is None else f'{error:8.2g}'}")
print("epidermis reduced scattering at 500 nm (mm^-1):", float(dj.epidermis_scattering(500.0)), "->", float(model.epidermis_scattering(500.0)))
print("dermis reduced scattering at 500 nm (mm^-1):", float(dj.dermis_scattering(500.0)), "->", float(model.dermis_scattering(500.0)))

# %% [markdown]
# ## Residual by wavelength, before and after
# DJ2006's constants leave a systematic residual (too bright in the blue-green, too dark in the red)
# that no per-spectrum parameter can absorb; the calibrated model's mean residual is flat.

# %%
fig, ax = plt.subplots(figsize=(8, 4))
for label, colour in (("dj2006", "tab:red"), ("calibrated", "tab:blue")):
    mean, sd = np.array(report[label]["mean_residual"]), np.array(report[label]["sd_residual"])
    ax.plot(wl, mean, color=colour, label=f"{label}: CIEDE2000 median {report[label]['delta_e2000_median']:.2f}")
    ax.fill_between(wl, mean - sd, mean + sd, color=colour, alpha=0.15)
ax.axhline(0.0, color="k", lw=0.5)
ax.set(xlabel="wavelength (nm)", ylabel="fitted - measured", title=f"ISSA face spectra ({report['calibrated']['groups'] and sum(g['spectra'] for g in report['calibrated']['groups'].values())})")
ax.legend()
fig.tight_layout()

# %% [markdown]
# ## Cross-validated accuracy
# Subjects in five folds; each fold's spectra fitted with constants (and prior) calibrated without it.

# %%
cv = record["cross_validation"]
for label in ("with_prior", "maximum_likelihood"):
    part = cv[label]
    print(f"{label:20s} CIEDE2000 median {part['delta_e2000_median']:.3f}, p95 {part['delta_e2000_p95']:.3f}; RMS median "
          f"{part['rms_median']:.4f}; success {100 * part['success_fraction']:.1f} %, MAX_STEPS {part['max_steps']}, "
          f"on a bound {100 * part['on_bound_fraction']:.1f} %")

# %% [markdown]
# ## The skin it finds, by population group
# Published ranges for comparison: melanosome volume fraction of the epidermis 1.3-6.3 % in light
# skinned adults, 11-16 % moderately pigmented, 18-43 % darkly pigmented (S. L. Jacques, "Skin
# optics", OMLC News 1998, the source of DJ2006's melanin spectra; for a 60 um epidermis, as here);
# dermal blood volume a few percent (the range checked here is 0.1-10 %).

# %%
groups = report["calibrated"]["groups"]
quantiles = report["quantiles"]
fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
for ax, (name, scale, unit) in zip(axes, (("melanin", 100, "%"), ("haemoglobin", 100, "%"), ("melanin_blend", 1, ""))):
    labels = list(groups)
    for i, label in enumerate(labels):
        q = np.array(groups[label]["quantiles"][name]) * scale
        ax.plot([i, i], [q[0], q[-1]], color="0.6")
        ax.plot([i, i], [q[1], q[3]], color="tab:blue", lw=6)
        ax.plot(i, q[2], "wo", mec="k")
    ax.set_xticks(range(len(labels)), [label.split(": ")[1].split(" (")[0] + f" ({label.split(':')[0]})" for label in labels],
                  rotation=45, ha="right")
    ax.set(title=f"{name} (5-25-50-75-95 %)", ylabel=unit)
    if name != "melanin_blend":
        ax.set_yscale("log")
axes[0].axhspan(1.3, 6.3, color="gold", alpha=0.2, label="Jacques 1998 light")
axes[0].axhspan(18, 43, color="brown", alpha=0.15, label="Jacques 1998 dark")
axes[0].legend(fontsize=8)
axes[1].axhspan(0.1, 10, color="red", alpha=0.08)
fig.tight_layout()

for label, g in groups.items():
    q = g["quantiles"]
    print(f"{label:34s} melanin {100 * q['melanin'][2]:5.1f} %  haemoglobin {100 * q['haemoglobin'][2]:4.1f} %  blend {q['melanin_blend'][2]:.2f}  "
          f"on a bound {100 * g['on_bound_fraction']:4.1f} %  CIEDE2000 {g['delta_e2000_median']:.2f} / {g['delta_e2000_p95']:.2f}")

# %% [markdown]
# ## By body site

# %%
for label, g in report["calibrated"]["sites"].items():
    q = g["quantiles"]
    print(f"{label:12s} {g['spectra']:5d} spectra: melanin {100 * q['melanin'][2]:5.1f} %, haemoglobin {100 * q['haemoglobin'][2]:4.1f} %, "
          f"CIEDE2000 median {g['delta_e2000_median']:.2f}")

# %% [markdown]
# ## The population prior the model carries
# Median and 16-84 % of each fit variable over the calibration population (in physical units).
# `fit_spectra` uses it by default with this model (MAP fits); `prior=False` gives maximum likelihood.

# %%
for name, (median, low, high) in prior_table(model).items():
    print(f"{name:14s} {median:.4g}  ({low:.4g} - {high:.4g})")

# %% [markdown]
# ## NIST (inner forearm, another instrument): a check the calibration never saw

# %%
nist = report["nist"]
print(f"repeat spread (RMS, median over subjects): {nist['repeat_spread_rms_median']:.4f}")
for label in ("dj2006", "calibrated"):
    print(f"{label:10s} RMS median {nist[label]['rms_median']:.4f}, CIEDE2000 median {nist[label]['delta_e2000_median']:.2f}")

# %% [markdown]
# ## Live: a sample of the measured spectra, where the shared data are present

# %%
data = ROOT.parent / "shared" / "data" / "issa-subset" / "issa_subset.csv"
if data.exists():
    archive = skinfit.read_issa(data)
    face = archive.select([r["body_site"] in skinfit.io.FACE_SITES for r in archive.records]).complete(wl)
    pick = np.random.default_rng(0).choice(len(face.reflectance), 6, replace=False)
    fit = skinfit.fit_spectra(wl, face.reflectance[pick], specular_included_deg=8.0, bandwidth_nm=10.0, progress=False)
    old = skinfit.fit_spectra(wl, face.reflectance[pick], model=dj, specular_included_deg=8.0, bandwidth_nm=10.0, progress=False)
    fig, axes = plt.subplots(2, 3, figsize=(13, 6), sharex=True)
    for ax, i in zip(axes.flat, range(len(pick))):
        rec = face.records[pick[i]]
        ax.plot(wl, face.reflectance[pick[i]], "k.", label="measured")
        ax.plot(wl, fit.fitted[i], "tab:blue", label=f"calibrated, dE {fit.delta_e2000[i]:.2f}")
        ax.plot(wl, old.fitted[i], "tab:red", lw=0.8, label=f"DJ2006, dE {old.delta_e2000[i]:.2f}")
        ax.set_title(f"{rec['ethnic_group'][:14]} {rec['body_site']}", fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
else:
    print("../shared/data not present: the live part is skipped (everything above comes from the saved record)")
