"""Optical layers: a generic ``Layer``, and the DJ2006 constants of the skin stack (``skinfit.SkinModel`` builds it)."""

from __future__ import annotations

import equinox as eqx
import numpy as np
from jaxtyping import Array, Float

from .._validate import SkinfitInputError, as_float_array, check_range, is_concrete

#: DJ2006 defaults.
BLOOD_OXYGENATION = 0.75
EPIDERMIS_THICKNESS_MM = 0.25
SKIN_IOR = 1.4
#: Henyey-Greenstein g of both skin layers for ``method="transport"``: skin scatters forward with
#: g about 0.8-0.9 in the epidermis and about 0.8 in the dermis (model notes 12, from the tissue-optics
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
