"""Chromophore absorption and tissue scattering spectra (wavelength in nm, coefficients in mm^-1).

Sources (model notes sections 2-3):

* Eumelanin, pheomelanin and bloodless-skin baseline: S. L. Jacques, "Skin optics", OMLC News,
  January 1998 (https://omlc.org/news/jan98/skinoptics.html), converted from cm^-1 to mm^-1 as in the
  public Donner & Jensen 2006 implementations.
* Haemoglobin: Prahl's OMLC molar extinction table (``spectra/prahl_haemoglobin.csv``) for whole
  blood at 150 g/L and 64,500 g/mol.
* Reduced scattering: Mie + Rayleigh power law of the DJ2006 implementations; the dermis scatters
  half as much as the epidermis (``skinfit.SkinModel`` holds the laws of the calibrated model).
* Beta-carotene (optional, not DJ2006): Prahl's OMLC PhotochemCAD table (``spectra/beta_carotene.csv``,
  in hexane; Du et al. 1998), decadic molar extinction.
* Blood in vessels (optional, not DJ2006): the pigment-packaging factor of Verkruysse et al. 1997
  (Phys. Med. Biol. 42, 51-65) for blood confined to cylindrical vessels.

Every function takes wavelengths of any shape and returns the same shape.
"""

from __future__ import annotations

import importlib.resources

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._caching import eager_cache

#: Wavelength range (nm) covered by the haemoglobin table, and so by the skin model.
WAVELENGTH_RANGE_NM = (250.0, 1000.0)

#: Haemoglobin concentration of whole blood (g/L) and molar mass (g/mol), as in DJ2006 codes.
BLOOD_HAEMOGLOBIN_G_PER_L = 150.0
HAEMOGLOBIN_MOLAR_MASS_G_PER_MOL = 64_500.0

# mm^-1 per (cm^-1 / M): 2.303 * 150 g/L / 64,500 g/mol / (10 mm per cm) = 5.3558e-4. Prahl writes ln(10)
# as 2.303, and so do the DJ2006 tables (damlaren: 280.795 mm^-1 for HbO2 at 414 nm); we keep it.
_EXTINCTION_TO_MM = (
    2.303 * BLOOD_HAEMOGLOBIN_G_PER_L / HAEMOGLOBIN_MOLAR_MASS_G_PER_MOL / 10.0
)


@eager_cache()
def haemoglobin_table() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Prahl's table as ``(wavelength_nm, epsilon_HbO2, epsilon_Hb)``, in cm^-1 per mol/L."""
    text = (
        importlib.resources.files("skinfit.spectra")
        .joinpath("prahl_haemoglobin.csv")
        .read_text(encoding="utf-8")
    )
    rows = [line for line in text.splitlines() if line.strip() and not line.startswith("#")]
    # rows[0] is the column header: wavelength_nm,epsilon_HbO2,epsilon_Hb
    data = np.loadtxt(rows[1:], delimiter=",", dtype=float, ndmin=2)
    return data[:, 0], data[:, 1], data[:, 2]


@eager_cache()
def carotene_table() -> tuple[np.ndarray, np.ndarray]:
    """Prahl's beta-carotene table as ``(wavelength_nm, epsilon)``, epsilon in cm^-1 per mol/L (decadic)."""
    text = importlib.resources.files("skinfit.spectra").joinpath("beta_carotene.csv").read_text(encoding="utf-8")
    rows = [line for line in text.splitlines() if line.strip() and not line.startswith("#")]
    data = np.loadtxt(rows[1:], delimiter=",", dtype=float, ndmin=2)
    # beyond 540 nm the table holds only the instrument's offset (~0.5 % of the peak): carotene is clear there
    epsilon = np.where(data[:, 0] > _CAROTENE_CLEAR_NM, 0.0, np.maximum(data[:, 1], 0.0))
    return data[:, 0], epsilon


_CAROTENE_CLEAR_NM = 540.0


