"""Parameter maps to linear sRGB through the exact forward model and the camera model."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._batching import map_batches, pad_size
from ..model import SkinModel, model_with_options
from ._cie import DEFAULT_ILLUMINANT, linear_srgb_weights
from ._colour_table import COLOUR_WAVELENGTHS_NM, params_rgb


def render_maps(
    melanin,
    haemoglobin,
    shading,
    *,
    melanin_blend=0.7,
    illuminant: str = DEFAULT_ILLUMINANT,
    chunk_size: int = 65536,
    method: str | None = None,
    model: SkinModel | None = None,
) -> np.ndarray:
    """Linear sRGB (h, w, 3) of parameter maps through the exact forward model and camera model.

    Maps (h, w) in physical units (volume fractions; the blend may be a map or one value) are
    clipped to [0, 1]; pixels go through in fixed-size chunks, so memory stays bounded.
    """
    melanin, haemoglobin, shading = (np.asarray(a, dtype=float) for a in (melanin, haemoglobin, shading))
    blend = np.broadcast_to(np.asarray(melanin_blend, dtype=float), melanin.shape)
    columns = np.stack([np.clip(a, 0.0, 1.0).ravel() for a in (melanin, blend, haemoglobin)], axis=-1)
    weights = jnp.asarray(linear_srgb_weights(COLOUR_WAVELENGTHS_NM, illuminant))
    model = model_with_options(model, method=method)
    (rgb,) = map_batches(
        lambda c: (params_rgb(c, weights, model),), (columns,), pad_size(len(columns), chunk_size)
    )
    return shading[..., None] * rgb.reshape(*melanin.shape, 3)
