"""Arguments the commands share: wavelengths, radii, skin parameters, the model and its options, and
the input spectra; usage errors are ``SkinfitInputError`` (one line, exit status 2)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from .._validate import SkinfitInputError
from ..io import read_nist, read_spectra_csv
from ..model import ADDING_MODES, PRESET_NAMES, SkinModel, SkinParams, preset

DEFAULT_WAVELENGTHS = "400:700:10"
DEFAULT_RADII = "0.001:20:256"


class Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2 (argparse prints the whole usage by default)
        self.exit(2, f"{self.prog}: error: {message}\n")


def parse_wavelengths(text: str) -> np.ndarray:
    """'START:STOP:STEP' (inclusive, nm), 'A,B,C' or a single value."""
    try:
        if ":" in text:
            start, stop, step = (float(v) for v in text.split(":"))
            if step <= 0 or stop < start:
                raise ValueError
            return np.arange(start, stop + 0.5 * step, step)
        return np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise SkinfitInputError(f"--wavelengths {text!r}: expected START:STOP:STEP, a list A,B,C or one value") from None


def parse_radii(text: str) -> np.ndarray:
    """'START:STOP:N' in mm: N radii, log-spaced if START > 0, else linear from 0."""
    try:
        start, stop, count = text.split(":")
        start, stop, count = float(start), float(stop), int(count)
        if count < 1 or stop <= start or start < 0:
            raise ValueError
    except ValueError:
        raise SkinfitInputError(f"--radii {text!r}: expected START:STOP:N with 0 <= START < STOP and N >= 1") from None
    return np.geomspace(start, stop, count) if start > 0 else np.linspace(start, stop, count)


def add_model_arguments(parser: argparse.ArgumentParser, wavelengths: str = DEFAULT_WAVELENGTHS) -> None:
    group = parser.add_argument_group("skin parameters (a preset, explicit values, or a preset with overrides)")
    group.add_argument("--preset", choices=PRESET_NAMES, help="built-in parameter set")
    group.add_argument("--melanin", type=float, help="C_m, epidermal melanin volume fraction (0-1)")
    group.add_argument("--melanin-blend", type=float, help="beta_m, eumelanin fraction of melanin (0-1)")
    group.add_argument("--haemoglobin", type=float, help="C_h, dermal blood volume fraction (0-1)")
    model = parser.add_argument_group("model options")
    model.add_argument("--wavelengths", default=wavelengths, help=f"nm, START:STOP:STEP or A,B,C (default {wavelengths})")
    add_model_choice(model)
    model.add_argument("--adding", choices=ADDING_MODES, default=None, help="layer adding of a diffusion model (default directional)")
    model.add_argument("--blood-oxygenation", type=float, default=None, help="HbO2 fraction (default: the model's; DJ2006 0.75)")
    model.add_argument("--epidermis-thickness-mm", type=float, default=None, help="mm (default: the model's; DJ2006 0.25)")
    model.add_argument("--ior", type=float, default=None, help="refractive index of skin (default: the model's, 1.4)")


def add_model_choice(parser) -> None:
    parser.add_argument("--model", default="calibrated", metavar="NAME",
                        help="skin model: calibrated (default: constants calibrated on measured skin), dj2006 (Donner & Jensen "
                             "2006), or a model JSON file (SkinModel.save, skinfit calibrate-model)")


def model_from(args) -> SkinModel:
    return SkinModel.named(getattr(args, "model", None) or "calibrated")


def params_from(args) -> SkinParams:
    values = {}
    if args.preset:
        base = preset(args.preset)
        values = {"melanin": float(base.melanin), "melanin_blend": float(base.melanin_blend), "haemoglobin": float(base.haemoglobin)}
    for name in ("melanin", "melanin_blend", "haemoglobin"):
        if getattr(args, name) is not None:
            values[name] = getattr(args, name)
    missing = [n.replace("_", "-") for n in ("melanin", "melanin_blend", "haemoglobin") if n not in values]
    if missing:
        raise SkinfitInputError(f"give --preset or all of --melanin, --melanin-blend, --haemoglobin (missing: --{', --'.join(missing)})")
    return SkinParams(**values)


def model_options_from(args) -> dict:
    options = {"model": model_from(args)}
    for name in ("adding", "blood_oxygenation", "epidermis_thickness_mm", "ior"):
        if getattr(args, name) is not None:
            options[name] = getattr(args, name)
    return options


def parse_white_balance(text: str):
    """--white-balance: none, auto, chart or R,G,B gains."""
    if text in ("none", "auto", "chart"):
        return text
    try:
        gains = tuple(float(v) for v in text.split(","))
    except ValueError:
        gains = ()
    if len(gains) != 3 or not all(g > 0 for g in gains):
        raise SkinfitInputError(f"--white-balance takes none, auto, chart or three positive gains R,G,B; got {text!r}")
    return gains


def read_input_spectra(args) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Names, wavelengths (nm) and spectra (n, m) from the INPUT file."""
    path = Path(args.input)
    if args.format == "nist":
        nist = read_nist(path)
        if args.nist_spectra == "average":
            return list(nist.subjects), nist.wavelengths_nm, nist.average
        names = [f"{s} R{i + 1}" for s in nist.subjects for i in range(nist.repeats.shape[1])]
        return names, nist.wavelengths_nm, nist.repeats.reshape(-1, nist.repeats.shape[-1])
    return read_spectra_csv(path)
