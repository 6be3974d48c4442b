"""Frequency-domain adding of layers (Donner & Jensen 2005, "Kubelka-Munk in frequency space").

At each radial frequency q the lateral convolutions of the real-space profiles become products, so
the inter-reflections between a layer (1) and everything below it (2) sum as a geometric series:

    directional:  R12 = R1+ + T1+ R2 T1- / (1 - R2 R1-)
    symmetric:    R12 = R1+ + T1+ R2 T1+ / (1 - R2 R1+)     (DJ2005 as written; pbrt-v2-skin)

where + is light entering layer 1 from above and - from below. For skin the top face borders air
and the bottom face tissue, so R1- >> R1+ and T1- < T1+; the symmetric form is 12-20 % too bright
against Monte Carlo for light skin (model notes 5.4-5.5). It is kept only for comparison.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

from jaxtyping import Array, ArrayLike, Float

from .._validate import SkinfitInputError
from ._layers import Layer
from ._multipole import SlabResponse, slab_response

Adding = Literal["directional", "symmetric"]
ADDING_MODES = ("directional", "symmetric")


def add_below(top: SlabResponse, below_reflectance, adding: Adding = "directional"):
    """Reflectance from above of ``top`` over a substrate with reflectance ``below_reflectance``."""
    if adding == "directional":
        return top.reflect_top + top.transmit_top * below_reflectance * top.transmit_bottom / (
            1.0 - below_reflectance * top.reflect_bottom
        )
    if adding == "symmetric":
        return top.reflect_top + top.transmit_top**2 * below_reflectance / (
            1.0 - below_reflectance * top.reflect_top
        )
    raise ValueError(f"adding must be one of {ADDING_MODES}, got {adding!r}")


def stack_reflectance(responses: list[SlabResponse], adding: Adding = "directional"):
    """Reflectance from above of a stack of layer responses (top first), folded from the bottom."""
    reflectance = responses[-1].reflect_top
    for response in reversed(responses[:-1]):
        reflectance = add_below(response, reflectance, adding)
    return reflectance


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


def check_adding(adding) -> None:
    """A clear error for an adding mode other than ``ADDING_MODES``."""
    if adding not in ADDING_MODES:
        raise SkinfitInputError(f"adding must be one of {', '.join(ADDING_MODES)}, got {adding!r}")
