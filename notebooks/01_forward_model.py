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
# # 01 · The forward model
#
# The Donner & Jensen 2006 two-layer skin model on the closed-form DJ2005 multipole:
# chromophore spectra → layer optics → frequency-domain layer responses → adding → reflectance,
# colour and radial profiles. Units: nm, mm, mm⁻¹. Run it as a notebook (jupytext) or as a script.
# Everything here evaluates the paper's model (`SkinModel.dj2006()`, the `model=` of every call);
# the package default is the model calibrated on measured skin (notebook 05), compared at the end.

# %%
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import skinfit
from skinfit import model as chrom
from skinfit.colorimetry import linear_srgb_weights, spectrum_to_srgb
from skinfit.io import read_nist
from skinfit.model import profile

# the repository: from notebooks/ in Jupyter, docs/notebooks/ in the site build, or run as a script
HERE = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()
ROOT = next(p for p in [HERE, *HERE.parents] if (p / "pyproject.toml").is_file())
DATA = ROOT / "data"
DJ2006 = skinfit.SkinModel.dj2006()

# %% [markdown]
# ## Chromophore spectra
# Melanins and baseline are Jacques's power laws; haemoglobin is Prahl's table at 150 g/L.
# The epidermis scatters twice as strongly as the dermis.

# %%
wl = np.arange(250.0, 1001.0, 2.0)
fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 3.8))
for f, label in [
    (chrom.eumelanin_absorption, "eumelanin"),
    (chrom.pheomelanin_absorption, "pheomelanin"),
    (chrom.oxyhaemoglobin_absorption, "HbO$_2$ (whole blood)"),
    (chrom.deoxyhaemoglobin_absorption, "Hb (whole blood)"),
    (chrom.baseline_absorption, "baseline"),
]:
    ax.semilogy(wl, f(wl), label=label)
ax.set(xlabel="wavelength (nm)", ylabel=r"$\sigma_a$ (mm$^{-1}$)", title="absorption")
ax.legend(frameon=False, fontsize=8)
bx.plot(wl, chrom.epidermis_reduced_scattering(wl), label="epidermis")
bx.plot(wl, chrom.dermis_reduced_scattering(wl), label="dermis")
bx.set(xlabel="wavelength (nm)", ylabel=r"$\sigma_s'$ (mm$^{-1}$)", title="reduced scattering")
bx.legend(frameon=False)
fig.tight_layout()

# %% [markdown]
# ## Reflectance of the presets, and measured skin for scale
# Diffuse reflectance at normal incidence, specular excluded, entry Fresnel included. The grey band
# is the range of the 100 NIST subjects; those measurements include the specular reflection
# (~0.028) and lose light beyond a 5 mm port, so they are not a like-for-like comparison (the
# fitting notebook models both).

# %%
wl = np.arange(400.0, 701.0, 5.0)
spectra = {name: np.asarray(skinfit.diffuse_reflectance(skinfit.preset(name), wl, model=DJ2006)) for name in skinfit.PRESET_NAMES}
nist = read_nist(DATA / "nist_skin_reflectance_250-1000nm.csv")
band = np.array([np.interp(wl, nist.wavelengths_nm, s) for s in nist.average])

fig, (ax, sw) = plt.subplots(1, 2, figsize=(11, 3.8), gridspec_kw={"width_ratios": [3, 1]})
ax.fill_between(wl, band.min(0), band.max(0), color="0.85", label="NIST, 100 subjects")
for name, r in spectra.items():
    srgb = np.asarray(spectrum_to_srgb(r, wl))
    ax.plot(wl, r, color=srgb, lw=3, label=name)
    ax.plot(wl, r, color="k", lw=0.4)
ax.set(xlabel="wavelength (nm)", ylabel="reflectance", ylim=(0, None))
ax.legend(frameon=False)
for i, (name, r) in enumerate(spectra.items()):
    sw.add_patch(plt.Rectangle((i, 0), 0.9, 1, color=np.asarray(spectrum_to_srgb(r, wl))))
    sw.text(i + 0.45, -0.12, name, ha="center")
sw.set(xlim=(-0.1, 3), ylim=(-0.25, 1.05), title="sRGB (D65)")
sw.axis("off")
fig.tight_layout()

# %% [markdown]
# ## Directional against symmetric adding
# The top face borders air, the bottom face tissue: light returning from the dermis sees a very
# different epidermis (R1⁻ ≫ R1⁺). The symmetric form of DJ2005/pbrt-v2-skin ignores this and is
# 12-20 % too bright for light skin against Monte Carlo (model notes 5.5).

