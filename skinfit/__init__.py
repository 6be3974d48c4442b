"""skinfit: the Donner & Jensen 2006 spectral two-layer skin model in JAX, differentiable and fast.

Data flow: parameters -> optical coefficients -> layer responses -> adding -> reflectance / profiles
-> colour -> fit. Units: lengths mm, coefficients mm^-1, wavelengths nm.

Importing skinfit enables JAX float64 (``jax_enable_x64``): the model runs in float64 unless its
inputs are float32.
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from ._validate import SkinfitInputError  # noqa: E402
from .adding import stack_reflectance  # noqa: E402
from .layers import Layer, skin_layers  # noqa: E402
from .multipole import SlabResponse, slab_response  # noqa: E402
from .params import PRESET_NAMES, SkinParams, preset, preset_source  # noqa: E402
from .reflectance import diffuse_reflectance, layered_reflectance, stack_transfer  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "Layer",
    "PRESET_NAMES",
    "SkinParams",
    "SkinfitInputError",
    "SlabResponse",
    "diffuse_reflectance",
    "layered_reflectance",
    "preset",
    "preset_source",
    "skin_layers",
    "slab_response",
    "stack_reflectance",
    "stack_transfer",
]
