"""The ``skinfit`` argument parser: one subcommand per job, each bound to its command."""

from __future__ import annotations

import argparse

from ..model import ADDING_MODES, METHODS, PRESET_NAMES
from ._arguments import DEFAULT_RADII, Parser, add_model_arguments, add_model_choice
from ._commands import (
    MITSUBA_WAVELENGTHS,
    PROFILE_WAVELENGTHS,
    cmd_calibrate_model,
    cmd_demo,
    cmd_fit_image,
    cmd_fit_spectra,
    cmd_plan,
    cmd_presets,
    cmd_profiles,
    cmd_render_maps,
    cmd_spectrum,
    cmd_textures,
)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="skinfit", description="Spectral two-layer skin model (Donner & Jensen 2006) in JAX.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)

    spectrum = sub.add_parser("spectrum", help="print a diffuse reflectance spectrum as CSV")
    add_model_arguments(spectrum)
    spectrum.set_defaults(run=cmd_spectrum)

    profiles = sub.add_parser("profiles", help="write a spectral + RGB radial profile table")
    add_model_arguments(profiles, wavelengths=PROFILE_WAVELENGTHS)
    profiles.add_argument("--radii", default=DEFAULT_RADII, help=f"mm, START:STOP:N, log-spaced if START > 0 (default {DEFAULT_RADII})")
    profiles.add_argument("--illuminant", default="D65", help="illuminant of the RGB profiles (default D65)")
    profiles.add_argument("--out", required=True, help="output file (table: .csv, .npz or .exr)")
    profiles.add_argument("--format", default="table",
                          choices=("table", "renderer-table", "gaussians", "burley", "pbrt", "mitsuba", "mitsuba-spectral", "mitsuba-layered",
                                   "mitsuba-layered-spectral", "blender", "json"),
                          help="table: --radii as given (default); renderer-table: radii to 99.7 %% of the energy, normalised; "
                               "gaussians / burley: fits per RGB channel (JSON); pbrt: pbrt-v4 subsurface material; "
                               "mitsuba / mitsuba-spectral: Mitsuba 3 dielectric + homogeneous medium (XML; spectral: per "
                               f"wavelength, {MITSUBA_WAVELENGTHS} nm unless --wavelengths); mitsuba-layered / mitsuba-layered-spectral: the model's "
                               "epidermis slab over dermis as nested Mitsuba 3 media (Henyey-Greenstein g 0.8; the profile's shape, "
                               "not only its colour); blender: Principled BSDF values "
                               "compensated for Cycles (JSON); json: all fits and the media. Media are matched with exact "
                               "transport (index 1.4, isotropic, mm)")
    profiles.set_defaults(run=cmd_profiles)

    fit = sub.add_parser("fit-spectra", help="fit skin parameters to measured reflectance spectra")
    fit.add_argument("input", help="CSV with a wavelength_nm column and one column per spectrum, or the NIST file")
    fit.add_argument("--out", required=True, help="output CSV: one row per spectrum")
    fit.add_argument("--format", choices=("csv", "nist"), default="csv", help="input layout (default csv)")
    fit.add_argument("--nist-spectra", choices=("average", "repeats"), default="average", help="NIST: subject averages (default) or every repeat")
    fit.add_argument("--wavelengths", default="400:700:10", help="fit wavelengths in nm, START:STOP:STEP or A,B,C (default 400:700:10)")
    add_model_choice(fit)
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
                     help="override the model's forward method: diffusion, transport (tabulated adding-doubling, about the cost of "
                          "diffusion) or transport-direct (the direct solve, the reference: ~100x slower on a GPU, thousands of times on a CPU)")
    fit.add_argument("--plot", help="PNG of measured against fitted spectra (best and worst fits)")
    fit.add_argument("--quiet", action="store_true", help="no progress bar")
    fit.set_defaults(run=cmd_fit_spectra)

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
    calibrate.set_defaults(run=cmd_calibrate_model)

    image = sub.add_parser("fit-image", help="fit melanin, haemoglobin and shading maps to photos or albedo images")
    image.add_argument("inputs", nargs="+", metavar="INPUT", help="EXR, TIFF, PNG or JPEG files")
    image.add_argument("--out", required=True, help="output folder (maps EXR, reconstruction and CIEDE2000 PNGs per input)")
    image.add_argument("--melanin-blend", type=float, default=None,
                       help="beta_m for the whole image (default: estimated per face from its skin, with its uncertainty, "
                            "for a model with a population prior; 0.7 for DJ2006)")
    image.add_argument("--fit-blend", action="store_true", help="fit beta_m once for each image with the white balance instead")
    image.add_argument("--white-balance", default="auto",
                       help="auto (default: camera gains fitted once per image from its skin pixels, within a camera prior "
                            "of 15 %% per channel), none (inputs known to be calibrated linear sRGB / sRGB, D65 white), chart "
                            "(from a ColorChecker in the frame, as --colour-chart) or R,G,B gains")
    image.add_argument("--input", dest="input_type", choices=("photo", "albedo"), default="photo",
                       help="photo (default: shading free per pixel) or albedo (a calibrated albedo capture: one shading scale for "
                            "the image, fitted once; makes melanin identifiable in dark skin)")
    image.add_argument("--segmentation", choices=("faces", "none"), default="faces",
                       help="faces (default: fit the skin of the faces found by the shipped face models; where none is found, "
                            "every pixel) or none (every pixel; the skin model's gamut decides what is skin); --mask wins")
    image.add_argument("--regularisation", choices=("off", "light", "strong"), default="light",
                       help="edge-preserving spatial prior on melanin and haemoglobin (default light)")
    image.add_argument("--colour-chart", action="store_true",
                       help="calibrate the colours from a ColorChecker in the frame (needs skinfit[chart]); white balance then none")
    image.add_argument("--no-prior", action="store_true", help="maximum likelihood per pixel: no population or spatial prior")
    image.add_argument("--max-delta-e", type=float, default=1.0, help="CIEDE2000 above which a pixel is out of model (default 1)")
    image.add_argument("--exact-steps", type=int, default=0, help="Gauss-Newton steps on the exact model after the spline fit")
    add_model_choice(image)
    image.add_argument("--method", choices=METHODS, default=None,
                       help="override the model's forward method: diffusion, transport (tabulated adding-doubling) or transport-direct "
                            "(the direct solve: its colour table takes minutes on a laptop CPU)")
    image.add_argument("--dask", metavar="ADDRESS", default=None, help="run the images as tasks on this Dask scheduler")
    image.add_argument("--quiet", action="store_true", help="no progress bar")
    image.add_argument("--input-space", default=None,
                       help="srgb, linear or a colour-science RGB colourspace name (default: the file's ICC profile, else its type)")
    image.add_argument("--mask", default=None,
                       help="skin mask image (any channel count and bit depth: alpha, the only channel, or the largest): pixels where "
                            "it is 0 are not fitted; it wins over --segmentation")
    image.add_argument("--illuminant", default="D65", help="illuminant of the camera model (default D65)")
    image.add_argument("--overwrite", action="store_true", help="refit images whose maps already exist")
    image.set_defaults(run=cmd_fit_image)

    render = sub.add_parser("render-maps", help="render (edited) parameter maps to an sRGB image")
    render.add_argument("maps", metavar="MAPS.exr")
    render.add_argument("--out", required=True, help="PNG to write")
    render.add_argument("--scale-haemoglobin", type=float, default=1.0, help="e.g. 1.5 for a blush")
    render.add_argument("--scale-melanin", type=float, default=1.0)
    render.add_argument("--illuminant", default="D65")
    render.add_argument("--model", default=None, metavar="NAME", help="skin model (default: the one the maps were fitted with)")
    render.set_defaults(run=cmd_render_maps)

    textures = sub.add_parser("textures", help="albedo and subsurface-radius textures (EXR) from fitted maps")
    textures.add_argument("maps", metavar="MAPS.exr")
    textures.add_argument("--out", required=True, help="EXR to write")
    textures.add_argument("--mitsuba", metavar="DIR", default=None,
                          help="also write Mitsuba 3 volume grids (sigma_t.vol, albedo.vol) and skin_medium.xml to DIR")
    textures.add_argument("--mitsuba-layered", metavar="DIR", default=None,
                          help="also write the model's two layers per texel as Mitsuba 3 grids and skin_layers.xml to DIR "
                               "(needs --mm-per-pixel)")
    textures.add_argument("--mm-per-pixel", type=float, default=None, help="the maps' pixel size on the skin, mm (for --mitsuba-layered)")
    textures.add_argument("--illuminant", default="D65")
    add_model_choice(textures)
    textures.set_defaults(run=cmd_textures)

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
    add_model_choice(planned)
    planned.set_defaults(run=cmd_plan)

    demo = sub.add_parser("demo", help="the main job on the bundled face photo: parameter maps, reconstruction, a blush edit")
    demo.add_argument("--out", default="skinfit-demo", help="output folder (default ./skinfit-demo)")
    demo.add_argument("--quiet", action="store_true", help="no progress bar")
    add_model_choice(demo)
    demo.set_defaults(run=cmd_demo)

    presets = sub.add_parser("presets", help="reflectance spectra and profile tables of the skin presets")
    presets.add_argument("--out", default="skinfit-presets", help="output folder (default ./skinfit-presets)")
    add_model_choice(presets)
    presets.set_defaults(run=cmd_presets)
    return parser
