"""skinfit: the Donner & Jensen 2006 spectral two-layer skin model in JAX, differentiable and fast.

Data flow: parameters -> optical coefficients -> layer responses -> adding -> reflectance / profiles
-> colour -> fit. Units: lengths mm, coefficients mm^-1, wavelengths nm.

Importing skinfit enables JAX float64 (``jax_enable_x64``): the model runs in float64 unless its
inputs are float32.
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"

from ._validate import SkinfitInputError  # noqa: E402
from .adding import stack_reflectance  # noqa: E402
from .colorimetry import (  # noqa: E402
    linear_srgb_weights,
    spectrum_to_linear_srgb,
    spectrum_to_srgb,
    spectrum_to_xyz,
    srgb_decode,
    srgb_encode,
    xyz_to_linear_srgb,
    xyz_weights,
)
from .spectral_fit import FitStatus, SolverSettings, SpectralFit, fit_spectra  # noqa: E402
from .hankel import HankelQuadrature  # noqa: E402
from .calibration import ImageCalibration, calibrate  # noqa: E402
from .colour_chart import ChartCalibration, chart_calibration  # noqa: E402
from .colour_table import ColourTable, colour_table  # noqa: E402
from .image_fit import ImageFit, PixelStatus, fit_image, fit_pixels, render_maps  # noqa: E402
from .images import read_linear_rgb, read_mask  # noqa: E402
from .layers import Layer  # noqa: E402
from .skin_model import Diffusion, PopulationPrior, ScatteringLaw, SkinModel, Transport, skin_layers  # noqa: E402
from .measurements import ArchiveSpectra, NistSpectra, read_issa, read_nist  # noqa: E402
from .model_calibration import ModelCalibration, calibrate_model  # noqa: E402
from .monte_carlo import MonteCarloResult, monte_carlo_reflectance  # noqa: E402
from .multipole import SlabResponse, slab_response  # noqa: E402
from .params import PRESET_NAMES, SkinParams, preset, preset_source  # noqa: E402
from .planning import Plan, Request, plan  # noqa: E402
from .profiles import captured_reflectance, layered_profile, profile  # noqa: E402
from .reflectance import diffuse_reflectance, layered_reflectance, stack_transfer  # noqa: E402
from .renderer_media import RendererConventions, RendererMedium, transport_medium  # noqa: E402
from .renderers import RendererProfiles, renderer_profiles, renderer_textures, write_renderer  # noqa: E402
from .surface import brdf, lobe_albedo, reflectance_factor, surface_energy  # noqa: E402
from .tables import ProfileTable, profile_table, read_exr_table, write_table  # noqa: E402

__all__ = [
    "ArchiveSpectra",
    "ModelCalibration",
    "calibrate_model",
    "read_issa",
    "Diffusion",
    "PopulationPrior",
    "ScatteringLaw",
    "SkinModel",
    "Transport",
    "FitStatus",
    "SolverSettings",
    "SpectralFit",
    "brdf",
    "captured_reflectance",
    "fit_spectra",
    "HankelQuadrature",
    "ColourTable",
    "ImageCalibration",
    "ChartCalibration",
    "chart_calibration",
    "ImageFit",
    "PixelStatus",
    "calibrate",
    "colour_table",
    "fit_image",
    "fit_pixels",
    "read_linear_rgb",
    "read_mask",
    "render_maps",
    "Layer",
    "MonteCarloResult",
    "monte_carlo_reflectance",
    "NistSpectra",
    "PRESET_NAMES",
    "Plan",
    "Request",
    "ProfileTable",
    "SkinParams",
    "SkinfitInputError",
    "SlabResponse",
    "diffuse_reflectance",
    "layered_profile",
    "layered_reflectance",
    "lobe_albedo",
    "linear_srgb_weights",
    "plan",
    "preset",
    "preset_source",
    "profile",
    "profile_table",
    "read_exr_table",
    "read_nist",
    "RendererProfiles",
    "renderer_profiles",
    "renderer_textures",
    "RendererConventions",
    "RendererMedium",
    "transport_medium",
    "reflectance_factor",
    "skin_layers",
    "slab_response",
    "spectrum_to_linear_srgb",
    "spectrum_to_srgb",
    "spectrum_to_xyz",
    "srgb_decode",
    "srgb_encode",
    "stack_reflectance",
    "stack_transfer",
    "surface_energy",
    "write_renderer",
    "write_table",
    "xyz_to_linear_srgb",
    "xyz_weights",
]
