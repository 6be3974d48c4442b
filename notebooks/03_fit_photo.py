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
# # 03 · From a photo to melanin and haemoglobin maps, and back
#
# The bundled photo is a crop of NASA's public-domain portrait of astronaut Eileen Collins
# (`data/README.md`), with a skin mask made for it without the skin model (`benchmarks/demo_skin_mask.py`).
# The camera model: a pixel's linear sRGB (IEC 61966-2-1 primaries, D65 white = 1) is
# `white balance x shading x (the calibrated model's reflectance through the CIE 1931 observer under D65)`.
#
# Three channels carry three unknowns per pixel: melanin, haemoglobin and shading. What a face shares is
# fitted once: the white balance (camera gains, from the skin pixels under the population prior) and the
# melanin blend (the population's mean). Per pixel the fit is a MAP estimate under the calibrated model's
# population prior, the fold of the colour map (two parameter sets, one colour) is resolved against the
# smooth shading of the neighbourhood, and a light edge-preserving prior ties each pixel to its
# neighbourhood's median.

# %%
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import skinfit
from skinfit.fit import speckle_fraction
from skinfit.colorimetry import srgb_encode
from skinfit.io import read_linear_rgb, read_mask

HERE = Path.cwd() if "__file__" not in globals() else Path(__file__).resolve().parent
photo, _ = read_linear_rgb(HERE.parent / "data" / "eileen_collins_face.png")  # 8-bit sRGB decoded to linear
mask = read_mask(HERE.parent / "data" / "eileen_collins_skin_mask.png") > 0
fit = skinfit.fit_image(photo, mask=mask, progress=False)
print(fit.summary())

# %% [markdown]
# ## Which pixels the skin model explains
# `SUCCESS`: reproduced within CIEDE2000 1 with parameters skin has. `NOT_SKIN`: fitted only at the box's
# edge, far outside the population or with a shading 3x off its neighbourhood (hair, brows). `SPECULAR`:
# the neighbourhood's skin colour plus white light. `MASKED`: outside the skin mask.

# %%
for status in skinfit.PixelStatus:
    count = int(np.sum(fit.status[mask] == status))
    if count:
        print(f"{status.name:<13} {count:6d} skin-mask pixels ({100 * count / mask.sum():.1f} %)")
skin = fit.skin_mask
delta_e = fit.residual_dE2000[mask]
print(f"CIEDE2000 over the mask: median {np.median(delta_e):.2g}, 95th percentile {np.percentile(delta_e, 95):.2g}")
print(f"melanin off its 3x3 median by 2x: {100 * speckle_fraction(fit.melanin, skin):.2f} % of skin pixels")
# the bars of the demo job (tests/cli/test_main.py), on the same photo and mask
assert skin[mask].mean() >= 0.95 and np.median(delta_e) <= 0.2 and np.percentile(delta_e, 95) <= 0.7
assert speckle_fraction(fit.melanin, skin) < 0.02

# %% [markdown]
# ## The maps, their standard errors, and a blush re-rendered
# The standard errors are the Laplace approximation at the fit (`colour_noise` 0.3 % per channel): large
# where haemoglobin barely moves the colour and along the fold. The edit doubles haemoglobin and renders
# the maps through the exact forward model and the same camera model.

# %%
to_srgb = lambda linear: np.asarray(srgb_encode(np.clip(linear, 0, 1)))  # noqa: E731
blush = np.where(skin[..., None], fit.render(scale_haemoglobin=2.0), photo)
reconstruction = np.where(skin[..., None], fit.fitted_linear_rgb, 0.3 * photo)

fig, axes = plt.subplots(2, 4, figsize=(15, 8))
axes[0, 0].imshow(to_srgb(photo))
axes[0, 0].set_title("photo")
axes[0, 1].imshow(to_srgb(reconstruction))
axes[0, 1].set_title("reconstruction (skin)")
for ax, name, cmap in ((axes[0, 2], "melanin", "copper_r"), (axes[0, 3], "haemoglobin", "Reds"),
                       (axes[1, 0], "melanin_se", "viridis"), (axes[1, 1], "haemoglobin_se", "viridis")):
    values = getattr(fit, name)
    image = ax.imshow(np.ma.masked_where(~skin, values), cmap=cmap, vmin=0, vmax=np.percentile(values[skin], 99))
    fig.colorbar(image, ax=ax, fraction=0.046)
    ax.set_title(name.replace("_se", " standard error"))
image = axes[1, 2].imshow(np.ma.masked_where(~mask, fit.residual_dE2000), cmap="magma", vmin=0, vmax=1)
fig.colorbar(image, ax=axes[1, 2], fraction=0.046)
axes[1, 2].set_title("CIEDE2000")
axes[1, 3].imshow(to_srgb(blush))
axes[1, 3].set_title("blush: haemoglobin x 2")
for ax in axes.ravel():
    ax.axis("off")
fig.tight_layout()
fig.savefig("03_fit_photo_maps.png", dpi=100)

# %% [markdown]
# ## What the priors do
# Without them (`prior=False`: maximum likelihood per pixel, the white balance from the gamut alone) the
# same pixels are fitted exactly, but pixels fall on either branch of the fold and the maps speckle.

# %%
ml = skinfit.fit_image(photo, mask=mask, prior=False, progress=False)
ml_skin = ml.status == skinfit.PixelStatus.SUCCESS
print(f"maximum likelihood: {100 * ml_skin[mask].mean():.1f} % of the mask SUCCESS, "
      f"speckle {100 * speckle_fraction(ml.melanin, ml_skin):.2f} %, white balance {np.round(ml.white_balance, 3)}")
print(f"MAP + coherence:    {100 * skin[mask].mean():.1f} % of the mask SUCCESS, "
      f"speckle {100 * speckle_fraction(fit.melanin, skin):.2f} %, white balance {np.round(fit.white_balance, 3)}")
assert speckle_fraction(fit.melanin, skin) < speckle_fraction(ml.melanin, ml_skin)  # what the priors are for

# %% [markdown]
# ## Round trip: maps -> image -> maps
# Rendering the fitted maps and fitting the rendering again (calibrated input: no white balance; maximum
# likelihood) returns the maps where the colour map does not fold.

# %%
again = skinfit.fit_image(fit.fitted_linear_rgb / np.asarray(fit.white_balance), mask=skin, white_balance="none",
                          melanin_blend=float(fit.melanin_blend[skin][0]), prior=False, progress=False)
both = skin & (again.status == skinfit.PixelStatus.SUCCESS)
# 10x the median and 99th-percentile errors measured on 2026-12-02 (7.5e-9 / 6.0e-8, 3.7e-9 / 3.0e-8, 1.2e-7 / 4.8e-7)
bounds = {"melanin": (7.5e-8, 6e-7), "haemoglobin": (3.7e-8, 3e-7), "shading": (1.2e-6, 4.8e-6)}
for name, (median_bound, p99_bound) in bounds.items():
    error = np.abs(getattr(again, name) - getattr(fit, name))[both]
    print(f"{name:<12} round-trip error median {np.median(error):.1e}, 99th percentile {np.percentile(error, 99):.1e}")
    assert np.median(error) <= median_bound and np.percentile(error, 99) <= p99_bound
