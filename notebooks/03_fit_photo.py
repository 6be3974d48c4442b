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
# The bundled photo is NASA's public-domain portrait of astronaut Eileen Collins, 512 x 512 (`data/README.md`):
# an ordinary studio portrait, with a flag, a shuttle model, an orange suit and a helmet around the face. Nothing
# is prepared for it: `fit_image` finds the face with the shipped face models (a face detector and a 468-point
# face mesh, MediaPipe's, Apache-2.0), fits the skin of the face, ears and neck, and leaves the eyes, brows, lips,
# nostrils, hair, clothes and background out (`MASKED`; the `region` map says which is which).
#
# The camera model: a pixel's linear sRGB (IEC 61966-2-1 primaries, D65 white = 1) is
# `white balance x shading x (the calibrated model's reflectance through the CIE 1931 observer under D65)`.
# Three channels carry three unknowns per pixel: melanin, haemoglobin and shading. What a face shares is
# fitted once: the white balance (camera gains, from the face's skin, within a camera prior of 15 % per
# channel) and the melanin blend (per face: measured in an albedo capture; in a photo, whose shading is free,
# mostly the population's, with its uncertainty carried into the melanin's standard errors). Per pixel the fit is a MAP estimate under the
# calibrated model's population prior, the fold of the colour map (two parameter sets, one colour) is
# resolved against the smooth shading of the neighbourhood, and a light edge-preserving prior ties each pixel
# to its neighbourhood's median.

# %%
from pathlib import Path
import warnings

import matplotlib.pyplot as plt
import numpy as np

import skinfit
from skinfit.fit import speckle_fraction
from skinfit.colorimetry import srgb_encode
from skinfit.io import read_linear_rgb
from skinfit.segmentation import FaceRegion

# the repository: from notebooks/ in Jupyter, docs/notebooks/ in the site build, or run as a script
HERE = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()
ROOT = next(p for p in [HERE, *HERE.parents] if (p / "pyproject.toml").is_file())
PHOTO = ROOT / "data" / "astronaut_eileen_collins.png"
photo, _ = read_linear_rgb(PHOTO)  # 8-bit sRGB through its embedded ICC profile, to linear
fit = skinfit.fit_image(PHOTO, progress=False)
print(fit.summary())

# %% [markdown]
# ## Which pixels the skin model explains
# `SUCCESS`: reproduced within CIEDE2000 1 with parameters skin has. `NOT_SKIN`: fitted only at the box's
# edge, far outside the population or with a shading 3x off its neighbourhood. `SPECULAR`: the
# neighbourhood's skin colour plus white light. `MASKED`: not the skin of a face.

# %%
face_skin = fit.region == FaceRegion.SKIN
for region in FaceRegion:
    print(f"{region.name:<11} {int(np.sum(fit.region == region)):7d} pixels")
for status in skinfit.PixelStatus:
    count = int(np.sum(fit.status[face_skin] == status))
    if count:
        print(f"{status.name:<13} {count:6d} face-skin pixels ({100 * count / face_skin.sum():.1f} %)")
skin = fit.skin_mask
delta_e = fit.residual_dE2000[face_skin]
print(f"CIEDE2000 over the face's skin: median {np.median(delta_e):.2g}, 95th percentile {np.percentile(delta_e, 95):.2g}")
print(f"melanin off its 3x3 median by 2x: {100 * speckle_fraction(fit.melanin, skin):.2f} % of skin pixels")
assert fit.faces == 1 and skin[face_skin].mean() >= 0.9 and np.median(delta_e) <= 0.2
assert not skin[~face_skin].any()  # nothing but the face's skin is fitted

# %% [markdown]
# ## The regions, the maps, their standard errors, and a blush re-rendered
# The standard errors are the Laplace approximation at the fit (`colour_noise` 0.3 % per channel): large
# where haemoglobin barely moves the colour and along the fold. The edit doubles haemoglobin and renders
# the maps through the exact forward model and the same camera model.

# %%
to_srgb = lambda linear: np.asarray(srgb_encode(np.clip(linear, 0, 1)))  # noqa: E731
blush = np.where(skin[..., None], fit.render(scale_haemoglobin=2.0), photo)
reconstruction = np.where(skin[..., None], fit.fitted_linear_rgb, 0.3 * photo)
rows, cols = np.nonzero(fit.region > 0)
window = slice(rows.min() - 10, rows.max() + 10), slice(cols.min() - 10, cols.max() + 10)  # the face
region_colours = np.array([[0, 0, 0], [0.2, 0.85, 0.2], [0.9, 0.2, 0.9], [1, 0.6, 0.1], [0.95, 0.1, 0.1], [0.1, 0.9, 0.9],
                           [1, 1, 0.1], [0.2, 0.3, 1]])

