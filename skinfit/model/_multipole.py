"""Frequency-domain response of one diffusing layer: the closed-form infinite multipole.

Donner & Jensen 2005 model a slab of thickness d by an infinite array of dipoles mirrored about the
extrapolated boundaries at z = -z_b0 (top) and z = d + z_bd (bottom). In the 2-D Fourier domain
(radial frequency q, mm^-1) each image becomes one exponential in k = sqrt(sigma_tr^2 + q^2), and the
whole image series sums to (model notes 5.2)

    R(q) = alpha' cosh(k z_b0) sinh(k (d + z_bd - l)) / sinh(k L)
    T(q) = alpha' sinh(k (l + z_b0)) cosh(k z_bd) / sinh(k L),        L = d + z_b0 + z_bd,

the exact infinite multipole. We evaluate it in the overflow-free exponential form; ratios
(1 - e^{-2ka}) / (1 - e^{-2kL}) use expm1 so that they stay exact as k -> 0 (no absorption at q = 0),
where they tend to a / L. A semi-infinite layer (d = inf) reduces to the dipole of Jensen et al. 2001.

Light entering from below uses the same formulas with z_b0 and z_bd swapped.

All lengths are mm, coefficients mm^-1; arrays broadcast against each other.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float


class SlabResponse(NamedTuple):
    """Reflectance and transmittance of one layer at radial frequency q (dimensionless).

    ``reflect_top``/``transmit_top`` are for light entering from above (R+, T+), and
    ``reflect_bottom``/``transmit_bottom`` for light entering from below (R-, T-).
    """

    reflect_top: Array
    transmit_top: Array
    reflect_bottom: Array
    transmit_bottom: Array


class DiffusionCoefficients(NamedTuple):
    """Diffusion quantities of one layer (mm, mm^-1)."""

    albedo: Array  # reduced single-scattering albedo alpha' = sigma_s' / sigma_t'
    diffusion: Array  # D = 1 / (3 sigma_t'), mm
    source_depth: Array  # l = 1 / sigma_t', mm
    sigma_tr_squared: Array  # sigma_tr^2 = 3 sigma_a sigma_t', mm^-2


def fresnel_diffuse_reflectance(eta: ArrayLike) -> Float[Array, "..."]:
    """Hemispherical diffuse Fresnel reflectance F_dr of a boundary with relative index eta.

    eta = n_inside / n_outside. Polynomial fits: Groenhuis et al. for eta >= 1, Egan & Hilgeman for
    eta < 1 (model notes 4). F_dr(1.4) = 0.5295; F_dr(1) = 0.0016.
    """
    eta = jnp.asarray(eta)
    eta_safe = jnp.maximum(eta, 1e-3)  # both branches stay finite for any eta > 0
    above = -1.440 / eta_safe**2 + 0.710 / eta_safe + 0.668 + 0.0636 * eta_safe
    below = -0.4399 + 0.7099 / eta_safe - 0.3319 / eta_safe**2 + 0.0636 / eta_safe**3
    return jnp.where(eta >= 1.0, above, below)


def boundary_coefficient(eta: ArrayLike) -> Float[Array, "..."]:
    """A = (1 + F_dr) / (1 - F_dr): internal-reflection factor of the extrapolated boundary."""
    f_dr = fresnel_diffuse_reflectance(eta)
    return (1.0 + f_dr) / (1.0 - f_dr)


def diffusion_coefficients(absorption: ArrayLike, reduced_scattering: ArrayLike) -> DiffusionCoefficients:
    """Diffusion quantities from absorption and reduced scattering (mm^-1)."""
    sigma_a = jnp.asarray(absorption)
    sigma_s = jnp.asarray(reduced_scattering)
    sigma_t = sigma_a + sigma_s
    # A layer with no interaction at all has no diffuse response; keep the arithmetic finite there.
    sigma_t = jnp.maximum(sigma_t, jnp.finfo(jnp.result_type(sigma_t, float)).tiny ** 0.25)
    return DiffusionCoefficients(
        albedo=sigma_s / sigma_t,
        diffusion=1.0 / (3.0 * sigma_t),
        source_depth=1.0 / sigma_t,
        sigma_tr_squared=3.0 * sigma_a * sigma_t,
    )


def _wavenumber(sigma_tr_squared, q):
    """k = sqrt(sigma_tr^2 + q^2), floored so that k = 0 (no absorption, q = 0) has finite gradients."""
    k2 = sigma_tr_squared + jnp.square(q)
    floor = jnp.finfo(jnp.result_type(k2, float)).tiny ** 0.25
    return jnp.sqrt(jnp.maximum(k2, floor**2))


def _ratio(k, a, length):
    """(1 - e^{-2 k a}) / (1 - e^{-2 k L}), exact as k -> 0 where it tends to a / L."""
    return jnp.expm1(-2.0 * k * a) / jnp.expm1(-2.0 * k * length)


def slab_response(
    absorption: ArrayLike,
    reduced_scattering: ArrayLike,
    thickness: ArrayLike,
    eta_top: ArrayLike,
    eta_bottom: ArrayLike,
    q: ArrayLike = 0.0,
) -> SlabResponse:
    """Closed-form infinite-multipole response of one layer at radial frequency ``q`` (mm^-1).

    ``thickness`` in mm may be ``inf`` (semi-infinite: the Jensen 2001 dipole, T = 0, and the
    response from below is zero). ``eta_top``/``eta_bottom`` are the relative indices
    n_layer / n_neighbour across the top and bottom faces.

    The real source sits at depth l = 1/sigma_t'. Where l exceeds the thickness (a slab less than
    one transport mean free path thick, outside the validity of diffusion) it is placed on the far
    face, which keeps R + T = alpha' at q = 0 for a non-absorbing slab, and every value finite.
    """
    coeff = diffusion_coefficients(absorption, reduced_scattering)
    thickness = jnp.asarray(thickness)
    k = _wavenumber(coeff.sigma_tr_squared, q)
    z_top = 2.0 * boundary_coefficient(eta_top) * coeff.diffusion
    z_bottom = 2.0 * boundary_coefficient(eta_bottom) * coeff.diffusion
    half_albedo = 0.5 * coeff.albedo

    # Semi-infinite layers go through the same expressions with a finite stand-in thickness and are
    # then masked: an inf inside an exponent would give 0 * inf = NaN in the gradient.
    semi_infinite = jnp.isinf(thickness)
    d = jnp.where(semi_infinite, 1.0, thickness)
    l = jnp.minimum(coeff.source_depth, d)

    def from_side(z_near, z_far):
        # Source at depth l below the face the light enters; z_near is that face's extrapolation.
        span = d + z_near + z_far
        reflect = (
            half_albedo
            * jnp.exp(-k * l)
            * (1.0 + jnp.exp(-2.0 * k * z_near))
            * _ratio(k, d + z_far - l, span)
        )
        transmit = (
            half_albedo
            * jnp.exp(-k * (d - l))
            * (1.0 + jnp.exp(-2.0 * k * z_far))
            * _ratio(k, l + z_near, span)
        )
        return reflect, transmit

    r_top, t_top = from_side(z_top, z_bottom)
    r_bottom, t_bottom = from_side(z_bottom, z_top)
    r_semi = half_albedo * (jnp.exp(-k * coeff.source_depth) + jnp.exp(-k * (coeff.source_depth + 2.0 * z_top)))
    zero = jnp.zeros_like(r_top)
    return SlabResponse(
        reflect_top=jnp.where(semi_infinite, r_semi, r_top),
        transmit_top=jnp.where(semi_infinite, zero, t_top),
        reflect_bottom=jnp.where(semi_infinite, zero, r_bottom),
        transmit_bottom=jnp.where(semi_infinite, zero, t_bottom),
    )


def _dipole_geometry(absorption, reduced_scattering, eta_top, thickness):
    """Diffusion quantities, and the real and virtual source depths of the top-face dipole.

    The real source depth is clamped to ``thickness`` exactly as in ``slab_response``, so that the
    dipole is the leading (slowest-decaying in q) part of a finite slab's R+ as well.
    """
    coeff = diffusion_coefficients(absorption, reduced_scattering)
    thickness = jnp.asarray(thickness)
    z_real = jnp.minimum(coeff.source_depth, jnp.where(jnp.isinf(thickness), coeff.source_depth, thickness))
    z_virtual = z_real + 4.0 * boundary_coefficient(eta_top) * coeff.diffusion
    return coeff, z_real, z_virtual


def dipole_transfer(absorption, reduced_scattering, eta_top, q=0.0, thickness=float("inf")):
    """Frequency-domain R(q) of the top-face dipole, (alpha'/2) (e^{-k z_r} + e^{-k z_v})."""
    coeff, z_real, z_virtual = _dipole_geometry(absorption, reduced_scattering, eta_top, thickness)
    k = _wavenumber(coeff.sigma_tr_squared, q)
    return 0.5 * coeff.albedo * (jnp.exp(-k * z_real) + jnp.exp(-k * z_virtual))


def dipole_profile(
    absorption: ArrayLike,
    reduced_scattering: ArrayLike,
    eta_top: ArrayLike,
    radius_mm: ArrayLike,
    thickness: ArrayLike = float("inf"),
) -> Float[Array, "..."]:
    """Real-space R(r) in mm^-2 of the top-face dipole (Jensen et al. 2001 for a semi-infinite layer).

    The exact inverse Hankel transform of ``dipole_transfer``, from
    FT2D{z (1 + s rho) e^{-s rho} / rho^3} = 2 pi e^{-k z} with rho = sqrt(r^2 + z^2):
    R(r) = (alpha'/4 pi) sum over the real and virtual source of z (1 + s rho) e^{-s rho} / rho^3,
    s = sigma_tr.
    """
    coeff, z_real, z_virtual = _dipole_geometry(absorption, reduced_scattering, eta_top, thickness)
    sigma_tr = _wavenumber(coeff.sigma_tr_squared, 0.0)
    r2 = jnp.square(jnp.asarray(radius_mm))

    def pole(z):
        rho = jnp.sqrt(r2 + z**2)
        return z * (1.0 + sigma_tr * rho) * jnp.exp(-sigma_tr * rho) / rho**3

    return coeff.albedo / (4.0 * jnp.pi) * (pole(z_real) + pole(z_virtual))


def dipole_energy(
    absorption: ArrayLike,
    reduced_scattering: ArrayLike,
    eta_top: ArrayLike,
    radius_mm: ArrayLike,
    thickness: ArrayLike = float("inf"),
) -> Float[Array, "..."]:
    """Integral of 2 pi r R(r) dr over 0 <= r <= radius of ``dipole_profile`` (dimensionless).

    Each pole integrates in closed form, since d/drho (e^{-s rho}/rho) = -(1 + s rho) e^{-s rho}/rho^2:
    (alpha'/2) (e^{-s z} - z e^{-s rho_a} / rho_a), rho_a = sqrt(radius^2 + z^2).
    """
    coeff, z_real, z_virtual = _dipole_geometry(absorption, reduced_scattering, eta_top, thickness)
    sigma_tr = _wavenumber(coeff.sigma_tr_squared, 0.0)
    a2 = jnp.square(jnp.asarray(radius_mm))

    def pole(z):
        rho = jnp.sqrt(a2 + z**2)
        return jnp.exp(-sigma_tr * z) - z * jnp.exp(-sigma_tr * rho) / rho

    return 0.5 * coeff.albedo * (pole(z_real) + pole(z_virtual))
