"""The ``skinfit`` command line: spectra, profile tables, fits and the demo job.

Usage errors (bad arguments, out-of-range values) print one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

from ._validate import SkinfitInputError
from .adding import ADDING_MODES
from .colorimetry import spectrum_to_srgb, srgb_encode
from .distributed import fit_images_on_cluster
from .fit_outputs import encoded_srgb, fit_image_to_folder, write_fit
from .image_fit import fit_image
from .map_rendering import render_maps
from .images import read_exr_channels, read_linear_rgb, read_mask, write_exr, write_png
from .measurements import FACE_SITES, read_issa, read_nist
from .model_calibration import DEFAULT_CONSTANTS, calibrate_model
from .params import PRESET_NAMES, SkinParams, preset
from .planning import Request, plan
from .plots import plot_fits, plot_image_fit, plot_profiles, plot_spectra
from .reflectance import METHODS, diffuse_reflectance
from .renderers import renderer_profiles, renderer_textures, write_mitsuba_textures, write_renderer
from .skin_model import SkinModel
from .spectral_fit import FitStatus, fit_spectra
from .tables import profile_table, write_table

#: The bundled photo (package skinfit.data, folder data/ of the repository).
DEMO_PHOTO = "eileen_collins_face.png"
DEMO_MASK = "eileen_collins_skin_mask.png"  # made by benchmarks/demo_skin_mask.py
DEFAULT_WAVELENGTHS = "400:700:10"
DEFAULT_RADII = "0.001:20:256"


class _Parser(argparse.ArgumentParser):
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


def _add_model_arguments(parser: argparse.ArgumentParser, wavelengths: str = DEFAULT_WAVELENGTHS) -> None:
    group = parser.add_argument_group("skin parameters (a preset, explicit values, or a preset with overrides)")
    group.add_argument("--preset", choices=PRESET_NAMES, help="built-in parameter set")
    group.add_argument("--melanin", type=float, help="C_m, epidermal melanin volume fraction (0-1)")
    group.add_argument("--melanin-blend", type=float, help="beta_m, eumelanin fraction of melanin (0-1)")
    group.add_argument("--haemoglobin", type=float, help="C_h, dermal blood volume fraction (0-1)")
    model = parser.add_argument_group("model options")
    model.add_argument("--wavelengths", default=wavelengths, help=f"nm, START:STOP:STEP or A,B,C (default {wavelengths})")
    _add_model_choice(model)
    model.add_argument("--adding", choices=ADDING_MODES, default=None, help="layer adding of a diffusion model (default directional)")
    model.add_argument("--blood-oxygenation", type=float, default=None, help="HbO2 fraction (default: the model's; DJ2006 0.75)")
    model.add_argument("--epidermis-thickness-mm", type=float, default=None, help="mm (default: the model's; DJ2006 0.25)")
    model.add_argument("--ior", type=float, default=None, help="refractive index of skin (default: the model's, 1.4)")


def _add_model_choice(parser) -> None:
    parser.add_argument("--model", default="calibrated", metavar="NAME",
                        help="skin model: calibrated (default: constants calibrated on measured skin), dj2006 (Donner & Jensen "
                             "2006), or a model JSON file (SkinModel.save, skinfit calibrate-model)")


def _model(args) -> SkinModel:
    return SkinModel.named(getattr(args, "model", None) or "calibrated")


def _params(args) -> SkinParams:
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


def _model_options(args) -> dict:
    options = {"model": _model(args)}
    for name in ("adding", "blood_oxygenation", "epidermis_thickness_mm", "ior"):
        if getattr(args, name) is not None:
            options[name] = getattr(args, name)
    return options


#: Default wavelengths of profile exports, and those of a Mitsuba spectral export (nm).
PROFILE_WAVELENGTHS = "400:700:5"
MITSUBA_WAVELENGTHS = "360:830:10"


def _cmd_spectrum(args) -> int:
    wavelengths = parse_wavelengths(args.wavelengths)
    reflectance = np.asarray(diffuse_reflectance(_params(args), wavelengths, **_model_options(args)))
    lines = ["wavelength_nm,reflectance"] + [f"{w:g},{r:.8f}" for w, r in zip(wavelengths, reflectance)]
    print("\n".join(lines))
    return 0


def _cmd_profiles(args) -> int:
    if args.format != "table":

        wavelengths = args.wavelengths
        if args.format == "mitsuba-spectral" and wavelengths == PROFILE_WAVELENGTHS:
            wavelengths = MITSUBA_WAVELENGTHS  # Mitsuba's spectral variants sample 360-830 nm
        result = renderer_profiles(_params(args), parse_wavelengths(wavelengths), illuminant=args.illuminant,
                                   label=args.preset or "", **_model_options(args))
        fmt = "table" if args.format == "renderer-table" else args.format
        path = write_renderer(result, fmt, args.out)
        errors = ", ".join(f"{c} {100 * result.gaussians[c]['energy_error']:.2f} %" for c in result.gaussians)
        print(f"wrote {path} ({args.format}): radii to {result.max_radius_mm:.4g} mm ({100 * 0.997:.1f} % of the energy), "
              f"sum-of-Gaussians energy error {errors}")
        return 0

    table = profile_table(
        _params(args),
        parse_wavelengths(args.wavelengths),
        parse_radii(args.radii),
        illuminant=args.illuminant,
        label=args.preset or "",
        **_model_options(args),
    )
    path = write_table(table, args.out)
    print(f"wrote {path}: {table.spectral.shape[0]} wavelengths x {table.spectral.shape[1]} radii (mm^-2) + linear sRGB profiles")
    return 0


def _cmd_plan(args) -> int:
    wavelengths = None if args.wavelengths in (None, "none") else tuple(parse_wavelengths(args.wavelengths).tolist())
    request = Request(
        wavelengths_nm=wavelengths,
        rgb=args.rgb,
        illuminant=args.illuminant,
        colour_tolerance=args.colour_tolerance,
        profiles=args.profiles,
        pixel_footprint_mm=args.pixel_footprint_mm,
        max_radius_mm=args.max_radius_mm,
        derivatives=args.derivatives,
    )
    has_params = args.preset or any(getattr(args, n) is not None for n in ("melanin", "melanin_blend", "haemoglobin"))
    print(plan(request, _params(args) if has_params else None, model=_model(args)).describe())
    return 0


def _cmd_textures(args) -> int:
    channels, _ = read_exr_channels(args.maps)
    missing = [k for k in ("melanin", "haemoglobin") if k not in channels]
    if missing:
        raise SkinfitInputError(f"{args.maps}: no {', '.join(missing)} channel (expected the maps EXR of fit-image)")
    textures = renderer_textures(channels, illuminant=args.illuminant, model=_model(args))
    units = ("albedo: linear-sRGB diffuse albedo; sigma_t (mm^-1), ss_albedo, mfp = 1/sigma_t (mm): the medium whose exact "
             "transport (index 1.4, isotropic) renders that albedo; base_colour, blender_radius (mm): the Blender Cycles Principled "
             "BSDF inputs that render it")
    write_exr(args.out, textures, {"skinfit:units": units, "skinfit:source": str(args.maps)})
    print(f"wrote {args.out}: albedo, sigma_t, ss_albedo, mfp, base_colour and blender_radius .R/G/B")
    if args.mitsuba:

        print(f"wrote {write_mitsuba_textures(textures, args.mitsuba)} with sigma_t.vol and albedo.vol")
    return 0


def _cmd_demo(args) -> int:
    """The main job on the bundled photo: parameter maps, reconstruction, a blush edit, a figure."""
    from importlib.resources import as_file, files


    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = _model(args)
    print(f"skinfit demo: fitting {DEMO_PHOTO} (NASA portrait of Eileen Collins, public domain)")
    print(f"  skin model: {model.description}")
    print("  camera model: linear sRGB = white balance x shading x skin reflectance through CIE 1931 / D65;")
    print("  white balance and melanin blend once for the image, MAP melanin, haemoglobin and shading per pixel")
    print(f"  under the population prior, light edge-preserving regularisation, on the shipped skin mask {DEMO_MASK}")
    with as_file(files("skinfit.data") / DEMO_PHOTO) as photo, as_file(files("skinfit.data") / DEMO_MASK) as mask_path:
        linear, _ = read_linear_rgb(photo)
        mask = read_mask(mask_path) > 0
    fit = fit_image(linear, mask=mask, model=model, progress=not args.quiet)
    summary = fit.summary()
    write_fit(fit, out, "", DEMO_PHOTO, "D65")
    # the edit on the skin, the photo elsewhere
    blush = encoded_srgb(np.where(fit.skin_mask[..., None], fit.render(scale_haemoglobin=2.0), linear))
    write_png(out / "blush.png", blush)
    plot_image_fit(encoded_srgb(linear), fit, blush, out / "maps.png", "blush: haemoglobin x 2")
    skin = fit.status[mask] == 0
    delta_e = fit.residual_dE2000[mask]
    print(
        f"  {int(skin.sum())} of {int(mask.sum())} skin-mask pixels fitted ({100 * skin.mean():.1f} %; the rest: see the status map), "
        f"CIEDE2000 over the mask median {np.median(delta_e):.2g}, 95th percentile {np.percentile(delta_e, 95):.2g}; "
        f"melanin median {np.median(fit.melanin[mask][skin]):.3f}, haemoglobin median {np.median(fit.haemoglobin[mask][skin]):.4f}"
    )
    print(f"  melanin blend {summary['melanin_blend']:.3g}, white balance {' '.join(f'{g:.3f}' for g in fit.white_balance)}, {summary['seconds']:.1f} s")
    print(f"wrote {out}/: maps.exr ({', '.join(fit.maps())}), maps.png, reconstructed.png, dE2000.png, skin_mask.png, blush.png")
    return 0


def _cmd_presets(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    wavelengths = np.arange(400.0, 701.0, 5.0)
    radii = parse_radii(DEFAULT_RADII)
    start = time.perf_counter()
    spectra, srgb, spectral_profiles = {}, {}, {}
    model = _model(args)
    for name in PRESET_NAMES:
        table = profile_table(preset(name), wavelengths, radii, label=name, model=model)
        write_table(table, out / f"profiles_{name}.csv")
        spectra[name] = table.reflectance  # the table already holds the diffuse reflectance
        srgb[name] = np.asarray(spectrum_to_srgb(spectra[name], wavelengths))
        spectral_profiles[name] = table.spectral
    elapsed = time.perf_counter() - start
    rows = ["wavelength_nm," + ",".join(PRESET_NAMES)]
    rows += [f"{w:g}," + ",".join(f"{spectra[n][i]:.6f}" for n in PRESET_NAMES) for i, w in enumerate(wavelengths)]
    (out / "reflectance.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    plot_spectra(wavelengths, spectra, srgb, out / "presets.png")
    plot_profiles(radii, wavelengths, spectral_profiles, out / "profiles.png")

    print(f"skinfit presets: the skin presets through {model.description}")
    print("  (diffuse reflectance, normal incidence, specular excluded)")
    print(f"{'preset':<8} {'C_m':>6} {'beta_m':>6} {'C_h':>6}   R(450)   R(550)   R(650)   sRGB (D65)")
    for name in PRESET_NAMES:
        p = preset(name)
        r = {w: spectra[name][np.argmin(np.abs(wavelengths - w))] for w in (450, 550, 650)}
        hex_ = "#" + "".join(f"{int(round(255 * c)):02x}" for c in srgb[name])
        print(f"{name:<8} {float(p.melanin):6.3f} {float(p.melanin_blend):6.2f} {float(p.haemoglobin):6.3f}"
              f"   {r[450]:.4f}   {r[550]:.4f}   {r[650]:.4f}   {hex_}")
    print(f"computed {len(PRESET_NAMES)} presets x {wavelengths.size} wavelengths x {radii.size} radii in {elapsed:.2f} s (incl. compilation)")
    print(f"wrote {out}/: reflectance.csv, profiles_<preset>.csv, presets.png, profiles.png")
    return 0


def _read_spectra(args) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Names, wavelengths (nm) and spectra (n, m) from the INPUT file."""
    path = Path(args.input)
    if args.format == "nist":

        nist = read_nist(path)
        if args.nist_spectra == "average":
            return list(nist.subjects), nist.wavelengths_nm, nist.average
        names = [f"{s} R{i + 1}" for s in nist.subjects for i in range(nist.repeats.shape[1])]
        return names, nist.wavelengths_nm, nist.repeats.reshape(-1, nist.repeats.shape[-1])
    try:
        lines = [line for line in path.read_text(encoding="utf-8").splitlines() if line.strip() and not line.startswith("#")]
    except OSError as err:
        raise SkinfitInputError(f"cannot read {path}: {err.strerror}") from None
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    if not header or header[0] != "wavelength_nm" or len(header) < 2:
        raise SkinfitInputError(f"{path}: expected a header 'wavelength_nm,<name>,...' (or use --format nist)")
    try:
        data = np.array([[float(v) if v.strip() else np.nan for v in line.split(",")] for line in lines[1:]])
    except ValueError as err:
        raise SkinfitInputError(f"{path}: non-numeric value ({err})") from None
    if data.ndim != 2 or data.shape[1] != len(header):
        raise SkinfitInputError(f"{path}: every row needs {len(header)} values")
    return header[1:], data[:, 0], data[:, 1:].T