fig, axes = plt.subplots(2, 4, figsize=(15, 8))
axes[0, 0].imshow(to_srgb(photo))
axes[0, 0].set_title("photo")
axes[0, 1].imshow(np.where(fit.region[..., None] > 0, 0.55 * to_srgb(photo) + 0.45 * region_colours[fit.region], to_srgb(photo))[window])
axes[0, 1].set_title("regions: skin green, eyes magenta, brows orange,\nlips red, mouth cyan, other blue", fontsize=8)
axes[0, 2].imshow(to_srgb(reconstruction)[window])
axes[0, 2].set_title("reconstruction (skin)")
for ax, name, cmap in ((axes[0, 3], "melanin", "copper_r"), (axes[1, 0], "haemoglobin", "Reds"),
                       (axes[1, 1], "melanin_se", "viridis")):
    values = getattr(fit, name)
    image = ax.imshow(np.ma.masked_where(~skin, values)[window], cmap=cmap, vmin=0, vmax=np.percentile(values[skin], 99))
    fig.colorbar(image, ax=ax, fraction=0.046)
    ax.set_title(name.replace("_se", " standard error"))
image = axes[1, 2].imshow(np.ma.masked_where(~face_skin, fit.residual_dE2000)[window], cmap="magma", vmin=0, vmax=1)
fig.colorbar(image, ax=axes[1, 2], fraction=0.046)
axes[1, 2].set_title("CIEDE2000")
axes[1, 3].imshow(to_srgb(blush)[window])
axes[1, 3].set_title("blush: haemoglobin x 2")
for ax in axes.ravel():
    ax.axis("off")
fig.tight_layout()
plt.show()

# %% [markdown]
# ## An albedo capture
# A cross-polarised albedo capture (BioSkin's test capture 2, MIT, downscaled 4x; `tests/data/README.md`)
# has no specular light and a near-uniform shading. It goes through the same call: the face models find the
# face (eyes closed), and the white balance, which the capture does not document, is fitted within the
# camera prior. Where the balance is known (a calibrated capture in linear sRGB), `white_balance="none"`.

# %%
capture = ROOT / "tests" / "data" / "face2_albedo_quarter.png"
albedo_fit = skinfit.fit_image(capture, progress=False)
albedo_skin = albedo_fit.region == FaceRegion.SKIN
print(f"{albedo_fit.faces} face; {100 * albedo_fit.skin_mask[albedo_skin].mean():.1f} % of its skin fitted, "
      f"CIEDE2000 median {np.median(albedo_fit.residual_dE2000[albedo_skin]):.2g}; "
      f"white balance {np.round(albedo_fit.white_balance, 3)} +- {np.round(albedo_fit.white_balance_sd, 3)} (relative)")
fig, axes = plt.subplots(1, 3, figsize=(9, 4.5))
albedo, _ = read_linear_rgb(capture)
axes[0].imshow(to_srgb(albedo))
axes[0].set_title("capture")
axes[1].imshow(np.ma.masked_where(~albedo_fit.skin_mask, albedo_fit.melanin), cmap="copper_r")
axes[1].set_title("melanin")
axes[2].imshow(np.ma.masked_where(~albedo_fit.skin_mask, albedo_fit.haemoglobin), cmap="Reds")
axes[2].set_title("haemoglobin")
for ax in axes:
    ax.axis("off")
fig.tight_layout()

# %% [markdown]
# ## When a photo fails
# - **No face is found** (a face under ~30 pixels, a profile beyond ~60 degrees, a face upside down, skin
#   that is not a face): `fit_image` warns and fits every pixel, the skin model's gamut deciding what is
#   skin, which lets skin-coloured wood, sand or cloth in. Give a mask (`mask=`, `--mask`): it always wins.
# - **The white balance looks wrong** (the summary's gains far from 1, or their standard errors large):
#   give the gains (`white_balance=(r, g, b)`), or put a ColorChecker in the frame (`white_balance="chart"`).
# - **A file is damaged** (a truncated JPEG): it is refused with a one-line error rather than fitted.
#
# A crop of the wall and flag behind the astronaut has no face: the warning says so, and with
# `segmentation="none"` the model's gamut alone decides (here it takes the beige wall as light skin, which is
# why the face models decide by default).

# %%
wall = photo[:140, :140]
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    wall_fit = skinfit.fit_image(wall, progress=False)
print([str(w.message) for w in caught if "no face" in str(w.message)])
print(f"faces found: {wall_fit.faces}; pixels the gamut rule calls skin: {100 * wall_fit.skin_mask.mean():.1f} %")
assert wall_fit.faces == 0

# %% [markdown]
# ## What the priors do
# Without them (`prior=False`: maximum likelihood per pixel, the white balance from the gamut alone) the
# same pixels are fitted exactly, but pixels fall on either branch of the fold and the maps speckle.

# %%
mask = face_skin
ml = skinfit.fit_image(photo, mask=mask, prior=False, progress=False)
ml_skin = ml.status == skinfit.PixelStatus.SUCCESS
print(f"maximum likelihood: {100 * ml_skin[mask].mean():.1f} % of the face's skin SUCCESS, "
      f"speckle {100 * speckle_fraction(ml.melanin, ml_skin):.2f} %, white balance {np.round(ml.white_balance, 3)}")
print(f"MAP + coherence:    {100 * skin[mask].mean():.1f} % of the face's skin SUCCESS, "
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
