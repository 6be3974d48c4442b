"""Skin parameters of the Donner & Jensen 2006 model, and published presets."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._validate import SkinfitInputError, as_float_array, check_range

#: Valid range of each parameter (volume fractions and the oil lobe scale are all in [0, 1]).
PARAMETER_RANGES = {
    "melanin": (0.0, 1.0),
    "melanin_blend": (0.0, 1.0),
    "haemoglobin": (0.0, 1.0),
    "oil": (0.0, 1.0),
}


class SkinParams(eqx.Module):
    """The four DJ2006 skin parameters. Fields may be arrays; they broadcast against each other.

    Attributes:
        melanin: C_m, melanin volume fraction of the epidermis (typical 0.001-0.5).
        melanin_blend: beta_m, eumelanin fraction of that melanin (0-1); 1 - beta_m is pheomelanin.
        haemoglobin: C_h, whole-blood volume fraction of the dermis (typical 0.001-0.1).
        oil: rho_s, scale of the specular surface lobe (0-1); the diffuse model ignores it.

    A pytree: jit, vmap and grad accept it. Out-of-range or non-finite values raise
    ``SkinfitInputError`` when the parameters are built from concrete values.
    """

    melanin: Float[Array, "*batch"]
    melanin_blend: Float[Array, "*batch"]
    haemoglobin: Float[Array, "*batch"]
    oil: Float[Array, "*batch"]

    def __init__(self, melanin, melanin_blend, haemoglobin, oil=0.0):
        for name, value in (
            ("melanin", melanin),
            ("melanin_blend", melanin_blend),
            ("haemoglobin", haemoglobin),
            ("oil", oil),
        ):
            array = as_float_array(name, value)
            check_range(name, array, *PARAMETER_RANGES[name])
            setattr(self, name, array)
        try:
            shape = np.broadcast_shapes(*(jnp.shape(v) for v in self._values()))
        except ValueError:
            shapes = ", ".join(f"{n}{jnp.shape(v)}" for n, v in zip(PARAMETER_RANGES, self._values()))
            raise SkinfitInputError(f"SkinParams fields do not broadcast: {shapes}") from None
        # Every field gets the full batch shape, so vmap can map any batch axis of the bundle.
        for name in PARAMETER_RANGES:
            setattr(self, name, jnp.broadcast_to(getattr(self, name), shape))

    def _values(self):
        return (self.melanin, self.melanin_blend, self.haemoglobin, self.oil)

    @property
    def shape(self) -> tuple[int, ...]:
        """Broadcast batch shape of the fields."""
        return tuple(np.broadcast_shapes(*(jnp.shape(v) for v in self._values())))


# name: ((C_m, beta_m, C_h), source)
_PRESETS = {
    "light": (
        (0.005, 0.7, 0.005),
        "'white' set of damlaren/pbrt-skin-bssrdf scenes/skin.pbrt; also G0S0 multipole.py "
        "'Caucasian'; the light-skin fixture of model notes 5.4",
    ),
    "medium": (
        (0.15, 0.7, 0.01),
        "C_m and C_h of the damlaren 'asian' set with beta_m = 0.7, as in the Monte Carlo "
        "comparison of model notes 5.5 (the damlaren scene itself uses beta_m = 0)",
    ),
    "dark": (
        (0.5, 0.7, 0.05),
        "'black' set of damlaren/pbrt-skin-bssrdf scenes/skin.pbrt; model notes 5.5",
    ),
}

#: Names of the built-in presets.
PRESET_NAMES = tuple(_PRESETS)


def preset(name: str) -> SkinParams:
    """A built-in parameter set: ``"light"``, ``"medium"`` or ``"dark"`` (see ``preset_source``)."""
    try:
        (c_m, beta_m, c_h), _ = _PRESETS[name]
    except KeyError:
        raise SkinfitInputError(
            f"unknown preset {name!r}; choose one of {', '.join(PRESET_NAMES)}"
        ) from None
    return SkinParams(melanin=c_m, melanin_blend=beta_m, haemoglobin=c_h)


def preset_source(name: str) -> str:
    """Where a preset's values come from."""
    preset(name)  # validates the name
    return _PRESETS[name][1]


def stack_params(params: list[SkinParams]) -> SkinParams:
    """Stack parameter sets with equal shapes along a new leading axis."""
    return SkinParams(
        *(jnp.stack([jnp.broadcast_to(getattr(p, n), p.shape) for p in params]) for n in PARAMETER_RANGES)
    )