def _resample(wavelengths, spectra, grid):
    lo, hi = wavelengths.min(), wavelengths.max()
    if grid.min() < lo or grid.max() > hi:
        raise SkinfitInputError(f"--wavelengths {grid.min():g}-{grid.max():g} nm reaches outside the data ({lo:g}-{hi:g} nm)")
    order = np.argsort(wavelengths)
    return np.stack([np.interp(grid, wavelengths[order], s[order]) for s in spectra])


def _cmd_fit_spectra(args) -> int:
    names, wavelengths, spectra = _read_spectra(args)
    grid = parse_wavelengths(args.wavelengths)
    target = _resample(wavelengths, spectra, grid)
    fixed = {}
    for item in args.fixed or []:
        name, _, value = item.partition("=")
        try:
            fixed[name.strip()] = float(value)
        except ValueError:
            raise SkinfitInputError(f"--fixed {item!r}: expected NAME=VALUE") from None
    start = time.perf_counter()
    model = _model(args)
    fit = fit_spectra(
        grid, target, model=model, free=None if args.free is None else tuple(args.free.split(",")), fixed=fixed,
        port_radius_mm=args.port_radius_mm, specular_included_deg=args.specular_included_deg, bandwidth_nm=args.bandwidth_nm,
        colour_weight=args.colour_weight, prior=args.prior, adding=args.adding, method=args.method, progress=not args.quiet,
    )
    elapsed = time.perf_counter() - start
    columns = list(fit.parameters)
    header = ["name", *columns, *(f"se_{c}" for c in fit.free), "rms_residual", "delta_e2000", "iterations", "status", "model"]
    rows = [",".join(header)]
    for i, name in enumerate(names):
        values = [f"{fit.parameters[c][i]:.8g}" for c in columns] + [f"{fit.standard_errors[c][i]:.3g}" for c in fit.free]
        values += [f"{fit.rms_residual[i]:.6g}", f"{fit.delta_e2000[i]:.4g}", str(int(fit.iterations[i])), FitStatus(int(fit.status[i])).name,
                   fit.model]
        rows.append(",".join([name.replace(",", " ")] + values))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(rows) + "\n", encoding="utf-8")
    ok = fit.status == FitStatus.SUCCESS
    print(f"fitted {len(names)} spectra ({ok.sum()} success) at {grid.size} wavelengths in {elapsed:.1f} s with model {fit.model}; "
          f"free: {', '.join(fit.free)}")
    if ok.any():
        print(f"RMS residual: median {np.median(fit.rms_residual[ok]):.4f}, worst {fit.rms_residual[ok].max():.4f}; "
              f"CIEDE2000: median {np.median(fit.delta_e2000[ok]):.2f}, worst {fit.delta_e2000[ok].max():.2f}")
    print(f"wrote {out}")
    if args.plot:

        plot_fits(grid, target, fit.fitted, names, fit.rms_residual, args.plot)
        print(f"wrote {args.plot}")
    return 0


