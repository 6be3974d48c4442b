"""What a spectral fit can vary: the skin parameters plus the terms real measurements need.

Each variable has a physical range; the solver works on an unbounded variable u with
value = low + (high - low) (1 + sin u) / 2 (the MINUIT transform), so every iterate stays inside its
range. Unlike a logistic map, a solution on a bound (common for real spectra, e.g. no eumelanin) is
an ordinary quadratic minimum in u, at u = +-pi/2, so the solver converges there instead of drifting
towards infinity.

The measurement model is

    measured(lambda) = calibration_scale * (diffuse(lambda) + specular_offset)

where ``diffuse`` is the DJ2006 diffuse reflectance (diffusion, or exact transport with
``method="transport"``; with ``blood_oxygenation``,
``epidermis_thickness_mm`` and ``scattering_scale`` as model options), or, with a finite
measurement port, the part of it that re-emerges within the port (``captured_reflectance``).
For an instrument that includes the specular reflection (incidence theta, e.g. 8 degrees for
a d/8 sphere in SCI mode), the surface layer replaces the entry Fresnel factor:

    measured(lambda) = calibration_scale * (rho(theta) + (1 - rho(theta)) R12(lambda) + specular_offset)

with rho = oil x the lobe's directional albedo (``skinfit.surface``), so ``oil`` can be fitted.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .layers import SKIN_ANISOTROPY
from .params import SkinParams


@dataclasses.dataclass(frozen=True)
class FitVariable:
    """One fit variable: its range, its value when fixed, and what it means."""

    low: float
    high: float
    default: float | None
    doc: str


VARIABLES: dict[str, FitVariable] = {
    "melanin": FitVariable(0.0, 1.0, None, "C_m, epidermal melanin volume fraction"),
    "melanin_blend": FitVariable(0.0, 1.0, None, "beta_m, eumelanin fraction of the melanin"),
    "haemoglobin": FitVariable(0.0, 1.0, None, "C_h, dermal blood volume fraction"),
    "blood_oxygenation": FitVariable(0.0, 1.0, 0.75, "HbO2 fraction of the blood (DJ2006: 0.75)"),
    "epidermis_thickness_mm": FitVariable(0.01, 1.0, 0.25, "epidermis thickness in mm (DJ2006: 0.25)"),
    "scattering_scale": FitVariable(0.2, 5.0, 1.0, "factor on the reduced scattering of both layers (DJ2006: 1)"),
    "specular_offset": FitVariable(
        0.0, 0.3, 0.0, "additive surface reflection, for hemispherical instruments that include it (~0.028)"
    ),
    "calibration_scale": FitVariable(0.5, 2.0, 1.0, "multiplicative calibration of the instrument"),
    "oil": FitVariable(
        0.0, 1.0, 0.3, "DJ2006 surface lobe scale rho_s; only for measurements that include the specular part "
        "(specular_included_deg); 0.3 in the DJ2006 scenes"
    ),
}

CHROMOPHORES = ("melanin", "melanin_blend", "haemoglobin")

#: Where a free variable starts when no table covers it (and it has no fixed value).
STARTS = {"specular_offset": 0.02, "oil": 0.3}


def to_unbounded(name: str, value):
    """u in [-pi/2, pi/2] such that ``from_unbounded(name, u) == value``."""
    var = VARIABLES[name]
    frac = np.clip((np.asarray(value, dtype=float) - var.low) / (var.high - var.low), 0.0, 1.0)
    return np.arcsin(2.0 * frac - 1.0)


def from_unbounded(name: str, u):
    """Physical value of variable ``name`` from its unbounded coordinate ``u``."""
    var = VARIABLES[name]
    return var.low + (var.high - var.low) * 0.5 * (1.0 + jnp.sin(u))


@dataclasses.dataclass(frozen=True)
class MeasurementModel:
    """The measured spectrum as a function of the free variables (hashable: it is static under jit).

    Attributes:
        free: names of the free variables, in the order of the unbounded vector u.
        fixed: values of the other variables.
        port_radius_mm: radius of the measurement port, or None for an infinite port.
        adding: layer adding mode (diffusion).
        specular_included_deg: incidence angle of a measurement that includes the specular part.
        method: forward model, ``"diffusion"`` (DJ2006) or ``"transport"`` (adding-doubling).
        anisotropy: Henyey-Greenstein g of both layers for ``"transport"``.
    """

    free: tuple[str, ...]
    fixed: tuple[tuple[str, float], ...]
    port_radius_mm: float | None = None
    adding: str = "directional"
    specular_included_deg: float | None = None
    method: str = "diffusion"
    anisotropy: float = SKIN_ANISOTROPY

    def with_method(self, method: str) -> "MeasurementModel":
        """The same measurement through another forward model (``"diffusion"`` or ``"transport"``)."""
        return dataclasses.replace(self, method=method)

    def values(self, u) -> dict:
        """All variables (free from u, the rest fixed) as a dict of arrays of u's batch shape."""
        values = {name: from_unbounded(name, u[..., i]) for i, name in enumerate(self.free)}
        for name, value in self.fixed:
            values[name] = jnp.full(u.shape[:-1], value, u.dtype)
        return values

    def spectrum(self, u, wavelengths_nm):
        """Model spectrum at ``wavelengths_nm`` for the unbounded vector u of shape (..., n_free)."""
        return self.spectrum_of_values(self.values(u), wavelengths_nm, u.dtype)

    def spectrum_of_free(self, theta, wavelengths_nm):
        """Model spectrum for the physical values ``theta`` (..., n_free) of the free variables."""
        values = {name: theta[..., i] for i, name in enumerate(self.free)}
        for name, value in self.fixed:
            values[name] = jnp.full(theta.shape[:-1], value, theta.dtype)
        return self.spectrum_of_values(values, wavelengths_nm, theta.dtype)

    def spectrum_of_values(self, v: dict, wavelengths_nm, dtype):
        """Model spectrum from a dict of every variable's physical value."""
        from .layers import SKIN_IOR
        from .profiles import _captured, energy_kernel
        from .reflectance import _skin_reflectance, _skin_stack

        params = SkinParams(v["melanin"], v["melanin_blend"], v["haemoglobin"])
        ior = jnp.asarray(SKIN_IOR, dtype)
        options = (v["blood_oxygenation"], v["epidermis_thickness_mm"], ior, v["scattering_scale"])
        if self.port_radius_mm is None:
            diffuse = None if self.method == "transport" else _skin_reflectance(params, wavelengths_nm, self.adding, *options)
        else:
            layers = _skin_stack(params, wavelengths_nm, *options)
            q, weights = energy_kernel(self.port_radius_mm, _PORT_QUADRATURE)
            diffuse = _captured(layers, jnp.asarray(self.port_radius_mm, dtype), q, weights, self.adding)
        if self.method == "transport":
            from .reflectance import _skin_reflectance_transport
            from .transport import STREAMS

            exact = _skin_reflectance_transport(params, wavelengths_nm, *options, anisotropy=jnp.asarray(self.anisotropy, dtype),
                                                streams=STREAMS, ior_value=SKIN_IOR)
            if diffuse is not None:
                # the energy-corrected profile (diffusion's shape, transport's total), as
                # ``profile(method="transport")``: the captured fraction is diffusion's
                diffuse = exact * diffuse / _skin_reflectance(params, wavelengths_nm, self.adding, *options)
            else:
                diffuse = exact
        if self.specular_included_deg is not None:
            from .reflectance import normal_fresnel_reflectance
            from .surface import lobe_albedo

            theta = np.radians(self.specular_included_deg)
            direction = jnp.asarray([np.sin(theta), 0.0, np.cos(theta)], dtype)
            rho = v["oil"][..., None] * lobe_albedo(direction)
            r12 = diffuse / (1.0 - normal_fresnel_reflectance(ior))  # undo the entry Fresnel factor
            diffuse = rho + (1.0 - rho) * r12
        return v["calibration_scale"][..., None] * (diffuse + v["specular_offset"][..., None])


def _port_quadrature():
    from .hankel import HankelQuadrature

    # The port integral needs less than a full profile: 1e-9 of the reflectance is ample for fits.
    return HankelQuadrature(q_max=120.0, nodes_per_panel=12)


_PORT_QUADRATURE = _port_quadrature()
