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
# # 04 · Profiles for renderers: tables, Gaussians, Burley, pbrt-v4, Mitsuba 3 and Blender
#
# The DJ2006 presets' radial profiles (linear sRGB under D65, mm^-2, integrating to the diffuse
# reflectance), and the forms renderers read: a sum of six Gaussians per channel (d'Eon & Luebke),
# Christensen-Burley parameters, and a homogeneous medium per channel for pbrt-v4's `subsurface`
# material and Blender's Principled BSDF. Errors are fractions of each channel's energy: the
# largest misplaced energy max_r |E_fit(r) - E(r)| and the L1 density error.

# %%
import matplotlib.pyplot as plt
import numpy as np

import skinfit
from skinfit import export

results = {name: skinfit.renderer_profiles(skinfit.preset(name), label=name) for name in skinfit.PRESET_NAMES}
rows = []
for name, r in results.items():
    for i, c in enumerate(export.CHANNELS):
        g, b = r.gaussians[c], r.burley[c]
        rows.append(f"{name:6s} {c:5s} albedo {r.rgb_albedo[i]:.4f}  Gaussians {100 * g['energy_error']:5.2f} % "
                    f"(L1 {100 * g['density_l1_error']:5.2f} %)  Burley d {b['shape_mm']:.3f} mm {100 * b['energy_error']:5.1f} % "
                    f"(L1 {100 * b['density_l1_error']:5.1f} %)  mfp {r.medium.mean_free_path_mm[i]:.4f} mm")
    rows.append(f"{name:6s} table radii {r.radii_mm[0]:.2e}-{r.max_radius_mm:.3f} mm (99.7 % of the energy)")
print("\n".join(rows))

# %% [markdown]
# Side by side: the model's profile (r·R(r), which shows where the energy sits on a log axis), the
# six-Gaussian fit and the Burley fit, per channel.

# %%
fig, axes = plt.subplots(1, 3, figsize=(14, 4), sharey=False)
colours = ("tab:red", "tab:green", "tab:blue")
for ax, (name, r) in zip(axes, results.items()):
    radii = r.radii_mm
    for i, c in enumerate(export.CHANNELS):
        g, b = r.gaussians[c], r.burley[c]
        ax.plot(radii, radii * r.rgb[i] / r.metadata["rgb_scale"][i], color=colours[i], lw=2, label=f"{c} model" if name == "light" else None)
        ax.plot(radii, radii * export.gaussian_sum(radii, g["variances_mm2"], g["weights"]), color=colours[i], ls="--", lw=1)
        ax.plot(radii, radii * export.burley_profile(radii, b["albedo"], b["shape_mm"]), color=colours[i], ls=":", lw=1)
    ax.set_xscale("log")
    ax.set_xlabel("r (mm)")
    ax.set_title(f"{name}: model (solid), 6 Gaussians (dashed), Burley (dotted)", fontsize=9)
axes[0].set_ylabel("r R(r) (mm^-1)")
axes[0].legend(fontsize=8)
fig.tight_layout()
plt.show()

# %% [markdown]
# ## Media for path tracers
#
# pbrt-v4, Mitsuba 3 and Blender Cycles trace light through a medium behind a dielectric boundary,
# which is exact transport. Each RGB channel (or wavelength) gets the semi-infinite homogeneous
# medium whose *exact* transport has the channel's albedo (adding-doubling) and its median
# energy radius (Monte Carlo): a medium matched through diffusion theory, as before, renders up
# to 30 % too dark. The conventions each export assumes are written into it.

# %%
for name, r in results.items():
    m = r.medium
    print(f"{name:7s} albedo {np.round(r.rgb_albedo, 4)}  single-scattering albedo {np.round(m.single_scattering_albedo, 4)}  "
          f"sigma_t {np.round(m.extinction_per_mm, 2)} mm^-1  median radius {np.round(m.median_radius_mm, 4)} mm")
print(results["light"].medium.conventions.describe())

# %% [markdown]
# ## pbrt-v4
#
# A `subsurface` material with sigma_a and sigma_s per channel (isotropic phase function), `eta`
# 1.4, `scale` = mm per scene unit (1000 for a scene in metres). pbrt-v4 renders it with its
# photon-beam-diffusion BSSRDF, an approximation of the exact transport it was matched with.

# %%
print(export.pbrt_v4_material(results["light"], name="skin_light"))

# %% [markdown]
# ## Mitsuba 3
#
# `skinfit profiles --format mitsuba` (or `mitsuba-spectral`) writes this XML; `skinfit.export`
# has the same as dictionaries for `mitsuba.load_dict`, and renders that check them. Here the
# medium preset in the reference slab (white environment, normal view, specular subtracted),
# with few samples: the test suite and `benchmarks/export.py` render with many more.

# %%

print(export.mitsuba_export(results["medium"]))
material = export.mitsuba_material(export.mitsuba_medium(results["medium"].medium), 1.4)
rendered, error = export.render_albedo(material, spp=2048)
print("Mitsuba / model:", np.round(rendered / results["medium"].rgb_albedo, 4), "+-", np.round(error / results["medium"].rgb_albedo, 4))
assert np.all(np.abs(rendered / results["medium"].rgb_albedo - 1) < np.maximum(0.02, 3 * error / results["medium"].rgb_albedo))

# %% [markdown]
# ## Blender (Principled BSDF)
#
# Cycles turns a base colour into a medium itself, and renders it darker than the base colour
# (Blender 4.2 LTS, random walk: 75-95 %). The export inverts the drift measured in that version
# (`benchmarks/measure_blender_drift.py`): the base colour that renders as the model's albedo, and
# the Subsurface Radius with which Cycles renders each channel's median energy radius. In
# Blender's Python console: `bsdf.inputs["Subsurface Radius"].default_value = radius` and so on.

# %%
for name, r in results.items():
    values = export.blender_principled(r)
    print(name, {k: (np.round(v, 4).tolist() if isinstance(v, list) else v) for k, v in values.items() if k != "note"})
