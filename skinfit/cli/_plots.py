"""Figures for people: reflectance spectra with sRGB swatches, and radial profiles on log axes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..colorimetry import srgb_encode
from ..fit import PixelStatus


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def plot_spectra(wavelengths_nm, spectra: dict[str, np.ndarray], srgb: dict[str, np.ndarray], path: str | Path):
    """Reflectance spectra (one line each) beside sRGB swatches of the same colours."""
    plt = _pyplot()
    fig, (ax, sw) = plt.subplots(1, 2, figsize=(9, 3.6), gridspec_kw={"width_ratios": [3, 1]})
    for name, values in spectra.items():
        ax.plot(wavelengths_nm, values, color=np.clip(srgb[name], 0, 1), lw=2.5, label=name)
        ax.plot(wavelengths_nm, values, color="k", lw=0.5)
    ax.set_xlabel("wavelength (nm)")
    ax.set_ylabel("diffuse reflectance")
    ax.set_ylim(0, None)
    ax.legend(frameon=False)
    ax.set_title("DJ2006 skin, normal incidence, specular excluded")
    for i, (name, colour) in enumerate(srgb.items()):
        sw.add_patch(plt.Rectangle((0, -i), 1, 0.9, color=np.clip(colour, 0, 1)))
        sw.text(1.1, -i + 0.45, f"{name}\n#{''.join(f'{int(round(255 * c)):02x}' for c in np.clip(colour, 0, 1))}", va="center")
    sw.set_xlim(0, 2.2)
    sw.set_ylim(-len(srgb) + 0.9, 1)
    sw.axis("off")
    sw.set_title("sRGB, D65")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_profiles(radii_mm, wavelengths_nm, profiles: dict[str, np.ndarray], path: str | Path, show_nm=(450.0, 550.0, 650.0)):
    """2 pi r^2 R(r) (energy per ln r) at a few wavelengths, one panel per parameter set."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(profiles), figsize=(4 * len(profiles), 3.4), squeeze=False, sharey=True)
    colours = ("tab:blue", "tab:green", "tab:red", "tab:purple", "tab:orange")
    for ax, (name, values) in zip(axes[0], profiles.items()):
        for lam, colour in zip(show_nm, colours):
            row = values[int(np.argmin(np.abs(np.asarray(wavelengths_nm) - lam)))]
            ax.loglog(radii_mm, np.maximum(2 * np.pi * radii_mm**2 * row, 1e-12), color=colour, label=f"{lam:g} nm")
        ax.set_ylim(1e-6, 1)
        ax.set_xlabel("radius r (mm)")
        ax.set_title(name)
    axes[0][0].set_ylabel(r"$2\pi r^2 R(r)$ (energy per ln r)")
    axes[0][0].legend(frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_fits(wavelengths_nm, measured, fitted, names, rms, path: str | Path, panels: int = 12):
    """Measured (dots) against fitted (line) spectra: the best and the worst fits by RMS residual."""
    plt = _pyplot()
    order = np.argsort(rms)
    half = min(panels // 2, (len(order) + 1) // 2)
    pick = list(dict.fromkeys([*order[:half], *order[::-1][:half]]))
    cols = 4
    rows = int(np.ceil(len(pick) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.4 * rows), squeeze=False, sharex=True)
    for ax, i in zip(axes.ravel(), pick):
        ax.plot(wavelengths_nm, measured[i], "k.", ms=3, label="measured")
        ax.plot(wavelengths_nm, fitted[i], "tab:red", label="fit")
        ax.set_title(f"{names[i]}  rms {rms[i]:.4f}", fontsize=8)
    for ax in axes.ravel()[len(pick):]:
        ax.axis("off")
    axes[0][0].legend(frameon=False, fontsize=7)
    fig.supxlabel("wavelength (nm)")
    fig.supylabel("reflectance")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


#: Colours of the region overlay (``FaceRegion`` order): background kept, skin green, eyes magenta,
#: brows orange, lips red, mouth cyan, nostrils yellow, other blue.
REGION_COLOURS = np.array([[0, 0, 0], [0.2, 0.85, 0.2], [0.9, 0.2, 0.9], [1.0, 0.6, 0.1], [0.95, 0.1, 0.1],
                           [0.1, 0.9, 0.9], [1.0, 1.0, 0.1], [0.2, 0.3, 1.0]], np.float32)


def region_overlay(encoded: np.ndarray, region: np.ndarray, opacity: float = 0.45) -> np.ndarray:
    """The photo (sRGB-encoded) with each face region tinted, the background dimmed."""
    colour = REGION_COLOURS[np.minimum(region, len(REGION_COLOURS) - 1)]
    tinted = (1 - opacity) * encoded + opacity * colour
    return np.where(region[..., None] > 0, tinted, 0.6 * encoded).astype(np.float32)


def _faces_window(region: np.ndarray, margin: float = 0.15) -> tuple[slice, slice]:
    """Rows and columns around every face's regions, ``margin`` of their size beyond."""
    rows, cols = np.nonzero(region > 0)
    if rows.size == 0:
        return slice(None), slice(None)
    pad_r, pad_c = int(margin * (rows.max() - rows.min() + 1)), int(margin * (cols.max() - cols.min() + 1))
    return (slice(max(0, rows.min() - pad_r), rows.max() + pad_r + 1), slice(max(0, cols.min() - pad_c), cols.max() + pad_c + 1))


def plot_image_fit(photo_srgb, fit, edited_srgb, path: str | Path, edit_label: str = "edit"):
    """An image fit at a glance: the photo, the face regions (where segmented), its reconstruction, the melanin, haemoglobin and
    shading maps, the CIEDE2000 and status maps, and an edit re-rendered. ``fit`` is an
    ``ImageFit``; the sRGB images are encoded (h, w, 3) in [0, 1]."""

    plt = _pyplot()

    skin = (fit.status == PixelStatus.SUCCESS) | (fit.status == PixelStatus.MAX_STEPS)
    masked = lambda a: np.ma.masked_where(~skin, a)  # noqa: E731
    # colour ranges from the skin's values, so that one stray pixel cannot flatten a map
    upper = lambda a: float(np.percentile(a[skin], 99.5)) if skin.any() else 1.0  # noqa: E731
    panels = [("photo", photo_srgb, {})]
    if fit.region is not None:
        panels.append((f"regions ({fit.faces} face{'s' if fit.faces != 1 else ''})", region_overlay(photo_srgb, fit.region), {}))
    panels += [
        ("reconstruction", np.clip(np.asarray(srgb_encode(np.clip(fit.fitted_linear_rgb, 0, 1))), 0, 1), {}),
        ("melanin C_m", masked(fit.melanin), {"cmap": "copper_r", "vmin": 0, "vmax": upper(fit.melanin)}),
        ("haemoglobin C_h", masked(fit.haemoglobin), {"cmap": "Reds", "vmin": 0, "vmax": upper(fit.haemoglobin)}),
        ("shading", masked(fit.shading), {"cmap": "gray", "vmin": 0, "vmax": upper(fit.shading)}),
    ]
    if fit.melanin_se is not None:
        panels += [
            ("C_m standard error", masked(fit.melanin_se), {"cmap": "viridis", "vmin": 0, "vmax": upper(fit.melanin_se)}),
            ("C_h standard error", masked(fit.haemoglobin_se), {"cmap": "viridis", "vmin": 0, "vmax": upper(fit.haemoglobin_se)}),
        ]
    panels += [
        ("CIEDE2000", masked(fit.residual_dE2000), {"cmap": "magma", "vmin": 0, "vmax": 2}),
        ("status", fit.status, {"cmap": "tab10", "vmin": -0.5, "vmax": 9.5, "interpolation": "nearest"}),
        (edit_label, edited_srgb, {}),
    ]
    cols = (len(panels) + 1) // 2
    fig, axes = plt.subplots(2, cols, figsize=(3.3 * cols, 7.2), squeeze=False)
    for ax in axes.ravel()[len(panels):]:
        ax.axis("off")
    # the faces fill a small part of a portrait: every panel but the photo shows the faces' window
    window = _faces_window(fit.region) if fit.region is not None else (slice(None), slice(None))
    for ax, (title, image, style) in zip(axes.ravel(), panels):
        shown = ax.imshow(image if title == "photo" else image[window], **style)
        if image.ndim == 2 and title != "status":
            fig.colorbar(shown, ax=ax, fraction=0.046, pad=0.03)
        ax.set_title(title)
        ax.axis("off")
        if title == "status":
            status_axis = ax
    names = ", ".join(f"{int(s)} {s.name.lower()}" for s in PixelStatus if np.any(fit.status == s))
    status_axis.set_title(f"status\n{names}", fontsize=7, wrap=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
