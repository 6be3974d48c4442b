"""Radial diffusion profiles R(r, lambda) in mm^-2: inverse Hankel transforms of R12(q).

R(r) = R_dipole(r) + (1/2pi) int [R12(q) - R_dipole(q)] J0(q r) q dq, where R_dipole is the top
layer's own dipole (closed form in both domains). The subtraction carries the sharp peak at small
r; what remains is smooth and decays fast in q, so a modest Gauss-Legendre quadrature reaches
~1e-15 of the peak (tests compare against real-space image sums and a 2-D FFT).

The integral of 2 pi r R(r) dr over the plane equals R12(0), the diffuse reflectance before the
entry Fresnel factor; ``entry_fresnel=True`` includes that factor so the profile integrates to
``diffuse_reflectance``.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._validate import SkinfitInputError
from ._adding import Adding, check_adding, stack_transfer
from ._fresnel import normal_fresnel_reflectance
from ._hankel import HankelQuadrature, check_radii, energy_kernel, inverse_kernel
from ._layers import Layer
from ._multipole import dipole_energy, dipole_profile, dipole_transfer
from ._params import SkinParams
from ._reflectance import _check_stack, checked_wavelengths, model_with_options
from ._skin_model import SkinModel


def layered_profile(
    layers: Sequence[Layer],
    radii_mm: ArrayLike,
    *,
    adding: Adding = "directional",
    ior_above: ArrayLike = 1.0,
    ior_below: ArrayLike = 1.0,
    entry_fresnel: bool = False,
    quadrature: HankelQuadrature = HankelQuadrature(),
) -> Float[Array, "... n_radii"]:
    """Radial profile R(r) in mm^-2 of a user-defined stack (top first) at radii ``radii_mm``.

    Layer fields of shape (...) give a result of shape (..., n_radii).
    """
    layers = _check_stack(layers)
    check_adding(adding)
    radii = check_radii(radii_mm)
    q, kernel = inverse_kernel(radii, quadrature)
    return _profile(layers, radii, q, kernel, adding, jnp.asarray(ior_above), jnp.asarray(ior_below), bool(entry_fresnel))


def profile(
    params: SkinParams,
    wavelengths_nm: ArrayLike,
    radii_mm: ArrayLike,
    *,
    model: SkinModel | None = None,
    adding: Adding | None = None,
    blood_oxygenation: ArrayLike | None = None,
    epidermis_thickness_mm: ArrayLike | None = None,
    ior: ArrayLike | None = None,
    scattering_scale: ArrayLike = 1.0,
    entry_fresnel: bool = False,
    quadrature: HankelQuadrature = HankelQuadrature(),
    method: str | None = None,
    anisotropy: ArrayLike | None = None,
) -> Float[Array, "*batch n_wavelengths n_radii"]:
    """Radial diffusion profile of skin, R(r, lambda) in mm^-2.

    Args:
        params: ``SkinParams`` of batch shape (...).
        wavelengths_nm: 1-D wavelengths in nm.
        radii_mm: 1-D radii in mm (concrete values, >= 0).
        model: ``SkinModel`` (default: the calibrated package default). With a ``Transport``
            method the multipole profile's shape is rescaled per wavelength so that it integrates
            to the transport-exact total: "energy-corrected", not a transport-exact shape.
        entry_fresnel: multiply by (1 - F0) so the profile integrates to ``diffuse_reflectance``
            instead of R12(0).
        quadrature: ``HankelQuadrature`` settings (accuracy against cost).
        **options: overrides of the model, as in ``diffuse_reflectance``.

    Returns:
        Array of shape (..., n_wavelengths, n_radii).
    """
    lam = checked_wavelengths(wavelengths_nm)
    model = model_with_options(model, adding=adding, blood_oxygenation=blood_oxygenation,
                               epidermis_thickness_mm=epidermis_thickness_mm, ior=ior, method=method, anisotropy=anisotropy)
    radii = check_radii(radii_mm)
    q, kernel = inverse_kernel(radii, quadrature)
    return skin_profile(params, lam, radii, q, kernel, model, bool(entry_fresnel), jnp.asarray(scattering_scale))


@eqx.filter_jit
def skin_profile(params, lam, radii, q, kernel, model, entry_fresnel, scattering_scale=1.0):
    layers = model.layers(params, lam, scattering_scale=scattering_scale)
    one = jnp.ones((), lam.dtype)
    shape = _profile(layers, radii, q, kernel, model.method.profile_adding, one, one, entry_fresnel)
    return shape * model.method.energy_correction(*layers)[..., None]


@eqx.filter_jit
def _profile(layers, radii, q, kernel, adding, ior_above, ior_below, entry_fresnel):
    top = layers[0]
    dtype = jnp.result_type(top.absorption, top.reduced_scattering)
    q, kernel, radii = (jnp.asarray(a, dtype) for a in (q, kernel, radii))
    eta_top = (top.ior / jnp.asarray(ior_above))[..., None]
    smooth = _smooth_transfer(layers, q, adding, ior_above, ior_below)
    result = smooth @ kernel + dipole_profile(
        top.absorption[..., None], top.reduced_scattering[..., None], eta_top, radii, top.thickness[..., None]
    ).astype(smooth.dtype)
    if entry_fresnel:
        result = result * (1.0 - normal_fresnel_reflectance(top.ior, ior_above))[..., None]
    return result


def captured_reflectance(
    params: SkinParams,
    wavelengths_nm: ArrayLike,
    port_radius_mm: float,
    *,
    model: SkinModel | None = None,
    adding: Adding | None = None,
    blood_oxygenation: ArrayLike | None = None,
    epidermis_thickness_mm: ArrayLike | None = None,
    ior: ArrayLike | None = None,
    scattering_scale: ArrayLike = 1.0,
    quadrature: HankelQuadrature = HankelQuadrature(),
) -> Float[Array, "*batch n_wavelengths"]:
    """Diffuse reflectance that re-emerges within ``port_radius_mm`` of a narrow normal beam.

    (1 - F0) int_0^a 2 pi r R(r) dr: what an integrating sphere with a port of radius a collects
    when the illumination spot is small compared with the port (model notes 13). Light that travels
    sideways beyond the port is lost; as a -> inf this tends to ``diffuse_reflectance``. With a
    transport model the profile is energy-corrected (see ``profile``).
    """
    lam = checked_wavelengths(wavelengths_nm)
    model = model_with_options(model, adding=adding, blood_oxygenation=blood_oxygenation,
                               epidermis_thickness_mm=epidermis_thickness_mm, ior=ior)
    if not (np.isfinite(port_radius_mm) and port_radius_mm > 0):
        raise SkinfitInputError("port_radius_mm must be a finite radius > 0 mm")
    q, weights = energy_kernel(port_radius_mm, quadrature)
    return _skin_captured(params, lam, jnp.asarray(port_radius_mm, lam.dtype), q, weights, model, jnp.asarray(scattering_scale))


@eqx.filter_jit
def _skin_captured(params, lam, radius, q, weights, model, scattering_scale=1.0):
    layers = model.layers(params, lam, scattering_scale=scattering_scale)
    return captured_of_layers(layers, radius, q, weights, model.method)


def captured_of_layers(layers, radius, q, weights, method):
    """What a port of ``radius`` captures of the stack's diffuse reflectance, by ``method``."""
    return _captured(layers, radius, q, weights, method.profile_adding) * method.energy_correction(*layers)


