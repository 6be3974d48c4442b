"""The commands of ``skinfit``: each ``cmd_<name>(args)`` runs one subcommand and returns its exit status."""

from __future__ import annotations

import time
from importlib.resources import as_file, files
from pathlib import Path

import numpy as np

from .._validate import SkinfitInputError
from ..colorimetry import render_maps, spectrum_to_srgb, srgb_encode
from ..export import (
    layered_medium,
    layered_textures,
    mitsuba_layered_xml,
    profile_table,
    renderer_profiles,
    renderer_textures,
    write_mitsuba_layered_textures,
    write_mitsuba_textures,
    write_renderer,
    write_table,
)
from ..fit import DEFAULT_CONSTANTS, FitStatus, calibrate_model, fit_image, fit_spectra
from ..io import (
    FACE_SITES,
    read_exr_channels,
    read_issa,
    read_linear_rgb,
    read_mask,
    resample_spectra,
    write_exr,
    write_png,
)
from ..model import PRESET_NAMES, SkinModel, diffuse_reflectance, model_with_options, preset
from ..planning import Request, plan
from ._arguments import (
    DEFAULT_RADII,
    model_from,
    model_options_from,
    params_from,
    parse_radii,
    parse_wavelengths,
    parse_white_balance,
    read_input_spectra,
)
from ._batch import blend_text, encoded_srgb, fit_image_to_folder, white_balance_text, write_fit
from ._dask import fit_images_on_cluster
from ._plots import plot_fits, plot_image_fit, plot_profiles, plot_spectra

#: The bundled photo (package skinfit.data, folder data/ of the repository).
DEMO_PHOTO = "astronaut_eileen_collins.png"

#: Default wavelengths of profile exports, and those of a Mitsuba spectral export (nm).
PROFILE_WAVELENGTHS = "400:700:5"
MITSUBA_WAVELENGTHS = "360:830:10"


def cmd_spectrum(args) -> int:
    wavelengths = parse_wavelengths(args.wavelengths)
    reflectance = np.asarray(diffuse_reflectance(params_from(args), wavelengths, **model_options_from(args)))
    lines = ["wavelength_nm,reflectance"] + [f"{w:g},{r:.8f}" for w, r in zip(wavelengths, reflectance)]
    print("\n".join(lines))
    return 0


def cmd_profiles(args) -> int:
    if args.format in ("mitsuba-layered", "mitsuba-layered-spectral"):
        return _write_layered(args)
    if args.format != "table":
        wavelengths = args.wavelengths
        if args.format == "mitsuba-spectral" and wavelengths == PROFILE_WAVELENGTHS:
            wavelengths = MITSUBA_WAVELENGTHS  # Mitsuba's spectral variants sample 360-830 nm
        result = renderer_profiles(params_from(args), parse_wavelengths(wavelengths), illuminant=args.illuminant,
                                   label=args.preset or "", **model_options_from(args))
        fmt = "table" if args.format == "renderer-table" else args.format
        path = write_renderer(result, fmt, args.out)
        errors = ", ".join(f"{c} {100 * result.gaussians[c]['energy_error']:.2f} %" for c in result.gaussians)
        print(f"wrote {path} ({args.format}): radii to {result.max_radius_mm:.4g} mm ({100 * 0.997:.1f} % of the energy), "
              f"sum-of-Gaussians energy error {errors}")
        return 0

    table = profile_table(
        params_from(args),
        parse_wavelengths(args.wavelengths),
        parse_radii(args.radii),
        illuminant=args.illuminant,
        label=args.preset or "",
        **model_options_from(args),
    )
    path = write_table(table, args.out)
    print(f"wrote {path}: {table.spectral.shape[0]} wavelengths x {table.spectral.shape[1]} radii (mm^-2) + linear sRGB profiles")
    return 0


def _write_layered(args) -> int:
    """The model's two layers as Mitsuba 3 media (``skinfit.export.layered_medium``)."""
    spectral = args.format == "mitsuba-layered-spectral"
    wavelengths = MITSUBA_WAVELENGTHS if args.wavelengths == PROFILE_WAVELENGTHS else args.wavelengths
    options = model_options_from(args)
    model = model_with_options(options.pop("model", None), **options)
    layered = layered_medium(params_from(args), parse_wavelengths(wavelengths), spectral=spectral, illuminant=args.illuminant,
                             model=model, label=args.preset or "")
    p = layered.metadata["parameters"]
    head = (f"{layered.metadata['generator']}, model {layered.metadata['model']}: C_m {p['melanin']:g}, "
            f"beta_m {p['melanin_blend']:g}, C_h {p['haemoglobin']:g}, oil {p['oil']:g}")
    path = Path(args.out)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(mitsuba_layered_xml(layered, comment=head), encoding="utf-8")
    per = f"{len(layered.channels)} wavelengths" if spectral else "RGB channels"
    print(f"wrote {path} (Mitsuba 3 epidermis {layered.epidermis_thickness_mm:g} mm over dermis, {per}, "
          f"Henyey-Greenstein g {layered.anisotropy:g})")
    return 0


def cmd_plan(args) -> int:
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
    print(plan(request, params_from(args) if has_params else None, model=model_from(args)).describe())
    return 0


