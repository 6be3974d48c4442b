"""Colour: CIE observers and illuminants, sRGB, CIELAB and CIEDE2000 (``_cie``), the colour spline
that maps parameters to linear sRGB fast (``_colour_table``), parameter maps rendered to colour
(``_map_rendering``) and colour-chart calibration of photographs (``_colour_chart``). Imports only
``skinfit.model`` below it.
"""

from ._cie import (
    DEFAULT_ILLUMINANT,
    delta_e2000,
    linear_srgb_to_lab,
    linear_srgb_weights,
    spectrum_to_linear_srgb,
    spectrum_to_srgb,
    spectrum_to_xyz,
    srgb_decode,
    srgb_encode,
    xyz_to_lab,
    xyz_to_linear_srgb,
    xyz_weights,
)
from ._colour_chart import ChartCalibration, chart_calibration, reference_swatches
from ._colour_table import (
    COLOUR_WAVELENGTHS_NM,
    DARK_HAEMOGLOBIN_MAX,
    DARK_MELANIN_MAX,
    HAEMOGLOBIN_MAX,
    MELANIN_MAX,
    ColourTable,
    chromaticity,
    colour_table,
    model_rgb,
    params_rgb,
    spline_channels,
    spline_rgb,
    warm_starts,
)
from ._map_rendering import render_maps

__all__ = [
    "chart_calibration",
    "ChartCalibration",
    "chromaticity",
    "colour_table",
    "COLOUR_WAVELENGTHS_NM",
    "ColourTable",
    "DEFAULT_ILLUMINANT",
    "delta_e2000",
    "HAEMOGLOBIN_MAX",
    "DARK_HAEMOGLOBIN_MAX",
    "DARK_MELANIN_MAX",
    "linear_srgb_to_lab",
    "linear_srgb_weights",
    "MELANIN_MAX",
    "model_rgb",
    "params_rgb",
    "reference_swatches",
    "render_maps",
    "spectrum_to_linear_srgb",
    "spectrum_to_srgb",
    "spectrum_to_xyz",
    "spline_channels",
    "spline_rgb",
    "srgb_decode",
    "srgb_encode",
    "warm_starts",
    "xyz_to_lab",
    "xyz_to_linear_srgb",
    "xyz_weights",
]
