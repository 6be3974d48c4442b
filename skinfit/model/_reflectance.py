"""Diffuse reflectance of layer stacks and of skin, at normal incidence.

The quantity is the diffuse reflectance of a flat, uniformly lit patch with the specular surface
reflection excluded and the entry Fresnel transmittance included:

    R_diffuse = (1 - F0) R12(q = 0),     F0 = ((n - n_above) / (n + n_above))^2,

which matched Monte Carlo for light skin to 0.1-4 % (model notes 5.5).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .. import _validate
from . import _chromophores as chrom
from ._adding import Adding, check_adding
from ._layers import Layer
from ._methods import Diffusion, ForwardMethod, method_class, method_from_options
from ._params import SkinParams
from ._skin_model import SkinModel, resolve_model


def _check_stack(layers):
    if isinstance(layers, Layer):
        layers = [layers]
    layers = list(layers)
    if not layers or not all(isinstance(layer, Layer) for layer in layers):
        raise _validate.SkinfitInputError("layers must be a non-empty sequence of skinfit.model.Layer, top first")
    for layer in layers[:-1]:
        t = layer.thickness
        if _validate.is_concrete(t) and bool(jnp.any(jnp.isinf(t))):
            raise _validate.SkinfitInputError("only the bottom layer may be semi-infinite (thickness=inf)")
    return layers


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
        layers: ``skinfit.model.Layer`` objects, top first; only the last may be semi-infinite.
        adding: ``"directional"`` (default) or ``"symmetric"`` (DJ2005-literal, for comparison).
        ior_above: refractive index above the stack (air, 1.0).
        ior_below: refractive index below a finite bottom layer (diffusion only: with
            ``method="transport"`` a finite bottom layer exits into a medium of its own index).
        method: ``"diffusion"`` (DJ2005 multipole, default) or ``"transport"`` (exact 1-D
            radiative transport by adding-doubling with each layer's ``anisotropy`` g; one
            refractive index for the stack; ``skinfit.model``). A stack is always solved directly,
            so ``"transport-direct"`` means the same here.
        streams: quadrature directions per hemisphere for ``method="transport"``.

    Returns the broadcast shape of the layer fields (for example (..., n_wavelengths)).
    """
    layers = _check_stack(layers)
    check_adding(adding)
    return method_class(method).stack_reflectance(layers, adding=adding, ior_above=ior_above, ior_below=ior_below,
                                                  streams=streams)


def diffuse_reflectance(
    params: SkinParams,
    wavelengths_nm: ArrayLike,
    *,
    model: SkinModel | None = None,
    adding: Adding | None = None,
    blood_oxygenation: ArrayLike | None = None,
    epidermis_thickness_mm: ArrayLike | None = None,
    ior: ArrayLike | None = None,
    scattering_scale: ArrayLike = 1.0,
    method: str | None = None,
    anisotropy: ArrayLike | None = None,
    streams: int | None = None,
) -> Float[Array, "*batch n_wavelengths"]:
    """Diffuse reflectance of skin at normal incidence (specular excluded, entry Fresnel included).

    Args:
        params: ``SkinParams``; fields of batch shape (...) broadcast.
        wavelengths_nm: 1-D wavelengths in nm, within 250-1000 nm (the haemoglobin table).
        model: the ``SkinModel`` (constants and forward method); default ``SkinModel.default()``, the
            calibrated model. ``SkinModel.dj2006()`` is Donner & Jensen 2006.
        adding, blood_oxygenation, epidermis_thickness_mm, ior: override the model's value
            (``adding`` applies to diffusion: ``"directional"`` or ``"symmetric"``).
        scattering_scale: factor on the reduced scattering of both layers (1: the model's).
        method: override the model's forward method: ``"diffusion"`` (DJ2005 multipole),
            ``"transport"`` (exact 1-D transport through the tabulated adding-doubling: about the
            cost of diffusion, within 1e-3 of the direct solve; the table is shipped for g 0.8 and
            n 1.4, built once (minutes) and cached on disk for other values) or ``"transport-direct"``
            (the direct adding-doubling, the reference). ``ior`` must be concrete for either transport.
        anisotropy, streams: Henyey-Greenstein g (default 0.8) and quadrature directions of
            the transport methods.

    Returns:
        Array of shape (..., n_wavelengths): (1 - F0) R12(q = 0).
    """
    lam = checked_wavelengths(wavelengths_nm)
    model = model_with_options(model, adding=adding, blood_oxygenation=blood_oxygenation,
                               epidermis_thickness_mm=epidermis_thickness_mm, ior=ior, method=method,
                               anisotropy=anisotropy, streams=streams)
    _validate.check_range("scattering_scale", scattering_scale, 1e-3, 1e3)
    return skin_reflectance(params, lam, model, jnp.asarray(scattering_scale))


def model_with_options(model: SkinModel | None, *, adding=None, blood_oxygenation=None, epidermis_thickness_mm=None,
                       ior=None, method=None, anisotropy=None, streams=None) -> SkinModel:
    """``model`` (default: the package default) with the keyword overrides of the public functions."""
    model = resolve_model(model)  # checked
    if adding is not None:
        check_adding(adding)
    if method is not None:
        method_class(method)  # the string boundary: a registered method, checked before any work
    overrides = {name: _validate.as_float_array(name, value) for name, value in
                 (("blood_oxygenation", blood_oxygenation), ("epidermis_thickness_mm", epidermis_thickness_mm), ("ior", ior))
                 if value is not None}
    if overrides:
        model = model.replace(**overrides).check()
    # replacing the method rebuilds (and checks) the model
    if method is None and adding is not None and isinstance(model.method, Diffusion):
        method = "diffusion"  # an adding override of a diffusion model
    if method is not None:
        model = model.replace(method=method_from_options(method, adding=adding, anisotropy=anisotropy, ior=model.ior, streams=streams))
    return model


@eqx.filter_jit
def skin_reflectance(params, lam, model: SkinModel, scattering_scale=1.0):
    """Diffuse reflectance (1 - F0) R12(0) of ``model`` (traced constants; the method is static)."""
    epidermis, dermis = model.layers(params, lam, scattering_scale=scattering_scale)
    return skin_stack_reflectance(epidermis, dermis, model.method)


def skin_stack_reflectance(epidermis: Layer, dermis: Layer, method: ForwardMethod):
    """(1 - F0) R12(0) of an epidermis over a semi-infinite dermis by ``method``."""
    return method.reflectance(epidermis, dermis)


def checked_wavelengths(wavelengths_nm) -> jax.Array:
    return _validate.wavelengths(wavelengths_nm, low=chrom.WAVELENGTH_RANGE_NM[0], high=chrom.WAVELENGTH_RANGE_NM[1])
