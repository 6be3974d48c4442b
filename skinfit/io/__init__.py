"""Reading and writing files: images (EXR, PNG, linear sRGB, masks) and measured spectra (NIST,
the ISSA archive layout, CSV tables). Imports ``skinfit.colorimetry`` for the sRGB transfer function.
"""

from ._images import (
    read_exr_channels,
    read_image,
    read_linear_rgb,
    read_mask,
    to_linear_srgb,
    write_exr,
    write_png,
)
from ._measurements import FACE_SITES, ArchiveSpectra, NistSpectra, read_issa, read_nist
from ._spectra_table import read_spectra_csv, resample_spectra

__all__ = [
    "ArchiveSpectra",
    "FACE_SITES",
    "NistSpectra",
    "read_exr_channels",
    "read_issa",
    "read_image",
    "read_linear_rgb",
    "read_mask",
    "read_nist",
    "read_spectra_csv",
    "resample_spectra",
    "to_linear_srgb",
    "write_exr",
    "write_png",
]
