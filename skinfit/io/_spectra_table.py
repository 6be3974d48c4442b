"""Spectra tables: a CSV file with a ``wavelength_nm`` column and one column per spectrum.

    wavelength_nm,subject A,subject B
    400,0.213,0.198
    ...

Lines starting with ``#`` are comments; an empty cell is a missing value (NaN).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._validate import SkinfitInputError


def read_spectra_csv(path) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Names, wavelengths (nm, shape (m,)) and reflectance spectra (shape (n, m)) from a CSV table."""
    path = Path(path)
    try:
        lines = [line for line in path.read_text(encoding="utf-8").splitlines() if line.strip() and not line.startswith("#")]
    except OSError as err:
        raise SkinfitInputError(f"cannot read {path}: {err.strerror}") from None
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    if not header or header[0] != "wavelength_nm" or len(header) < 2:
        raise SkinfitInputError(f"{path}: expected a header 'wavelength_nm,<name>,...' (NIST tables: skinfit.io.read_nist)")
    try:
        data = np.array([[float(v) if v.strip() else np.nan for v in line.split(",")] for line in lines[1:]])
    except ValueError as err:
        raise SkinfitInputError(f"{path}: non-numeric value ({err})") from None
    if data.ndim != 2 or data.shape[1] != len(header):
        raise SkinfitInputError(f"{path}: every row needs {len(header)} values")
    return header[1:], data[:, 0], data[:, 1:].T


def resample_spectra(wavelengths_nm, spectra, grid_nm) -> np.ndarray:
    """Spectra (n, m) sampled at ``wavelengths_nm`` (m,), linearly interpolated onto ``grid_nm``; the grid
    must lie within the data (no extrapolation)."""
    wavelengths_nm, grid_nm = np.asarray(wavelengths_nm, float), np.asarray(grid_nm, float)
    lo, hi = wavelengths_nm.min(), wavelengths_nm.max()
    if grid_nm.min() < lo or grid_nm.max() > hi:
        raise SkinfitInputError(f"--wavelengths {grid_nm.min():g}-{grid_nm.max():g} nm reaches outside the data ({lo:g}-{hi:g} nm)")
    order = np.argsort(wavelengths_nm)
    return np.stack([np.interp(grid_nm, wavelengths_nm[order], s[order]) for s in np.asarray(spectra)])
