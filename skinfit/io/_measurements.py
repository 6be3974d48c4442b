"""Readers for measured reflectance spectra."""

from __future__ import annotations

import csv
import dataclasses
from pathlib import Path

import numpy as np

from .._validate import SkinfitInputError


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


@dataclasses.dataclass(frozen=True)
class ArchiveSpectra:
    """Spectra of a multi-subject archive (e.g. the International Skin Spectra Archive, ISSA).

    Attributes:
        wavelengths_nm: (m,)
        reflectance: (n, m) reflectance factor (0-1); NaN where a record has no value.
        records: (n,) per-spectrum metadata, a dict each (origin, subject, ethnic_group, body_site, ...).
        subjects: (n,) subject label of each spectrum (origin and subject number: numbers restart per origin).
    """

    wavelengths_nm: np.ndarray
    reflectance: np.ndarray
    records: tuple[dict, ...]
    subjects: np.ndarray

    def select(self, keep: np.ndarray) -> "ArchiveSpectra":
        keep = np.asarray(keep)
        return ArchiveSpectra(self.wavelengths_nm, self.reflectance[keep], tuple(np.asarray(self.records, dtype=object)[keep]),
                              self.subjects[keep])

    def complete(self, wavelengths_nm) -> "ArchiveSpectra":
        """The spectra with a value at every one of ``wavelengths_nm``, restricted to them."""
        at = [int(np.flatnonzero(np.isclose(self.wavelengths_nm, w))[0]) for w in wavelengths_nm]
        values = self.reflectance[:, at]
        keep = np.all(np.isfinite(values), axis=1)
        picked = self.select(keep)
        return dataclasses.replace(picked, wavelengths_nm=np.asarray(wavelengths_nm, dtype=float), reflectance=values[keep])


#: Face sites of the ISSA body-site labels.
FACE_SITES = ("cheek", "cheek bone", "chin", "forehead", "nose tip")


def read_issa(path: str | Path) -> ArchiveSpectra:
    """Read the ISSA layout (Lu et al. 2025, Sci. Data, DOI 10.1038/s41597-025-04857-5): one record
    per row with columns ``record, origin, subject, ethnic_group, gender, age_group, body_site,
    specular``, then one column per wavelength in nm (reflectance factor 0-1; empty: no value)."""
    path = Path(path)
    try:
        rows = list(csv.reader(path.read_text(encoding="utf-8").splitlines()))
    except OSError as err:
        raise SkinfitInputError(f"cannot read {path}: {err.strerror}") from None
    if not rows:
        raise SkinfitInputError(f"{path} is empty")
    header = rows[0]
    spectral = [i for i, h in enumerate(header) if h.strip().replace(".", "", 1).isdigit()]
    meta = [i for i in range(len(header)) if i not in spectral]
    if not spectral or "subject" not in header:
        raise SkinfitInputError(f"{path}: not the ISSA layout (metadata columns, then one column per wavelength)")
    try:
        values = np.array([[float(r[i]) if i < len(r) and r[i].strip() else np.nan for i in spectral] for r in rows[1:]])
    except ValueError as err:
        raise SkinfitInputError(f"{path}: non-numeric reflectance ({err})") from None
    records = tuple({header[i]: (r[i] if i < len(r) else "") for i in meta} for r in rows[1:])
    subjects = np.array([f"{rec.get('origin', '')}:{rec['subject']}" for rec in records])
    return ArchiveSpectra(np.array([float(header[i]) for i in spectral]), values, records, subjects)
