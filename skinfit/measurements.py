"""Readers for measured reflectance spectra."""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np

from ._validate import SkinfitInputError


@dataclasses.dataclass(frozen=True)
class NistSpectra:
    """The NIST skin reflectance set (DOI 10.18434/M38597).

    Attributes:
        wavelengths_nm: (n_wavelengths,)
        subjects: subject names, e.g. "Subject 1".
        repeats: (n_subjects, 3, n_wavelengths) the three repeat measurements.
        average: (n_subjects, n_wavelengths) their mean, as published.
    """

    wavelengths_nm: np.ndarray
    subjects: tuple[str, ...]
    repeats: np.ndarray
    average: np.ndarray


def read_nist(path: str | Path) -> NistSpectra:
    """Read the NIST skin reflectance CSV (original layout; cp1252 or UTF-8)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise SkinfitInputError(f"cannot read {path}: {err.strerror}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("cp1252")
    rows = list(csv.reader(text.splitlines()))
    try:
        header_at = next(i for i, row in enumerate(rows) if row and row[0].strip().startswith("Wavelength"))
    except StopIteration:
        raise SkinfitInputError(f"{path} is not in the NIST layout (no 'Wavelength (nm)' header row)") from None
    names_row, header = rows[header_at - 1], rows[header_at]
    while header and not header[-1].strip():  # trailing empty columns
        header = header[:-1]
    try:
        data = np.array([[float(v) for v in row[: len(header)]] for row in rows[header_at + 1 :] if row and row[0].strip()])
    except ValueError as err:
        raise SkinfitInputError(f"{path}: non-numeric value in the data rows ({err})") from None
    subjects, repeats, average = [], [], []
    for col, label in enumerate(header):
        if label.strip() == "Average":
            start = col - 3
            subjects.append(names_row[start].strip() or f"Subject {len(subjects) + 1}")
            repeats.append(data[:, start:col].T)
            average.append(data[:, col])
    if not subjects:
        raise SkinfitInputError(f"{path}: no 'Average' columns found")
    return NistSpectra(data[:, 0], tuple(subjects), np.stack(repeats), np.stack(average))
