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
from .fresnel import fresnel_reflectance, normal_fresnel_reflectance  # noqa: F401 - part of this module's API
from .layers import SKIN_ANISOTROPY, Layer
from .multipole import slab_response
from .params import SkinParams
from .skin_model import Diffusion, SkinModel, Transport, resolve_model
from .transport import transport_reflectance


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
        method: override the model's forward method: ``"diffusion"`` (DJ2005 multipole) or
            ``"transport"`` (direct adding-doubling, the reference; ``ior`` must then be concrete).
        anisotropy, streams: Henyey-Greenstein g (default 0.8) and quadrature directions of
            ``method="transport"``.

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
        _check_options(adding)
    if method is not None:
        _check_method(method)
    overrides = {name: _validate.as_float_array(name, value) for name, value in
                 (("blood_oxygenation", blood_oxygenation), ("epidermis_thickness_mm", epidermis_thickness_mm), ("ior", ior))
                 if value is not None}
    if overrides:
        model = model.replace(**overrides).check()
    # replacing the method rebuilds (and checks) the model
    if method == "diffusion" or (method is None and adding is not None and isinstance(model.method, Diffusion)):
        model = model.replace(method=Diffusion(adding or "directional"))
    elif method == "transport":
        ior_values = np.unique(np.asarray(model.ior, dtype=float)) if _validate.is_concrete(model.ior) else None
        if ior_values is None or ior_values.size != 1:
            raise _validate.SkinfitInputError("method='transport' needs one concrete ior for the skin")
        g = SKIN_ANISOTROPY if anisotropy is None else anisotropy
        _validate.check_range("anisotropy", g, -0.99, 0.99)
        if np.ndim(g) != 0:
            raise _validate.SkinfitInputError("anisotropy must be one value")
        model = model.replace(method=Transport(float(g), float(ior_values[0]), int(streams or 16)))
    return model


@eqx.filter_jit
def skin_reflectance(params, lam, model: SkinModel, scattering_scale=1.0):
    """Diffuse reflectance (1 - F0) R12(0) of ``model`` (traced constants; the method is static)."""
    epidermis, dermis = model.layers(params, lam, scattering_scale=scattering_scale)
    return skin_stack_reflectance(epidermis, dermis, model.method)


def skin_stack_reflectance(epidermis: Layer, dermis: Layer, method: Diffusion | Transport):
    """(1 - F0) R12(0) of an epidermis over a semi-infinite dermis by ``method``."""
    if isinstance(method, Diffusion):
        r12 = stack_transfer([epidermis, dermis], 0.0, adding=method.adding)
        return (1.0 - normal_fresnel_reflectance(epidermis.ior)) * r12
    if method.table is not None:
        return method.table.reflectance(epidermis.absorption, epidermis.reduced_scattering, epidermis.thickness,
                                        dermis.absorption, dermis.reduced_scattering)
    shape = jnp.broadcast_shapes(jnp.shape(epidermis.absorption), jnp.shape(dermis.absorption))
    g = jnp.full(shape, method.anisotropy, jnp.result_type(epidermis.absorption))
    layers = [eqx.tree_at(lambda layer: layer.anisotropy, layer, g) for layer in (epidermis, dermis)]
    return transport_reflectance(layers, streams=method.streams, ior=method.ior, semi_infinite=True)


def checked_wavelengths(wavelengths_nm) -> jax.Array:
    return _validate.wavelengths(wavelengths_nm, low=chrom.WAVELENGTH_RANGE_NM[0], high=chrom.WAVELENGTH_RANGE_NM[1])
