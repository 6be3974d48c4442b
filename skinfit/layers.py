"""Optical layers: a generic ``Layer`` and the DJ2006 epidermis-over-dermis stack built from SkinParams."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from . import chromophores as chrom
from ._validate import SkinfitInputError, as_float_array, check_range, is_concrete
from .params import SkinParams

#: DJ2006 defaults.
BLOOD_OXYGENATION = 0.75
EPIDERMIS_THICKNESS_MM = 0.25
SKIN_IOR = 1.4
#: Henyey-Greenstein g of both skin layers for ``method="transport"``: skin scatters forward with
#: g about 0.8-0.9 in the epidermis and about 0.8 in the dermis (MODEL.md 12, from the tissue-optics
#: literature summarised by Jacques 2013, "Optical properties of biological tissues: a review").
SKIN_ANISOTROPY = 0.8


class Layer(eqx.Module):
    """One homogeneous layer of a stack (top first in a stack).

    Attributes:
        absorption: sigma_a, mm^-1 (>= 0).
        reduced_scattering: sigma_s' = sigma_s (1 - g), mm^-1 (> 0).
        thickness: mm (> 0); ``float("inf")`` for a semi-infinite layer, allowed only at the bottom.
        ior: refractive index (> 0).
        anisotropy: Henyey-Greenstein g in (-1, 1); diffusion ignores it (it depends on sigma_s' only).

    Fields may be arrays (for example over wavelength) and broadcast against each other.
    """

    absorption: Float[Array, "..."]
    reduced_scattering: Float[Array, "..."]
    thickness: Float[Array, "..."]
    ior: Float[Array, "..."]
    anisotropy: Float[Array, "..."]

    def __init__(self, absorption, reduced_scattering, thickness, ior=SKIN_IOR, anisotropy=0.0):
        self.absorption = as_float_array("absorption", absorption)
        self.reduced_scattering = as_float_array("reduced_scattering", reduced_scattering)
        self.thickness = as_float_array("thickness", thickness)
        self.ior = as_float_array("ior", ior)
        self.anisotropy = as_float_array("anisotropy", anisotropy)
        check_range("absorption", self.absorption, 0.0, float("inf"), unit="mm^-1")
        check_range("reduced_scattering", self.reduced_scattering, 1e-12, float("inf"), unit="mm^-1")
        _check_thickness(self.thickness)
        check_range("ior", self.ior, 1e-3, 10.0)
        check_range("anisotropy", self.anisotropy, -0.999999, 0.999999)


def _check_thickness(thickness):
    if not is_concrete(thickness):
        return
    t = np.asarray(thickness, dtype=float)
    if np.any(np.isnan(t)) or np.any(t <= 0.0):
        raise SkinfitInputError("thickness must be > 0 mm (use float('inf') for a semi-infinite layer)")


def skin_layers(
    params: SkinParams,
    wavelengths_nm: ArrayLike,
    *,
    blood_oxygenation: ArrayLike = BLOOD_OXYGENATION,
    epidermis_thickness_mm: ArrayLike = EPIDERMIS_THICKNESS_MM,
    ior: ArrayLike = SKIN_IOR,
    scattering_scale: ArrayLike = 1.0,
) -> tuple[Layer, Layer]:
    """Epidermis over semi-infinite dermis for each wavelength (MODEL.md 2.3, 3, 4).

    sigma_a,epi  = C_m [beta_m sigma_em + (1 - beta_m) sigma_pm] + (1 - C_m) sigma_base
    sigma_a,derm = C_h [gamma sigma_oxy + (1 - gamma) sigma_deoxy] + (1 - C_h) sigma_base

    Parameter arrays of batch shape (...) give layer fields of shape (..., n_wavelengths);
    ``blood_oxygenation`` (gamma), ``epidermis_thickness_mm``, ``ior`` and ``scattering_scale`` (a
    factor on the reduced scattering of both layers, 1 in DJ2006) broadcast with them.
    """
    lam = jnp.asarray(wavelengths_nm)
    expand = lambda x: jnp.asarray(x)[..., None]  # noqa: E731 - batch axes, then wavelength
    c_m, beta_m, c_h = expand(params.melanin), expand(params.melanin_blend), expand(params.haemoglobin)
    gamma = expand(blood_oxygenation)
    scale = expand(scattering_scale)

    base = chrom.baseline_absorption(lam)
    melanin = beta_m * chrom.eumelanin_absorption(lam) + (1.0 - beta_m) * chrom.pheomelanin_absorption(lam)
    blood = gamma * chrom.oxyhaemoglobin_absorption(lam) + (1.0 - gamma) * chrom.deoxyhaemoglobin_absorption(lam)

    epidermis = Layer(
        absorption=c_m * melanin + (1.0 - c_m) * base,
        reduced_scattering=scale * chrom.epidermis_reduced_scattering(lam),
        thickness=expand(epidermis_thickness_mm),
        ior=expand(ior),
    )
    dermis = Layer(
        absorption=c_h * blood + (1.0 - c_h) * base,
        reduced_scattering=scale * chrom.dermis_reduced_scattering(lam),
        thickness=jnp.full((), jnp.inf, lam.dtype),
        ior=expand(ior),
    )
    return epidermis, dermis
