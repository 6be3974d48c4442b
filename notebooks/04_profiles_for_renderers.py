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
# # 04 · Profiles for renderers: tables, Gaussians, Burley, pbrt-v4 and Blender
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
from skinfit import renderers

results = {name: skinfit.renderer_profiles(skinfit.preset(name), label=name) for name in skinfit.PRESET_NAMES}
rows = []
for name, r in results.items():
    for i, c in enumerate(renderers.CHANNELS):
        g, b = r.gaussians[c], r.burley[c]
        rows.append(f"{name:6s} {c:5s} albedo {r.rgb_albedo[i]:.4f}  Gaussians {100 * g['energy_error']:5.2f} % "
                    f"(L1 {100 * g['density_l1_error']:5.2f} %)  Burley d {b['shape_mm']:.3f} mm {100 * b['energy_error']:5.1f} % "
                    f"(L1 {100 * b['density_l1_error']:5.1f} %)  mfp {r.medium['mean_free_path_mm'][i]:.4f} mm")
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
    for i, c in enumerate(renderers.CHANNELS):
        g, b = r.gaussians[c], r.burley[c]
        ax.plot(radii, radii * r.rgb[i] / r.metadata["rgb_scale"][i], color=colours[i], lw=2, label=f"{c} model" if name == "light" else None)
        ax.plot(radii, radii * renderers.gaussian_sum(radii, g["variances_mm2"], g["weights"]), color=colours[i], ls="--", lw=1)
        ax.plot(radii, radii * renderers.burley_profile(radii, b["albedo"], b["shape_mm"]), color=colours[i], ls=":", lw=1)
    ax.set_xscale("log")
    ax.set_xlabel("r (mm)")
    ax.set_title(f"{name}: model (solid), 6 Gaussians (dashed), Burley (dotted)", fontsize=9)
axes[0].set_ylabel("r R(r) (mm^-1)")
axes[0].legend(fontsize=8)
fig.tight_layout()
fig.savefig("04_profiles_for_renderers.png", dpi=100)

# %% [markdown]
# ## pbrt-v4
#
# A `subsurface` material with the per-channel medium (g = 0, so sigma_s is the reduced
# scattering); `scale` converts the coefficients from mm^-1 to a scene in metres. pbrt then runs
# its own transport (photon beam diffusion), so its profile is not ours exactly: the Burley errors
# above say how far a simple analytic shape is from this model.

# %%
for name, r in results.items():
    print(renderers.pbrt_v4_material(r, name=f"skin_{name}"))

# %% [markdown]
# ## Blender (Principled BSDF)
#
# Base colour = the linear-sRGB albedo, subsurface radius = the mean free path per channel in mm,
# subsurface scale 0.001 (mm to metres). In Blender's Python console:
# `bsdf.inputs["Subsurface Radius"].default_value = radius` and so on.

# %%
for name, r in results.items():
    values = renderers.blender_principled(r)
    print(name, {k: (np.round(v, 4).tolist() if isinstance(v, list) else v) for k, v in values.items() if k != "note"})