# %%
light = skinfit.preset("light")
directional = np.asarray(skinfit.diffuse_reflectance(light, wl, model=DJ2006))
symmetric = np.asarray(skinfit.diffuse_reflectance(light, wl, model=DJ2006, adding="symmetric"))
print("light skin, symmetric / directional - 1 at 450/550/650 nm:",
      np.round((symmetric / directional - 1)[[10, 30, 50]], 3))
# The model notes 5.4 fixture, times the entry transmittance 1 - F0:
fixture = (1 - 1 / 36) * np.array([0.3553, 0.3893, 0.5209])
assert np.allclose(directional[[10, 30, 50]], fixture, atol=1e-4)

# %% [markdown]
# ## Radial profiles
# R(r, λ) in mm⁻² from an inverse Hankel transform of R12(q). Plotted as 2πr²R(r), the energy per
# unit ln r, so the area under each curve on the log axis is the reflectance. Red light spreads
# millimetres through the dermis; blue stays within a fraction of a millimetre.

# %%
radii = np.geomspace(1e-3, 30.0, 256)
fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
for ax, name in zip(axes, skinfit.PRESET_NAMES):
    values = np.asarray(profile(skinfit.preset(name), np.array([450.0, 550.0, 650.0]), radii, model=DJ2006))
    for v, c, lam in zip(values, ("tab:blue", "tab:green", "tab:red"), (450, 550, 650)):
        ax.loglog(radii, np.maximum(2 * np.pi * radii**2 * v, 1e-12), color=c, label=f"{lam} nm")
    ax.set(xlabel="r (mm)", title=name, ylim=(1e-6, 1))
axes[0].set_ylabel(r"$2\pi r^2 R(r)$")
axes[0].legend(frameon=False)
fig.tight_layout()

# Energy check: the profile integrates to R12(0).
values = np.asarray(profile(light, wl, np.geomspace(1e-5, 200, 4000), model=DJ2006))
rr = np.geomspace(1e-5, 200, 4000)
energy = np.trapezoid(2 * np.pi * rr**2 * values, np.log(rr), axis=-1)
r12 = np.asarray(skinfit.model.stack_transfer(skinfit.model.skin_layers(light, wl, model=DJ2006), 0.0))
print(f"max |energy / R12(0) - 1| over 61 wavelengths: {np.max(np.abs(energy / r12 - 1)):.1e}")
assert np.max(np.abs(energy / r12 - 1)) < 1e-6

# %% [markdown]
# ## RGB profiles for rendering
# The linear-sRGB profile is the colour-weighted sum of the spectral ones. sRGB's negative lobes can
# make the green and blue channels slightly negative in the far tail, where only red light remains.

# %%
rgb = linear_srgb_weights(wl) @ np.asarray(profile(light, wl, radii, model=DJ2006))
fig, ax = plt.subplots(figsize=(5, 3.6))
for channel, c in zip(rgb, ("tab:red", "tab:green", "tab:blue")):
    ax.loglog(radii, np.abs(2 * np.pi * radii**2 * channel), color=c)
ax.set(xlabel="r (mm)", ylabel=r"$|2\pi r^2 R_c(r)|$", title="light skin, linear sRGB", ylim=(1e-7, 1))
fig.tight_layout()
plt.show()


# %% [markdown]
# ## DJ2006 against the calibrated default
# The same presets through the package default (`SkinModel.default()`: DJ2006's chromophores on
# tabulated transport, a 60 µm epidermis and constants calibrated on measured face spectra).
# The presets' parameters were chosen for DJ2006, so the same numbers give other colours.

# %%
calibrated = skinfit.SkinModel.default()
print(calibrated.description)
fig, ax = plt.subplots(figsize=(7, 3.5))
for i, name in enumerate(skinfit.PRESET_NAMES):
    ax.plot(wl, spectra[name], color=f"C{i}", label=f"{name}, DJ2006")
    ax.plot(wl, np.asarray(skinfit.diffuse_reflectance(skinfit.preset(name), wl, model=calibrated)), "--", color=f"C{i}",
            label=f"{name}, calibrated")
ax.set(xlabel="wavelength (nm)", ylabel="diffuse reflectance")
ax.legend(frameon=False, ncol=2, fontsize=8)
fig.tight_layout()
