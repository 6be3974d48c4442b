"""Inverting the model: fit variables and their bounds, warm starts, the lock-step solvers for spectra,
the transport polish, pixels and images (with their calibration), and the calibration of the model's own
constants against measured spectra.
"""

from ._face_blend import BLEND_GRID, MODEL_DISCREPANCY, BlendEstimate, estimate_blends
from ._image_calibration import ImageCalibration, calibrate
from ._images import ImageFit, fit_image, population_blend, skin_box
from ._linalg import solve_normal
from ._lockstep import LockstepState
from ._model_calibration import (
    CONSTANTS,
    DEFAULT_CONSTANTS,
    ModelCalibration,
    calibrate_model,
    on_a_bound,
    prior_table,
)
from ._pixels import PixelStatus, fit_pixels
from ._spatial import neighbourhood_median, smooth_field, speckle_fraction
from ._spectra import (
    FitStatus,
    SolverSettings,
    SpectralFit,
    fit_spectra,
    measurement_model,
)
from ._variables import CHROMOPHORES, VARIABLES, stationarity
from ._warm_start import build_fit_table

__all__ = [
    "build_fit_table",
    "calibrate",
    "estimate_blends",
    "BlendEstimate",
    "BLEND_GRID",
    "MODEL_DISCREPANCY",
    "calibrate_model",
    "CHROMOPHORES",
    "CONSTANTS",
    "DEFAULT_CONSTANTS",
    "fit_image",
    "fit_pixels",
    "fit_spectra",
    "FitStatus",
    "ImageCalibration",
    "ImageFit",
    "LockstepState",
    "measurement_model",
    "ModelCalibration",
    "neighbourhood_median",
    "on_a_bound",
    "PixelStatus",
    "population_blend",
    "prior_table",
    "smooth_field",
    "solve_normal",
    "skin_box",
    "SolverSettings",
    "speckle_fraction",
    "SpectralFit",
    "stationarity",
    "VARIABLES",
]