def cmd_textures(args) -> int:
    channels, _ = read_exr_channels(args.maps)
    missing = [k for k in ("melanin", "haemoglobin") if k not in channels]
    if missing:
        raise SkinfitInputError(f"{args.maps}: no {', '.join(missing)} channel (expected the maps EXR of fit-image)")
    textures = renderer_textures(channels, illuminant=args.illuminant, model=model_from(args))
    units = ("albedo: linear-sRGB diffuse albedo; sigma_t (mm^-1), ss_albedo, mfp = 1/sigma_t (mm): the medium whose exact "
             "transport (index 1.4, isotropic) renders that albedo; base_colour, blender_radius (mm): the Blender Cycles Principled "
             "BSDF inputs that render it")
    write_exr(args.out, textures, {"skinfit:units": units, "skinfit:source": str(args.maps)})
    print(f"wrote {args.out}: albedo, sigma_t, ss_albedo, mfp, base_colour and blender_radius .R/G/B")
    if args.mitsuba:
        print(f"wrote {write_mitsuba_textures(textures, args.mitsuba)} with sigma_t.vol and albedo.vol")
    if args.mitsuba_layered:
        if args.mm_per_pixel is None:
            raise SkinfitInputError("--mitsuba-layered lays the maps over a patch: give its pixel size with --mm-per-pixel")
        layered = layered_textures(channels, illuminant=args.illuminant, model=model_from(args), progress=True)
        path = write_mitsuba_layered_textures(layered, args.mitsuba_layered, mm_per_pixel=args.mm_per_pixel)
        print(f"wrote {path} with the epidermis' and dermis' sigma_t and albedo grids")
    return 0


def cmd_demo(args) -> int:
    """The main job on the bundled photo: faces found, parameter maps, reconstruction, a blush
    edit, a figure."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = model_from(args)
    print(f"skinfit demo: fitting {DEMO_PHOTO} (NASA portrait of Eileen Collins, 512 x 512, public domain)")
    print(f"  skin model: {model.description}")
    print("  camera model: linear sRGB = white balance x shading x skin reflectance through CIE 1931 / D65;")
    print("  the skin of the faces found by the shipped face models (detector, face mesh, the face's skin colour);")
    print("  white balance once for the image from that skin, MAP melanin, haemoglobin and shading per pixel")
    print("  under the population prior, light edge-preserving regularisation")
    with as_file(files("skinfit.data") / DEMO_PHOTO) as photo:
        fit = fit_image(photo, model=model, progress=not args.quiet)
        linear, _ = read_linear_rgb(photo)
    summary = fit.summary()
    write_fit(fit, out, "", DEMO_PHOTO, "D65", linear)
    # the edit on the skin, the photo elsewhere
    blush = encoded_srgb(np.where(fit.skin_mask[..., None], fit.render(scale_haemoglobin=2.0), linear))
    write_png(out / "blush.png", blush)
    plot_image_fit(encoded_srgb(linear), fit, blush, out / "maps.png", "blush: haemoglobin x 2")
    region = fit.region if fit.region is not None else np.zeros(fit.status.shape, np.uint8)
    face_skin = region == 1
    skin = fit.status[face_skin] == 0
    delta_e = fit.residual_dE2000[face_skin]
    print(f"  {fit.faces or 0} face{'s' if fit.faces != 1 else ''} found ({fit.skin_from} chose the pixels fitted): "
          f"{int(face_skin.sum())} skin pixels, {int(skin.sum())} fitted ({100 * skin.mean():.1f} %; the rest: see the status map)")
    print(f"  CIEDE2000 over the skin median {np.median(delta_e):.2g}, 95th percentile {np.percentile(delta_e, 95):.2g}; "
          f"melanin median {np.median(fit.melanin[face_skin][skin]):.3f}, haemoglobin median {np.median(fit.haemoglobin[face_skin][skin]):.4f}")
    print(f"  melanin blend {blend_text(fit)}, white balance {white_balance_text(fit)}, {summary['seconds']:.1f} s")
    print(f"wrote {out}/: maps.exr ({', '.join(fit.maps())}), maps.png, regions.png, reconstructed.png, dE2000.png, skin_mask.png, blush.png")
    return 0


def cmd_presets(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    wavelengths = np.arange(400.0, 701.0, 5.0)
    radii = parse_radii(DEFAULT_RADII)
    start = time.perf_counter()
    spectra, srgb, spectral_profiles = {}, {}, {}
    model = model_from(args)
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


def cmd_fit_spectra(args) -> int:
    names, wavelengths, spectra = read_input_spectra(args)
    grid = parse_wavelengths(args.wavelengths)
    target = resample_spectra(wavelengths, spectra, grid)
    fixed = {}
    for item in args.fixed or []:
        name, _, value = item.partition("=")
        try:
            fixed[name.strip()] = float(value)
        except ValueError:
            raise SkinfitInputError(f"--fixed {item!r}: expected NAME=VALUE") from None
    start = time.perf_counter()
    model = model_from(args)
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


def cmd_calibrate_model(args) -> int:
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
        names, wavelengths, spectra = read_input_spectra(args)
        target = resample_spectra(wavelengths, spectra, grid)
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


def cmd_fit_image(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    white_balance = parse_white_balance(args.white_balance)
    options = dict(
        melanin_blend=args.melanin_blend, fit_blend=args.fit_blend, white_balance=white_balance, input_space=args.input_space,
        mask=args.mask, segmentation=args.segmentation, input_type=args.input_type, illuminant=args.illuminant, max_delta_e=args.max_delta_e, exact_steps=args.exact_steps, method=args.method,
        model=model_from(args), progress=False if args.quiet else None, regularisation=args.regularisation, colour_chart=args.colour_chart,
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


def cmd_render_maps(args) -> int:
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