def _cmd_calibrate_model(args) -> int:
    grid = parse_wavelengths(args.wavelengths)
    if args.format == "issa":

        archive = read_issa(args.input)
        sites = FACE_SITES if args.sites == "face" else None if args.sites == "all" else tuple(args.sites.split(","))
        if sites is not None:
            archive = archive.select([r.get("body_site") in sites for r in archive.records])
        try:
            archive = archive.complete(grid)
        except IndexError:
            raise SkinfitInputError(f"--wavelengths: the archive has no column for some of {grid.tolist()}") from None
        target, groups = archive.reflectance, archive.subjects
    else:
        names, wavelengths, spectra = _read_spectra(args)
        target = _resample(wavelengths, spectra, grid)
        groups = np.array([name.rsplit("/", 1)[0] for name in names])  # "subject/site" names group by subject
    if len(target) < 2:
        raise SkinfitInputError("calibrating shared constants needs several spectra (found fewer than 2)")
    constants = DEFAULT_CONSTANTS if args.constants is None else tuple(args.constants.split(","))
    start = SkinModel.named(args.start)
    print(f"calibrating {', '.join(constants)} on {len(target)} spectra of {len(set(groups))} subjects, starting from {start.name}")
    calibration = calibrate_model(grid, target, model=start, constants=constants, groups=groups, folds=args.folds,
                                  specular_included_deg=args.specular_included_deg, bandwidth_nm=args.bandwidth_nm,
                                  port_radius_mm=args.port_radius_mm, max_steps=args.max_steps, name=args.name, progress=not args.quiet)
    for name, value in calibration.constants.items():
        print(f"  {name:34s} {value:11.6g}  +- {calibration.standard_errors[name]:.2g} (subject-robust)")
    record = calibration.record()
    fit = record["in_sample"]
    print(f"in sample: CIEDE2000 median {fit['delta_e2000_median']:.3f}, p95 {fit['delta_e2000_p95']:.3f}; RMS median {fit['rms_median']:.4f}; "
          f"{calibration.seconds:.0f} s")
    if "cross_validation" in record:
        cv = record["cross_validation"]["with_prior"]
        print(f"cross-validated ({args.folds} subject folds): CIEDE2000 median {cv['delta_e2000_median']:.3f}, p95 {cv['delta_e2000_p95']:.3f}; "
              f"RMS median {cv['rms_median']:.4f}")
    calibration.model.save(args.out, calibration={"input": str(args.input), "wavelengths_nm": grid.tolist(), **record})
    print(f"wrote {args.out} (use it with --model {args.out})")
    return 0


