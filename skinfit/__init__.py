"""skinfit: the Donner & Jensen 2006 spectral two-layer skin model in JAX, differentiable and fast.

Data flow, one subpackage per stage, each importing only the ones before it:

    model -> colorimetry -> io -> planning -> export -> fit -> cli

``skinfit.model`` (parameters, optics, multipole, adding, profiles, transport), ``skinfit.colorimetry``
(CIE colour, CIEDE2000, the colour spline), ``skinfit.io`` (images, measured spectra),
``skinfit.planning`` (compute only what a request needs), ``skinfit.export`` (profile tables, renderer
formats), ``skinfit.fit`` (spectra, images, model calibration) and ``skinfit.cli``. The names below are
what a user calls; everything else lives in its subpackage, and ``skinfit.internal`` gathers the
machinery the benchmarks use. Units: lengths mm, coefficients mm^-1, wavelengths nm.

Importing skinfit enables JAX float64 (``jax_enable_x64``): the model runs in float64 unless its
inputs are float32. It also keeps compiled programs on disk between runs (JAX's persistent
compilation cache, in a private per-machine folder, never over the user's own JAX setting); set
``SKINFIT_COMPILATION_CACHE=0`` before the import to opt out (``skinfit._compilation_cache``). Image
fits' colour tables are kept there too (``SKINFIT_DISK_CACHE=0`` opts out; ``skinfit._disk_cache``).
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from ._compilation_cache import enable_compilation_cache as _enable_compilation_cache  # noqa: E402

_enable_compilation_cache()

# the imports follow the stages, lowest first
from . import _deprecated  # noqa: E402
from ._validate import SkinfitInputError  # noqa: E402
from ._version import __version__  # noqa: E402, F401
from .model import (  # noqa: E402
    PRESET_NAMES,
    Diffusion,
    Layer,
    SkinModel,
    SkinParams,
    Transport,
    diffuse_reflectance,
    layered_reflectance,
    preset,
    profile,
)
from .colorimetry import render_maps, spectrum_to_srgb  # noqa: E402
from .io import read_issa, read_nist  # noqa: E402
from .planning import Request, plan  # noqa: E402
from .export import profile_table, renderer_profiles, write_renderer  # noqa: E402
from .fit import (  # noqa: E402
    FitStatus,
    ImageFit,
    ModelCalibration,
    PixelStatus,
    SpectralFit,
    calibrate_model,
    fit_image,
    fit_spectra,
)
from . import cli, colorimetry, export, fit, io, model, planning  # noqa: E402, F401 - the stages, as attributes

_deprecated.install_finder()

__all__ = [
    # parameters and the model
    "SkinParams",
    "preset",
    "PRESET_NAMES",
    "SkinModel",
    "Diffusion",
    "Transport",
    # forward model
    "diffuse_reflectance",
    "Layer",
    "layered_reflectance",
    "profile",
    "spectrum_to_srgb",
    "render_maps",
    "plan",
    "Request",
    # fits and their results
    "fit_spectra",
    "SpectralFit",
    "FitStatus",
    "fit_image",
    "ImageFit",
    "PixelStatus",
    "calibrate_model",
    "ModelCalibration",
    # data and exports
    "read_nist",
    "read_issa",
    "profile_table",
    "renderer_profiles",
    "write_renderer",
    # errors
    "SkinfitInputError",
]


def __getattr__(name: str):
    # the 0.1 names and flat modules, for one release (skinfit._deprecated)
    return _deprecated.moved_attribute(name)


def __dir__():
    return sorted(set(globals()) | set(__all__))
