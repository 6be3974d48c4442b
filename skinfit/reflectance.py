"""Diffuse reflectance of layer stacks and of skin, at normal incidence.

The quantity is the diffuse reflectance of a flat, uniformly lit patch with the specular surface
reflection excluded and the entry Fresnel transmittance included:

    R_diffuse = (1 - F0) R12(q = 0),     F0 = ((n - n_above) / (n + n_above))^2,

which matched Monte Carlo for light skin to 0.1-4 % (MODEL.md 5.5).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from . import chromophores as chrom
from . import _validate
from .adding import ADDING_MODES, Adding, stack_reflectance
from .layers import BLOOD_OXYGENATION, EPIDERMIS_THICKNESS_MM, SKIN_ANISOTROPY, SKIN_IOR, Layer, skin_layers
from .multipole import slab_response
from .params import SkinParams


#: The skin-model options of ``diffuse_reflectance`` at their DJ2006 values.
SKIN_OPTION_DEFAULTS = {
    "blood_oxygenation": BLOOD_OXYGENATION,
    "epidermis_thickness_mm": EPIDERMIS_THICKNESS_MM,
    "ior": SKIN_IOR,
    "scattering_scale": 1.0,
}


def fresnel_reflectance(cos_incidence: ArrayLike, n_from: ArrayLike, n_to: ArrayLike) -> Float[Array, "..."]:
    """Unpolarised Fresnel reflectance for light in index ``n_from`` meeting a face into ``n_to``
    at incidence cosine ``cos_incidence`` (in [0, 1]); 1 beyond the critical angle (NaN-free)."""
    c = jnp.clip(jnp.asarray(cos_incidence), 0.0, 1.0)
    n_from, n_to = jnp.asarray(n_from), jnp.asarray(n_to)
    sin_t2 = (n_from / n_to) ** 2 * (1.0 - c * c)
    total = sin_t2 >= 1.0
    cos_t = jnp.sqrt(jnp.where(total, 0.5, 1.0 - sin_t2))
    rs = ((n_from * c - n_to * cos_t) / (n_from * c + n_to * cos_t)) ** 2
    rp = ((n_from * cos_t - n_to * c) / (n_from * cos_t + n_to * c)) ** 2
    return jnp.where(total, 1.0, 0.5 * (rs + rp))


def normal_fresnel_reflectance(n_inside: ArrayLike, n_outside: ArrayLike = 1.0) -> Float[Array, "..."]:
    """Fresnel reflectance at normal incidence, ((n1 - n2) / (n1 + n2))^2."""
    n_inside, n_outside = jnp.asarray(n_inside), jnp.asarray(n_outside)
    return jnp.square((n_inside - n_outside) / (n_inside + n_outside))


def stack_transfer(
    layers: Sequence[Layer],
    q: ArrayLike = 0.0,
    *,
    adding: Adding = "directional",
    ior_above: ArrayLike = 1.0,
    ior_below: ArrayLike = 1.0,
) -> Float[Array, "..."]:
    """R12(q): frequency-domain diffuse reflectance of a stack (top first), without entry Fresnel.

    ``q`` (radial frequency, mm^-1) broadcasts against the layer fields. R12(0) is the total
    diffuse reflectance for light already inside the top layer; its inverse Hankel transform is the
    radial profile R(r) in mm^-2.
    """
    responses = []
    for i, layer in enumerate(layers):
        n_above = layers[i - 1].ior if i > 0 else ior_above
        n_below = layers[i + 1].ior if i + 1 < len(layers) else ior_below
        responses.append(
            slab_response(
                layer.absorption,
                layer.reduced_scattering,
                layer.thickness,
                eta_top=layer.ior / n_above,
                eta_bottom=layer.ior / n_below,
                q=q,
            )
        )
    return stack_reflectance(responses, adding)


def _check_options(adding):
    if adding not in ADDING_MODES:
        raise _validate.SkinfitInputError(f"adding must be one of {', '.join(ADDING_MODES)}, got {adding!r}")


def _check_stack(layers):
    if isinstance(layers, Layer):
        layers = [layers]
    layers = list(layers)
    if not layers or not all(isinstance(layer, Layer) for layer in layers):
        raise _validate.SkinfitInputError("layers must be a non-empty sequence of skinfit.Layer, top first")
    for layer in layers[:-1]:
        t = layer.thickness
        if _validate.is_concrete(t) and bool(jnp.any(jnp.isinf(t))):
            raise _validate.SkinfitInputError("only the bottom layer may be semi-infinite (thickness=inf)")
    return layers


METHODS = ("diffusion", "transport")


def layered_reflectance(
    layers: Sequence[Layer],
    *,
    adding: Adding = "directional",
    ior_above: ArrayLike = 1.0,
    ior_below: ArrayLike = 1.0,
    method: str = "diffusion",
    streams: int = 16,
) -> Float[Array, "..."]:
    """Diffuse reflectance (1 - F0) R12(0) of a user-defined stack of layers (top first).

    Args:
        layers: ``skinfit.Layer`` objects, top first; only the last may be semi-infinite.
        adding: ``"directional"`` (default) or ``"symmetric"`` (DJ2005-literal, for comparison).
        ior_above: refractive index above the stack (air, 1.0).
        ior_below: refractive index below a finite bottom layer (diffusion only: with
            ``method="transport"`` a finite bottom layer exits into a medium of its own index).
        method: ``"diffusion"`` (DJ2005 multipole, default) or ``"transport"`` (exact 1-D
            radiative transport by adding-doubling with each layer's ``anisotropy`` g; one
            refractive index for the stack; ``skinfit.transport``).
        streams: quadrature directions per hemisphere for ``method="transport"``.

    Returns the broadcast shape of the layer fields (for example (..., n_wavelengths)).
    """
    layers = _check_stack(layers)
    _check_method(method)
    if method == "transport":
        from .transport import transport_reflectance

        _validate.check_range("ior_above", ior_above, 1.0, 3.0)
        return transport_reflectance(layers, ior_above=float(np.asarray(ior_above)), streams=streams)
    _check_options(adding)
    return _layered_reflectance(layers, adding, jnp.asarray(ior_above), jnp.asarray(ior_below))


def _check_method(method):
    if method not in METHODS:
        raise _validate.SkinfitInputError(f"method must be one of {', '.join(METHODS)}, got {method!r}")


@eqx.filter_jit
def _layered_reflectance(layers, adding, ior_above, ior_below):
    r12 = stack_transfer(layers, 0.0, adding=adding, ior_above=ior_above, ior_below=ior_below)
    return (1.0 - normal_fresnel_reflectance(layers[0].ior, ior_above)) * r12


def diffuse_reflectance(
    params: SkinParams,
    wavelengths_nm: ArrayLike,
    *,
    adding: Adding = "directional",
    blood_oxygenation: ArrayLike = BLOOD_OXYGENATION,
    epidermis_thickness_mm: ArrayLike = EPIDERMIS_THICKNESS_MM,
    ior: ArrayLike = SKIN_IOR,
    scattering_scale: ArrayLike = 1.0,
    method: str = "diffusion",
    anisotropy: ArrayLike = SKIN_ANISOTROPY,
    streams: int = 16,
) -> Float[Array, "*batch n_wavelengths"]:
    """Diffuse reflectance of skin at normal incidence (specular excluded, entry Fresnel included).

    Args:
        params: ``SkinParams``; fields of batch shape (...) broadcast.
        wavelengths_nm: 1-D wavelengths in nm, within 250-1000 nm (the haemoglobin table).
        adding: ``"directional"`` (default) or ``"symmetric"``.
        blood_oxygenation: gamma, HbO2 fraction of the blood (DJ2006: 0.75).
        epidermis_thickness_mm: epidermis thickness in mm (DJ2006: 0.25).
        ior: refractive index of both layers (DJ2006: 1.4).
        scattering_scale: factor on the reduced scattering of both layers (DJ2006: 1).
        method: ``"diffusion"`` (DJ2006, default) or ``"transport"`` (adding-doubling, exact 1-D
            transport; ``ior`` must then be one concrete value).
        anisotropy: Henyey-Greenstein g of both layers for ``method="transport"`` (default 0.8,
            ``SKIN_ANISOTROPY``); the reduced scattering stays the input.
        streams: quadrature directions per hemisphere for ``method="transport"``.

    Returns:
        Array of shape (..., n_wavelengths): (1 - F0) R12(q = 0).
    """
    lam = _checked_wavelengths(wavelengths_nm)
    _check_method(method)
    options = _skin_options(adding, blood_oxygenation, epidermis_thickness_mm, ior, scattering_scale, like=(lam, params))
    if method == "transport":
        if not _validate.is_concrete(ior) or np.ndim(ior) != 0:
            raise _validate.SkinfitInputError("method='transport' needs one concrete ior for the skin")
        _validate.check_range("anisotropy", anisotropy, -0.99, 0.99)
        return _skin_reflectance_transport(params, lam, *options, anisotropy=jnp.asarray(anisotropy, lam.dtype),
                                           streams=int(streams), ior_value=float(np.asarray(ior)))
    return _skin_reflectance(params, lam, adding, *options)


def _skin_reflectance_transport(params, lam, blood_oxygenation, epidermis_thickness_mm, ior, scattering_scale, *,
                                anisotropy, streams: int, ior_value: float):
    """``diffuse_reflectance(..., method="transport")`` after validation (usable under jit and in
    fits: the options may be traced, the index ``ior_value`` is concrete)."""
    from .transport import transport_reflectance

    epidermis, dermis = (eqx.tree_at(lambda layer: layer.anisotropy, layer, jnp.broadcast_to(anisotropy, jnp.shape(layer.absorption)))
                         for layer in _skin_stack(params, lam, blood_oxygenation, epidermis_thickness_mm, ior, scattering_scale))
    return transport_reflectance([epidermis, dermis], streams=streams, ior=ior_value, semi_infinite=True)


def _skin_stack(params, lam, blood_oxygenation, epidermis_thickness_mm, ior, scattering_scale):
    """``skin_layers`` with the options in the order ``_skin_options`` returns them."""
    return skin_layers(
        params,
        lam,
        blood_oxygenation=blood_oxygenation,
        epidermis_thickness_mm=epidermis_thickness_mm,
        ior=ior,
        scattering_scale=scattering_scale,
    )


@eqx.filter_jit
def _skin_reflectance(params, lam, adding, blood_oxygenation, epidermis_thickness_mm, ior, scattering_scale):
    layers = _skin_stack(params, lam, blood_oxygenation, epidermis_thickness_mm, ior, scattering_scale)
    r12 = stack_transfer(layers, 0.0, adding=adding)
    return (1.0 - normal_fresnel_reflectance(ior[..., None])) * r12


def _checked_wavelengths(wavelengths_nm) -> jax.Array:
    return _validate.wavelengths(wavelengths_nm, low=chrom.WAVELENGTH_RANGE_NM[0], high=chrom.WAVELENGTH_RANGE_NM[1])


def _skin_options(adding, blood_oxygenation, epidermis_thickness_mm, ior, scattering_scale, *, like):
    """Validate the skin-model options; return the numeric ones as arrays (traced, not static, under jit).

    They take the floating dtype of ``like`` (wavelengths and parameters), so float32 inputs compute
    in float32.
    """
    _check_options(adding)
    _validate.check_range("blood_oxygenation", blood_oxygenation, 0.0, 1.0)
    _validate.check_range("epidermis_thickness_mm", epidermis_thickness_mm, 1e-9, 1e3, unit="mm")
    _validate.check_range("ior", ior, 1.0, 3.0)
    _validate.check_range("scattering_scale", scattering_scale, 1e-3, 1e3)
    dtype = jnp.result_type(*jax.tree_util.tree_leaves(like))
    return tuple(
        _validate.as_float_array(name, value).astype(dtype)
        for name, value in (
            ("blood_oxygenation", blood_oxygenation),
            ("epidermis_thickness_mm", epidermis_thickness_mm),
            ("ior", ior),
            ("scattering_scale", scattering_scale),
        )
    )