def carotene_absorption(wavelengths_nm: ArrayLike) -> Float[Array, "..."]:
    """Absorption of beta-carotene, mm^-1 per umol/L: ln(10) epsilon / 10 mm per cm x 1e-6 mol per umol.

    Zero outside the table (below 220 nm, where skinfit is not valid anyway, and above 700 nm) and
    beyond 540 nm. 0.0321 mm^-1 per umol/L at the 451 nm peak.
    """
    wl, epsilon = carotene_table()
    lam = jnp.asarray(wavelengths_nm)
    values = np.log(10.0) * epsilon / 10.0 * 1e-6
    return jnp.interp(lam, jnp.asarray(wl, lam.dtype), jnp.asarray(values, lam.dtype), left=0.0, right=0.0)


def packaging_factor(absorption: ArrayLike, vessel_radius_mm: ArrayLike) -> Float[Array, "..."]:
    """Pigment-packaging factor of blood confined to vessels of radius R (Verkruysse et al. 1997):

        C = (1 - exp(-2 mu_a R)) / (2 mu_a R),

    which multiplies the absorption of homogeneously spread blood: inside strongly absorbing bands
    light cannot reach the centre of a vessel, so the blood absorbs less than if it were spread out.
    C = 1 at R = 0 (no packaging, DJ2006); finite with finite gradients for any R >= 0.
    """
    x = 2.0 * jnp.asarray(absorption) * jnp.asarray(vessel_radius_mm)
    small = x < 1e-6
    x_safe = jnp.where(small, 1.0, x)
    return jnp.where(small, 1.0 - 0.5 * x, -jnp.expm1(-x_safe) / x_safe)


def _interp_table(wavelengths_nm, column: int):
    wl, *eps = haemoglobin_table()
    values = eps[column] * _EXTINCTION_TO_MM
    lam = jnp.asarray(wavelengths_nm)
    return jnp.interp(lam, jnp.asarray(wl, lam.dtype), jnp.asarray(values, lam.dtype))


def eumelanin_absorption(wavelengths_nm: ArrayLike) -> Float[Array, "..."]:
    """Eumelanin absorption, 6.6e10 * lambda^-3.33 mm^-1 (Jacques 1998)."""
    lam = jnp.asarray(wavelengths_nm)
    return 6.6e10 * lam**-3.33


def pheomelanin_absorption(wavelengths_nm: ArrayLike) -> Float[Array, "..."]:
    """Pheomelanin absorption, 2.9e14 * lambda^-4.75 mm^-1 (Jacques 1998)."""
    lam = jnp.asarray(wavelengths_nm)
    return 2.9e14 * lam**-4.75


def baseline_absorption(wavelengths_nm: ArrayLike) -> Float[Array, "..."]:
    """Bloodless-skin baseline, 0.0244 + 8.53 exp(-(lambda - 154) / 66.2) mm^-1 (Jacques 1998)."""
    lam = jnp.asarray(wavelengths_nm)
    return 0.0244 + 8.53 * jnp.exp(-(lam - 154.0) / 66.2)


def oxyhaemoglobin_absorption(wavelengths_nm: ArrayLike) -> Float[Array, "..."]:
    """Absorption of fully oxygenated whole blood (HbO2, 150 g/L) in mm^-1, Prahl table."""
    return _interp_table(wavelengths_nm, 0)


def deoxyhaemoglobin_absorption(wavelengths_nm: ArrayLike) -> Float[Array, "..."]:
    """Absorption of fully deoxygenated whole blood (Hb, 150 g/L) in mm^-1, Prahl table."""
    return _interp_table(wavelengths_nm, 1)


def epidermis_reduced_scattering(wavelengths_nm: ArrayLike) -> Float[Array, "..."]:
    """Epidermal reduced scattering, 14.74 lambda^-0.22 + 2.2e11 lambda^-4 mm^-1 (Mie + Rayleigh)."""
    lam = jnp.asarray(wavelengths_nm)
    return 14.74 * lam**-0.22 + 2.2e11 * lam**-4.0


def dermis_reduced_scattering(wavelengths_nm: ArrayLike) -> Float[Array, "..."]:
    """Dermal reduced scattering: half the epidermal value (DJ2006 implementations)."""
    return 0.5 * epidermis_reduced_scattering(wavelengths_nm)
