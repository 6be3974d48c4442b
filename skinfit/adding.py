"""Frequency-domain adding of layers (Donner & Jensen 2005, "Kubelka-Munk in frequency space").

At each radial frequency q the lateral convolutions of the real-space profiles become products, so
the inter-reflections between a layer (1) and everything below it (2) sum as a geometric series:

    directional:  R12 = R1+ + T1+ R2 T1- / (1 - R2 R1-)
    symmetric:    R12 = R1+ + T1+ R2 T1+ / (1 - R2 R1+)     (DJ2005 as written; pbrt-v2-skin)

where + is light entering layer 1 from above and - from below. For skin the top face borders air
and the bottom face tissue, so R1- >> R1+ and T1- < T1+; the symmetric form is 12-20 % too bright
against Monte Carlo for light skin (MODEL.md 5.4-5.5). It is kept only for comparison.
"""

from __future__ import annotations

from typing import Literal

from .multipole import SlabResponse

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
