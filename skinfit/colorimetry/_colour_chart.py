"""Colour calibration from a ColorChecker chart in the frame.

Where a photo holds a ColorChecker Classic (24 swatches), the chart fixes what a white balance
fitted from skin can only guess: ``chart_calibration`` finds the chart and its swatch colours with
colour-science's ``colour-checker-detection`` (segmentation), and fits the 3 x 3 matrix that takes
the camera's linear RGB to linear sRGB (D65 white) with ``colour.characterisation``
(``matrix_colour_correction``, Cheung et al. 2004, three terms: linear, so exposure scales through).
The reference swatches are the chart's published xyY values (colour-science's
``CCS_COLOURCHECKERS``; D50), adapted to D65 with the Bradford transform.

Conventions of the fit that follow: pixels are linear sRGB primaries (IEC 61966-2-1) with D65 white
at 1; the camera model's illuminant is D65 unless ``illuminant=`` says otherwise. To check a
calibration, look at ``ChartCalibration.delta_e2000`` (per swatch after correction; a good
characterisation of a real camera leaves a median of 1-3).

``colour-checker-detection`` (with OpenCV) is an optional dependency: ``pip install skinfit[chart]``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._validate import SkinfitInputError
from ._cie import delta_e2000, linear_srgb_to_lab

#: The chart skinfit calibrates against (colour-science's name of its reference data).
DEFAULT_CHART = "ColorChecker24 - After November 2014"


@dataclasses.dataclass(frozen=True)
class ChartCalibration:
    """A chart's colour correction: ``matrix`` (3, 3) takes camera linear RGB (..., 3) to linear
    sRGB as ``rgb @ matrix.T``; ``measured`` and ``reference`` (24, 3) are the swatches in the
    image and their linear sRGB values, ``delta_e2000`` (24,) the swatches' CIEDE2000 after correction."""

    chart: str
    matrix: np.ndarray
    measured: np.ndarray
    reference: np.ndarray
    delta_e2000: np.ndarray

    def apply(self, linear_rgb: np.ndarray) -> np.ndarray:
        """The corrected image (..., 3)."""
        return np.asarray(linear_rgb, dtype=float) @ self.matrix.T

    def invert(self, linear_srgb: np.ndarray) -> np.ndarray:
        """Back to the camera's values: what a reconstruction compares with the input."""
        return np.asarray(linear_srgb, dtype=float) @ np.linalg.inv(self.matrix).T


def reference_swatches(chart: str = DEFAULT_CHART) -> np.ndarray:
    """Linear sRGB (D65) of a chart's swatches (n, 3), from colour-science's published xyY values."""
    import colour

    if chart not in colour.CCS_COLOURCHECKERS:
        raise SkinfitInputError(f"unknown colour chart {chart!r}; colour-science knows {', '.join(sorted(colour.CCS_COLOURCHECKERS))}")
    data = colour.CCS_COLOURCHECKERS[chart]
    xyz = colour.xyY_to_XYZ(np.array(list(data.data.values())))
    return np.asarray(colour.XYZ_to_RGB(xyz, "sRGB", illuminant=data.illuminant, chromatic_adaptation_transform="Bradford"))


def chart_calibration(linear_rgb: np.ndarray, chart: str = DEFAULT_CHART) -> ChartCalibration:
    """Detect a ColorChecker in a linear image (h, w, 3) and fit its colour correction matrix."""
    try:
        from colour_checker_detection import detect_colour_checkers_segmentation
    except ImportError as error:
        raise SkinfitInputError("colour-chart calibration needs colour-checker-detection: pip install 'skinfit[chart]'") from error
    import colour

    image = np.asarray(linear_rgb, dtype=float)
    if image.ndim != 3 or image.shape[-1] != 3:
        raise SkinfitInputError(f"expected an image of shape (h, w, 3), got {image.shape}")
    found = detect_colour_checkers_segmentation(np.clip(image, 0.0, None), additional_data=True)
    if not found:
        raise SkinfitInputError("no ColorChecker chart found in the image (colour-checker-detection, segmentation)")
    measured = np.asarray(found[0].swatch_colours, dtype=float)
    reference = reference_swatches(chart)
    if measured.shape != reference.shape:
        raise SkinfitInputError(f"the detected chart has {len(measured)} swatches, {chart!r} {len(reference)}")
    matrix = np.asarray(colour.characterisation.matrix_colour_correction(measured, reference, method="Cheung 2004", terms=3))
    corrected = measured @ matrix.T
    delta_e = np.asarray(delta_e2000(linear_srgb_to_lab(np.clip(reference, 1e-6, None)), linear_srgb_to_lab(np.clip(corrected, 1e-6, None))))
    return ChartCalibration(chart, matrix, measured, reference, delta_e)
