"""Semi-public machinery for benchmarks and experiments (like ``equinox.internal``): stable enough to
use, not part of the user API, may change between releases without deprecation.

Each name is re-exported from the subpackage that owns it.
"""

from ._batching import map_batches
from .colorimetry import colour_table, model_rgb, spline_rgb
from .fit import LockstepState, build_fit_table, measurement_model
from .model import (
    ADDING_MODES,
    METHODS,
    HankelQuadrature,
    SlabResponse,
    add_below,
    model_with_options,
    resolve_model,
    skin_profile,
    skin_reflectance,
    skin_stack_reflectance,
    slab_response,
    solve_dominant,
    stack_reflectance,
    stack_reflectance_transport,
    stack_transfer,
)

__all__ = [
    "ADDING_MODES",
    "HankelQuadrature",
    "LockstepState",
    "METHODS",
    "SlabResponse",
    "add_below",
    "build_fit_table",
    "colour_table",
    "map_batches",
    "measurement_model",
    "model_rgb",
    "model_with_options",
    "resolve_model",
    "skin_profile",
    "skin_reflectance",
    "skin_stack_reflectance",
    "slab_response",
    "solve_dominant",
    "spline_rgb",
    "stack_reflectance",
    "stack_reflectance_transport",
    "stack_transfer",
]
