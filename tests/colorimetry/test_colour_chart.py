"""Colour calibration from a ColorChecker in the frame (colour-checker-detection + colour.characterisation)."""

import numpy as np
import pytest

from skinfit import render_maps
from skinfit._validate import SkinfitInputError
from skinfit.colorimetry import chart_calibration, reference_swatches
from skinfit.fit import PixelStatus, fit_image

#: A camera's colour cast and exposure: what the chart must undo.
CAST = 0.8 * np.array([[0.9, 0.08, 0.02], [0.05, 1.0, 0.05], [0.02, 0.1, 0.7]])


def chart_scene(face=None):
    """A 4 x 6 chart of the reference swatches (linear sRGB, clipped to [0, 1]) on a dark card,
    and optionally a face patch (h, w, 3) beside it, seen through CAST."""
    reference = np.clip(reference_swatches(), 0.0, 1.0)
    image = np.full((420, 720, 3), 0.02)
    top, left, size, gap = 60, 40, 56, 10
    image[top - 16 : top + 4 * (size + gap) + 6, left - 16 : left + 6 * (size + gap) + 6] = 0.01
    for i in range(4):
        for j in range(6):
            image[top + i * (size + gap) : top + i * (size + gap) + size, left + j * (size + gap) : left + j * (size + gap) + size] = reference[6 * i + j]
    if face is not None:
        image[100 : 100 + face.shape[0], 480 : 480 + face.shape[1]] = face
    return image @ CAST.T, reference


def test_chart_correction_undoes_a_colour_cast():
    seen, reference = chart_scene()
    calibration = chart_calibration(seen)
    inside = np.all((reference > 0.0) & (reference < 1.0), axis=1)  # clipped swatches are not the chart's colour
    np.testing.assert_allclose(calibration.apply(calibration.measured)[inside], reference[inside], atol=0.01)
    assert np.median(calibration.delta_e2000) < 1.0
    np.testing.assert_allclose(calibration.matrix @ CAST, np.eye(3), atol=0.03)


def test_fit_image_with_a_chart_recovers_the_skin_under_the_cast():
    y, x = np.mgrid[0:32, 0:32] / 31
    melanin, haemoglobin, shading = 0.03 + 0.05 * x, 0.01 + 0.02 * y, np.full((32, 32), 0.7)
    face = render_maps(melanin, haemoglobin, shading)
    seen, _ = chart_scene(face)
    mask = np.zeros(seen.shape[:2])
    mask[100:132, 480:512] = 1
    fit = fit_image(seen, mask=mask, colour_chart=True, progress=False)
    ok = fit.status[100:132, 480:512] == PixelStatus.SUCCESS
    assert ok.mean() > 0.95
    error = np.abs(fit.melanin[100:132, 480:512] - melanin) / melanin
    assert np.median(error[ok]) < 0.1  # the chart's 3 x 3 fit leaves a residual cast of ~1 %
    assert fit.white_balance == (1.0, 1.0, 1.0) and "colour_chart_matrix" in fit.summary()
    # the reconstruction is in the camera's values, as the input
    np.testing.assert_allclose(fit.fitted_linear_rgb[100:132, 480:512][ok], seen[100:132, 480:512][ok], rtol=0.02)


def test_no_chart_is_a_clear_error():
    with pytest.raises(SkinfitInputError, match="no ColorChecker"):
        chart_calibration(np.full((200, 300, 3), 0.3))