def _cmd_fit_image(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    white_balance = _white_balance(args.white_balance)
    options = dict(
        melanin_blend=args.melanin_blend, fit_blend=args.fit_blend, white_balance=white_balance, input_space=args.input_space,
        mask=args.mask, illuminant=args.illuminant, max_delta_e=args.max_delta_e, exact_steps=args.exact_steps, method=args.method,
        model=_model(args), progress=False if args.quiet else None, regularisation=args.regularisation, colour_chart=args.colour_chart,
    )
    if args.no_prior:
        options["prior"] = False
    if args.dask:

        return fit_images_on_cluster(args.dask, args.inputs, out, options, overwrite=args.overwrite)
    for path in args.inputs:
        maps_path = out / f"{Path(path).stem}_maps.exr"
        if maps_path.exists() and not args.overwrite:  # a rerun of an interrupted batch skips finished images
            print(f"{path}: {maps_path} exists, skipped (--overwrite to refit)")
            continue
        print(fit_image_to_folder(path, out, options))
    return 0


def _white_balance(text: str):
    """--white-balance: none, auto or R,G,B gains."""
    if text in ("none", "auto"):
        return text
    try:
        gains = tuple(float(v) for v in text.split(","))
    except ValueError:
        gains = ()
    if len(gains) != 3 or not all(g > 0 for g in gains):
        raise SkinfitInputError(f"--white-balance takes none, auto or three positive gains R,G,B; got {text!r}")
    return gains


def _cmd_render_maps(args) -> int:
    channels, attributes = read_exr_channels(args.maps)
    missing = [c for c in ("melanin", "haemoglobin", "shading", "melanin_blend") if c not in channels]
    if missing:
        raise SkinfitInputError(f"{args.maps} lacks channel(s) {', '.join(missing)}: not a skinfit maps file")
    fitted = channels.get("status", np.zeros_like(channels["melanin"])) <= 2
    linear = render_maps(
        channels["melanin"] * args.scale_melanin,
        channels["haemoglobin"] * args.scale_haemoglobin,
        channels["shading"],
        melanin_blend=channels["melanin_blend"],
        illuminant=args.illuminant,
        model=SkinModel.named(args.model or str(attributes.get("skinfit:model", "calibrated"))),
    )
    gains = [float(g) for g in str(attributes.get("skinfit:white_balance", "1 1 1")).split()]
    linear = linear * np.asarray(gains if len(gains) == 3 else [1.0, 1.0, 1.0])  # the camera's, as fitted
    linear[~fitted] = 0.0
    write_png(args.out, np.asarray(srgb_encode(np.clip(linear, 0, 1))))
    print(f"wrote {args.out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="skinfit", description="Spectral two-layer skin model (Donner & Jensen 2006) in JAX.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    spectrum = sub.add_parser("spectrum", help="print a diffuse reflectance spectrum as CSV")
    _add_model_arguments(spectrum)
    spectrum.set_defaults(run=_cmd_spectrum)

    profiles = sub.add_parser("profiles", help="write a spectral + RGB radial profile table")
    _add_model_arguments(profiles, wavelengths=PROFILE_WAVELENGTHS)
    profiles.add_argument("--radii", default=DEFAULT_RADII, help=f"mm, START:STOP:N, log-spaced if START > 0 (default {DEFAULT_RADII})")
    profiles.add_argument("--illuminant", default="D65", help="illuminant of the RGB profiles (default D65)")
    profiles.add_argument("--out", required=True, help="output file (table: .csv, .npz or .exr)")
    profiles.add_argument("--format", default="table",
                          choices=("table", "renderer-table", "gaussians", "burley", "pbrt", "mitsuba", "mitsuba-spectral", "blender", "json"),
                          help="table: --radii as given (default); renderer-table: radii to 99.7 %% of the energy, normalised; "
                               "gaussians / burley: fits per RGB channel (JSON); pbrt: pbrt-v4 subsurface material; "
                               "mitsuba / mitsuba-spectral: Mitsuba 3 dielectric + homogeneous medium (XML; spectral: per "
                               f"wavelength, {MITSUBA_WAVELENGTHS} nm unless --wavelengths); blender: Principled BSDF values "
                               "compensated for Cycles (JSON); json: all fits and the media. Media are matched with exact "
                               "transport (index 1.4, isotropic, mm)")
    profiles.set_defaults(run=_cmd_profiles)

    fit = sub.add_parser("fit-spectra", help="fit skin parameters to measured reflectance spectra")
    fit.add_argument("input", help="CSV with a wavelength_nm column and one column per spectrum, or the NIST file")
    fit.add_argument("--out", required=True, help="output CSV: one row per spectrum")
    fit.add_argument("--format", choices=("csv", "nist"), default="csv", help="input layout (default csv)")
    fit.add_argument("--nist-spectra", choices=("average", "repeats"), default="average", help="NIST: subject averages (default) or every repeat")
    fit.add_argument("--wavelengths", default="400:700:10", help="fit wavelengths in nm, START:STOP:STEP or A,B,C (default 400:700:10)")
    _add_model_choice(fit)
    fit.add_argument("--free", default=None, help="comma-separated fit variables (default melanin,melanin_blend,haemoglobin, and oil "
                     "with --specular-included-deg); also blood_oxygenation, epidermis_thickness_mm, scattering_scale, "
                     "carotene_umol_per_l, specular_offset, calibration_scale")
    fit.add_argument("--fixed", action="append", metavar="NAME=VALUE", help="value of a variable that is not free (repeatable)")
    fit.add_argument("--port-radius-mm", type=float, default=None, help="instrument port radius: light beyond it is lost (default: none)")
    fit.add_argument("--specular-included-deg", type=float, default=None,
                     help="the measurement includes the specular part at this incidence (e.g. 8 for d/8 SCI): oil is then free")
    fit.add_argument("--bandwidth-nm", type=float, default=None,
                     help="the instrument's band-pass (FWHM of a triangular slit, nm; e.g. 10 for a 10 nm spectrophotometer)")
    fit.add_argument("--colour-weight", type=float, default=0.02,
                     help="weight of the CIELAB difference per Delta E beside the spectral residual (default 0.02; 0: spectral only)")
    fit.add_argument("--prior", action=argparse.BooleanOptionalAction, default=None,
                     help="the model's population prior (MAP fits); default: on for a model that has one (the "
                          "calibrated default), off for dj2006; --no-prior gives maximum-likelihood fits")
    fit.add_argument("--adding", choices=ADDING_MODES, default=None, help="layer adding of a diffusion model (default directional)")
    fit.add_argument("--method", choices=METHODS, default=None,
                     help="override the model's forward method: diffusion, or transport (direct adding-doubling; ~100x slower on a GPU, "
                          "more on a CPU)")
    fit.add_argument("--plot", help="PNG of measured against fitted spectra (best and worst fits)")
    fit.add_argument("--quiet", action="store_true", help="no progress bar")
    fit.set_defaults(run=_cmd_fit_spectra)

    calibrate = sub.add_parser("calibrate-model", help="calibrate the skin model's shared constants on measured spectra")
    calibrate.add_argument("input", help="CSV (wavelength_nm column, one column per spectrum named SUBJECT or SUBJECT/SITE), NIST or ISSA file")
    calibrate.add_argument("--out", required=True, help="model JSON to write (SkinModel.from_file, --model PATH)")
    calibrate.add_argument("--format", choices=("csv", "nist", "issa"), default="csv", help="input layout (default csv)")
    calibrate.add_argument("--nist-spectra", choices=("average", "repeats"), default="average", help=argparse.SUPPRESS)
    calibrate.add_argument("--sites", default="face", help="ISSA body sites: face (default), all, or a comma-separated list")
    calibrate.add_argument("--wavelengths", default="400:700:10", help="nm, START:STOP:STEP or A,B,C (default 400:700:10)")
    calibrate.add_argument("--constants", default=None, help="comma-separated constants to calibrate (default: those of the shipped model)")
    calibrate.add_argument("--start", default="calibrated", help="the model to start from: calibrated (default), dj2006 or a JSON file")
    calibrate.add_argument("--specular-included-deg", type=float, default=None, help="as for fit-spectra (e.g. 8 for d/8 SCI)")
    calibrate.add_argument("--bandwidth-nm", type=float, default=None, help="as for fit-spectra (the instrument's band-pass)")
    calibrate.add_argument("--port-radius-mm", type=float, default=None, help="as for fit-spectra")
    calibrate.add_argument("--folds", type=int, default=0, help="subject folds for cross-validation (default 0: none)")
    calibrate.add_argument("--max-steps", type=int, default=40, help="outer Levenberg-Marquardt steps (default 40)")
    calibrate.add_argument("--name", default="calibrated", help="name of the calibrated model (written into its outputs)")
    calibrate.add_argument("--quiet", action="store_true", help="no progress bar")
    calibrate.set_defaults(run=_cmd_calibrate_model)

    image = sub.add_parser("fit-image", help="fit melanin, haemoglobin and shading maps to photos or albedo images")
    image.add_argument("inputs", nargs="+", metavar="INPUT", help="EXR, TIFF, PNG or JPEG files")
    image.add_argument("--out", required=True, help="output folder (maps EXR, reconstruction and CIEDE2000 PNGs per input)")
    image.add_argument("--melanin-blend", type=float, default=None,
                       help="beta_m for the whole image (default: the model's population mean, 0.42 calibrated, 0.7 DJ2006)")
    image.add_argument("--fit-blend", action="store_true", help="fit beta_m once for each image instead")
    image.add_argument("--white-balance", default="auto",
                       help="auto (default: camera gains fitted once per image from its skin pixels), none (inputs known to be "
                            "calibrated linear sRGB / sRGB, D65 white) or R,G,B gains")
    image.add_argument("--regularisation", choices=("off", "light", "strong"), default="light",
                       help="edge-preserving spatial prior on melanin and haemoglobin (default light)")
    image.add_argument("--colour-chart", action="store_true",
                       help="calibrate the colours from a ColorChecker in the frame (needs skinfit[chart]); white balance then none")
    image.add_argument("--no-prior", action="store_true", help="maximum likelihood per pixel: no population or spatial prior")
    image.add_argument("--max-delta-e", type=float, default=1.0, help="CIEDE2000 above which a pixel is out of model (default 1)")
    image.add_argument("--exact-steps", type=int, default=0, help="Gauss-Newton steps on the exact model after the spline fit")
    _add_model_choice(image)
    image.add_argument("--method", choices=METHODS, default=None,
                       help="override the model's forward method: diffusion, or transport (direct adding-doubling; its colour table "
                            "takes ~1-2 min on a laptop CPU)")
    image.add_argument("--dask", metavar="ADDRESS", default=None, help="run the images as tasks on this Dask scheduler")
    image.add_argument("--quiet", action="store_true", help="no progress bar")
    image.add_argument("--input-space", default=None, help="srgb, linear or a colour-science RGB colourspace name")
    image.add_argument("--mask", default=None,
                       help="skin mask image (any channel count and bit depth: alpha, the only channel, or the largest): pixels where "
                            "it is 0 are not fitted; without one, skin_mask.png is derived from the fit")
    image.add_argument("--illuminant", default="D65", help="illuminant of the camera model (default D65)")
    image.add_argument("--overwrite", action="store_true", help="refit images whose maps already exist")
    image.set_defaults(run=_cmd_fit_image)

    render = sub.add_parser("render-maps", help="render (edited) parameter maps to an sRGB image")
    render.add_argument("maps", metavar="MAPS.exr")
    render.add_argument("--out", required=True, help="PNG to write")
    render.add_argument("--scale-haemoglobin", type=float, default=1.0, help="e.g. 1.5 for a blush")
    render.add_argument("--scale-melanin", type=float, default=1.0)
    render.add_argument("--illuminant", default="D65")
    render.add_argument("--model", default=None, metavar="NAME", help="skin model (default: the one the maps were fitted with)")
    render.set_defaults(run=_cmd_render_maps)

    textures = sub.add_parser("textures", help="albedo and subsurface-radius textures (EXR) from fitted maps")
    textures.add_argument("maps", metavar="MAPS.exr")
    textures.add_argument("--out", required=True, help="EXR to write")
    textures.add_argument("--mitsuba", metavar="DIR", default=None,
                          help="also write Mitsuba 3 volume grids (sigma_t.vol, albedo.vol) and skin_medium.xml to DIR")
    textures.add_argument("--illuminant", default="D65")
    _add_model_choice(textures)
    textures.set_defaults(run=_cmd_textures)

    planned = sub.add_parser("plan", help="print what a request computes and what it skips")
    planned.add_argument("--wavelengths", default=None, help="spectral output in nm, START:STOP:STEP or A,B,C (default: none)")
    planned.add_argument("--rgb", action="store_true", help="linear sRGB output")
    planned.add_argument("--illuminant", default="D65", help="illuminant of the RGB output (default D65)")
    planned.add_argument("--colour-tolerance", type=float, default=0.1, help="CIEDE2000 allowed for RGB (default 0.1)")
    planned.add_argument("--profiles", action="store_true", help="radial profiles")
    planned.add_argument("--pixel-footprint-mm", type=float, default=None, help="size of a pixel on the skin (mm)")
    planned.add_argument("--max-radius-mm", type=float, default=20.0, help="largest radius that matters (mm, default 20)")
    planned.add_argument("--derivatives", action="store_true", help="derivatives with respect to the parameters")
    group = planned.add_argument_group("skin parameters (optional: with them the planner checks profile widths)")
    group.add_argument("--preset", choices=PRESET_NAMES)
    group.add_argument("--melanin", type=float)
    group.add_argument("--melanin-blend", type=float)
    group.add_argument("--haemoglobin", type=float)
    _add_model_choice(planned)
    planned.set_defaults(run=_cmd_plan)

    demo = sub.add_parser("demo", help="the main job on the bundled face photo: parameter maps, reconstruction, a blush edit")
    demo.add_argument("--out", default="skinfit-demo", help="output folder (default ./skinfit-demo)")
    demo.add_argument("--quiet", action="store_true", help="no progress bar")
    _add_model_choice(demo)
    demo.set_defaults(run=_cmd_demo)

    presets = sub.add_parser("presets", help="reflectance spectra and profile tables of the skin presets")
    presets.add_argument("--out", default="skinfit-presets", help="output folder (default ./skinfit-presets)")
    _add_model_choice(presets)
    presets.set_defaults(run=_cmd_presets)
    return parser


def _enable_compilation_cache() -> None:
    """Keep compiled programs between runs (a fit compiles for about 15 s on a 2-core CPU).

    The folder is ``$SKINFIT_CACHE_DIR``, else ``$XDG_CACHE_HOME/skinfit/jax`` (``~/.cache``);
    a folder the user configured for JAX already wins. Only the command line does this: a library
    should not change global JAX settings.
    """
    if jax.config.jax_compilation_cache_dir:
        return
    folder = os.environ.get("SKINFIT_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "skinfit", "jax"
    )
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError:
        return  # read-only home: run uncached
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    _enable_compilation_cache()
    try:
        return args.run(args)
    except SkinfitInputError as err:
        print(f"skinfit {args.command}: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"skinfit {args.command}: error: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
