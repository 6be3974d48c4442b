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
# (`data/README.md`). The camera model: a pixel's linear sRGB is
# `white balance x shading x (DJ2006 reflectance through the CIE 1931 observer under D65)`.
# Per pixel melanin, haemoglobin and shading are free; the melanin blend (0.7, DJ2006's value) and the
# white balance (camera gains, fitted once for the image) are shared by the whole image.

# %%
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import skinfit
from skinfit.colorimetry import srgb_encode
from skinfit.images import read_linear_rgb

HERE = Path.cwd() if "__file__" not in globals() else Path(__file__).resolve().parent
photo_path = HERE.parent / "data" / "eileen_collins_face.png"
photo, _ = read_linear_rgb(photo_path)  # 8-bit sRGB decoded to linear
fit = skinfit.fit_image(photo, white_balance=True, progress=False)
summary = fit.summary()
print({k: v for k, v in summary.items()})

# %% [markdown]
# ## Which pixels the skin model explains
# `SUCCESS` pixels are reproduced within CIEDE2000 1 (the default `max_delta_e`); hair, eyes, lips, the suit
# and the background are `OUT_OF_MODEL` (their colour is not a DJ2006 skin colour). In this photo's warm,
# saturated studio light a share of the cheeks is outside the model's gamut at blend 0.7 as well.

# %%
for status in skinfit.PixelStatus:
    count = int(np.sum(fit.status == status))
    if count:
        print(f"{status.name:<13} {count:6d} pixels ({100 * count / fit.status.size:.1f} %)")
fitted = fit.status == skinfit.PixelStatus.SUCCESS
print(f"CIEDE2000 over fitted pixels: median {np.median(fit.residual_dE2000[fitted]):.2g}, 95th percentile {np.percentile(fit.residual_dE2000[fitted], 95):.2g}")

# %% [markdown]
# ## The maps, and a blush re-rendered
# The edit scales haemoglobin by 1.5 and renders the maps through the exact forward model and the same camera
# model (`skinfit.render_maps`, then the fitted white balance).

# %%
shown = fit.status <= skinfit.PixelStatus.OUT_OF_MODEL
blush = skinfit.render_maps(fit.melanin, 1.5 * fit.haemoglobin, fit.shading, melanin_blend=0.7) * np.asarray(fit.white_balance)
blush = np.where(fitted[..., None], blush, fit.fitted_linear_rgb)
to_srgb = lambda linear: np.asarray(srgb_encode(np.clip(linear, 0, 1)))  # noqa: E731

fig, axes = plt.subplots(1, 5, figsize=(16, 4))
axes[0].imshow(to_srgb(photo))
axes[0].set_title("photo")
axes[1].imshow(to_srgb(fit.fitted_linear_rgb))
axes[1].set_title("reconstruction")
for ax, name, cmap in ((axes[2], "melanin", "copper_r"), (axes[3], "haemoglobin", "Reds")):
    image = ax.imshow(np.ma.masked_where(~fitted, getattr(fit, name)), cmap=cmap, vmax=np.percentile(getattr(fit, name)[fitted], 99))
    fig.colorbar(image, ax=ax, fraction=0.046)
    ax.set_title(f"{name} (volume fraction)")
axes[4].imshow(to_srgb(blush))
axes[4].set_title("blush: haemoglobin x 1.5")
for ax in axes:
    ax.axis("off")
fig.tight_layout()
fig.savefig("03_fit_photo_maps.png", dpi=100)

# %% [markdown]
# ## Round trip: maps -> image -> maps
# Rendering the fitted maps and fitting the rendering again returns the maps (the fit is exact where the
# model reaches the colour).

# %%
again = skinfit.fit_image(fit.fitted_linear_rgb / np.asarray(fit.white_balance), progress=False)
both = fitted & (again.status == skinfit.PixelStatus.SUCCESS)
for name in ("melanin", "haemoglobin", "shading"):
    error = np.abs(getattr(again, name) - getattr(fit, name))[both]
    print(f"{name:<12} round-trip error median {np.median(error):.1e}, 99th percentile {np.percentile(error, 99):.1e}")