def _captured(layers, radius, q, weights, adding):
    """(1 - F0) times the energy of the stack's profile within ``radius`` (layers in air above)."""
    top = layers[0]
    dtype = jnp.result_type(top.absorption, top.reduced_scattering)
    q, weights = jnp.asarray(q, dtype), jnp.asarray(weights, dtype)
    smooth = _smooth_transfer(layers, q, adding, 1.0, 1.0)
    energy = smooth @ weights + dipole_energy(top.absorption, top.reduced_scattering, top.ior, radius, top.thickness)
    return (1.0 - normal_fresnel_reflectance(top.ior)) * energy


def _smooth_transfer(layers, q, adding, ior_above, ior_below):
    """R12(q) minus the top layer's dipole at frequencies q (trailing axis): the smooth part that
    the quadrature transforms; the dipole itself is transformed in closed form."""
    top = layers[0]
    eta_top = (top.ior / jnp.asarray(ior_above))[..., None]
    # Fields gain a trailing axis over q; everything else broadcasts as before.
    expanded = [jax.tree_util.tree_map(lambda a: jnp.asarray(a)[..., None], layer) for layer in layers]
    r12 = stack_transfer(expanded, q, adding=adding, ior_above=ior_above, ior_below=ior_below)
    return r12 - dipole_transfer(expanded[0].absorption, expanded[0].reduced_scattering, eta_top, q, expanded[0].thickness)
