"""Whole images to melanin, haemoglobin and shading maps, on the per-pixel solver of ``pixel_fit``.

``fit_image`` adds what one pixel cannot know: the white balance from the skin
(``skinfit.fit``), the fold's branch chosen against the smooth shading field of the
neighbourhood, an edge-preserving spatial prior, and the statuses of pixels that are not skin.
Pixels that cannot be fitted get a status code and zeros, never NaN. Images go through in bands
of rows, so memory stays bounded.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
import warnings

import jax.numpy as jnp
import numpy as np

from .. import _scratch as scratch
from .._batching import bucket_size, padded_rows
from .._validate import SkinfitInputError
from ..colorimetry import (
    DEFAULT_ILLUMINANT,
    DARK_HAEMOGLOBIN_MAX,
    DARK_MELANIN_MAX,
    HAEMOGLOBIN_MAX,
    MELANIN_MAX,
    ChartCalibration,
    chart_calibration,
    colour_table,
    render_maps,
    srgb_encode,
)
from ..io import read_image, read_mask
from ..model import SkinModel, model_with_options, resolve_model
from ..segmentation import FaceSegmentation, SegmentationUnavailable, segment_faces
from ._face_blend import MODEL_DISCREPANCY, BlendEstimate, estimate_blends
from ._image_calibration import calibrate
from ._pixels import PixelStatus, fit_pixels, screen_pixels
from ._spatial import neighbourhood_median, smooth_field
from ._variables import VARIABLES

#: ``PixelStatus``, ``fit_pixels`` (``pixel_fit``) and ``render_maps`` (``map_rendering``) are
#: re-exported: this module is where users have found them.
__all__ = ["ImageFit", "PixelStatus", "fit_image", "fit_pixels", "render_maps"]


@dataclasses.dataclass(frozen=True)
class ImageFit:
    """Parameter maps of one image (each (h, w)), its reconstruction and a summary.

    ``status`` holds ``PixelStatus`` codes; pixels that were not fitted hold 0 in every map. Maps
    are float32 (relative precision 6e-8, as the EXR stores them).
    ``white_balance`` are the camera gains (r, g, b) the fit divided out (1 unless fitted), and
    ``colour_chart`` the chart correction applied first (or None): ``fitted_linear_rgb`` is in the
    camera's values, as the input.
    """

    melanin: np.ndarray
    melanin_blend: np.ndarray
    haemoglobin: np.ndarray
    shading: np.ndarray
    residual_dE2000: np.ndarray
    status: np.ndarray
    fitted_linear_rgb: np.ndarray  # (h, w, 3)
    seconds: float
    melanin_se: np.ndarray | None = None
    haemoglobin_se: np.ndarray | None = None
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    model: SkinModel | None = None
    colour_chart: object | None = None  # the ChartCalibration the image was corrected with
    input_encoding: str = "linear sRGB array"  # how the input was decoded (``skinfit.io.read_image``)
    white_balance_sd: tuple[float, float, float] | None = None  # relative standard errors of the fitted gains
    region: np.ndarray | None = None  # (h, w) ``FaceRegion`` codes where faces were segmented
    faces: int | None = None  # faces found (None: not looked for)
    skin_from: str = "model gamut"  # what chose the pixels fitted: "faces", "mask" or "model gamut"
    input_type: str = "photo"  # "photo" (shading free per pixel) or "albedo" (one shading scale)
    shading_scale: float | None = None  # the albedo capture's shading scale (input_type "albedo")
    melanin_blend_sd: np.ndarray | None = None  # (h, w) posterior sd of the face's blend (None: the blend was given)
    blends: tuple[dict, ...] = ()  # per face (or region) estimated: ``BlendEstimate.as_dict()``
    stage_seconds: dict[str, float] = dataclasses.field(default_factory=dict)  # wall time of each stage of the fit

    @property
    def model_name(self) -> str:
        return resolve_model(self.model).name

    @property
    def skin_mask(self) -> np.ndarray:
        """The automatic skin mask (h, w) bool: pixels fitted as skin (``SUCCESS``): not masked,
        in the model's gamut, with parameters skin has, no glint."""
        return self.status == PixelStatus.SUCCESS

    MAP_NAMES = ("melanin", "melanin_blend", "haemoglobin", "shading", "residual_dE2000", "status", "melanin_se", "haemoglobin_se",
                 "region", "melanin_blend_sd")

    def maps(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in self.MAP_NAMES if getattr(self, name) is not None}

    def render(self, scale_melanin: float = 1.0, scale_haemoglobin: float = 1.0, illuminant: str = DEFAULT_ILLUMINANT) -> np.ndarray:
        """Linear sRGB (h, w, 3) of the maps with scaled melanin and haemoglobin (an edit), through
        the exact model and the fitted white balance. Pixels with maps (status up to
        ``OUT_OF_MODEL``) are rendered; the others keep their fitted colour (0)."""
        edited = render_maps(
            scale_melanin * self.melanin, scale_haemoglobin * self.haemoglobin, self.shading,
            melanin_blend=self.melanin_blend, illuminant=illuminant, model=self.model,
        ) * np.asarray(self.white_balance)
        if self.colour_chart is not None:
            edited = self.colour_chart.invert(edited)
        return np.where((self.status <= PixelStatus.OUT_OF_MODEL)[..., None], edited, self.fitted_linear_rgb)

    def summary(self) -> dict[str, float]:
        """Pixels, fitted fraction, median and 95th-percentile CIEDE2000 of the fitted pixels,
        the blend and white balance, time."""
        fitted = self.skin_mask
        delta_e = _gathered(self.residual_dE2000, fitted)  # a band at a time: out-of-core maps stay out
        return {
            "pixels": int(self.status.size),
            "fitted": int(fitted.sum()),
            "fitted_fraction": float(fitted.mean()),
            "median_dE2000": float(np.median(delta_e)) if delta_e.size else float("nan"),
            "p95_dE2000": float(np.percentile(delta_e, 95)) if delta_e.size else float("nan"),
            # the blend of the fitted pixels (the map holds 0 where nothing was fitted)
            "melanin_blend": round(float(np.median(_gathered(self.melanin_blend, fitted))), 6) if fitted.any() else float("nan"),
            "blends": [dict(b) for b in self.blends],
            "white_balance": list(self.white_balance),
            "white_balance_sd": None if self.white_balance_sd is None else list(self.white_balance_sd),
            **({"colour_chart_matrix": self.colour_chart.matrix.tolist(),
                "colour_chart_median_dE2000": float(np.median(self.colour_chart.delta_e2000))} if self.colour_chart is not None else {}),
            "input_encoding": self.input_encoding,
            "skin_from": self.skin_from,
            "input_type": self.input_type,
            "shading_scale": self.shading_scale,
            "faces": self.faces,
            "model": self.model_name,
            "seconds": self.seconds,
            "stage_seconds": dict(self.stage_seconds),
        }


class _Stages:
    """Wall time of the named stages of one fit, summed over repeats (a stage per blend group)."""

    def __init__(self):
        self.seconds: dict[str, float] = {}

    @contextlib.contextmanager
    def __call__(self, name: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            scratch.release_pages(trim_heap=True)  # what the stage touched of out-of-core arrays, and its freed heap
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start


#: Spatial regularisation of ln C_m and ln C_h (``fit_image(regularisation=...)``): the standard
#: deviation of a pixel's value about the median of its neighbourhood, and that neighbourhood's size.
REGULARISATION = {"off": None, "light": (0.3, 3), "strong": (0.05, 5)}


def fit_image(
    image,
    *,
    melanin_blend: float | None = None,
    fit_blend: bool = False,
    blend_regions=None,
    white_balance: str | bool | tuple[float, float, float] = "auto",
    input_space: str | None = None,
    mask=None,
    segmentation: str = "faces",
    input_type: str = "photo",
    use_alpha: bool = True,
    illuminant: str = DEFAULT_ILLUMINANT,
    regularisation: str = "light",
    colour_chart=False,
    method: str | None = None,
    model: SkinModel | None = None,
    progress: bool | None = None,
    out_of_core: bool | None = None,
    **options,
) -> ImageFit:
    """Fit melanin, haemoglobin and shading maps to a photo or albedo image.

    Args:
        image: a path (read through OpenImageIO, see ``skinfit.io``) or a linear sRGB array
            (h, w, 3).
        melanin_blend: beta_m for the whole image (three channels cannot carry it per pixel);
            default None: estimated per face, pooled over its skin, with its uncertainty
            (``skinfit.fit.estimate_blends``: measured in an albedo capture, mostly the population
            prior's in a photo, whose width then widens the maps' standard errors); the faces are
            the segmentation's, else ``blend_regions``, else the whole mask or image. A model
            without a population prior on the blend (DJ2006), or ``prior=False``, takes the
            prior's mean (DJ2006: 0.7) instead.
        fit_blend: fit beta_m once for the whole image with the white balance instead
            (``skinfit.fit.calibrate``; the population prior scores the blend).
        blend_regions: (h, w) integer labels of the pixels that share a blend (a person each;
            0: none): overrides the faces found, e.g. for a mosaic of several people.
        white_balance: ``"auto"`` (default) fits per-channel camera gains once for the image from
            its skin pixels under a camera prior of 15 % per channel (``skinfit.fit.calibrate``:
            photos and captures of unknown balance; the gains' standard errors go in
            ``white_balance_sd``); ``"none"`` for inputs known to be calibrated (albedo in linear
            sRGB, D65 white = 1); ``"chart"`` calibrates from a ColorChecker in the frame (as
            ``colour_chart=True``); a tuple (r, g, b) gives them. ``True``/``False`` mean
            ``"auto"``/``"none"``.
        input_space: encoding of a file (``None``: from its type and metadata).
        mask: (h, w) array or image path; pixels where it is 0 are not fitted (status MASKED).
            A mask given wins over ``segmentation``.
        segmentation: ``"faces"`` (default) fits the skin of the faces in the photo
            (``skinfit.segmentation``: face detector, face mesh, the face's skin colour; eyes,
            brows, lips, nostrils, hair, background and clothes are MASKED; the region of every
            pixel is in ``region``); where no face is found, it warns and falls back to
            ``"none"``: every pixel, the model's gamut and ``skin_box`` deciding what is skin.
        input_type: ``"photo"`` (default: the shading is free per pixel) or ``"albedo"``: a
            calibrated albedo capture, whose shading is one scale for the whole image; the scale is
            fitted once (the one under which the skin's colours are reproduced best) and every
            pixel's shading held to it within ``ALBEDO_SHADING_SD``. This is what makes melanin
            identifiable in dark skin, which a photo's free shading lets pass for lighter skin in
            shadow.
        use_alpha: treat the file's alpha channel as a mask.
        illuminant: the illuminant of the camera model (colour-science name; D65 default).
        regularisation: ``"off"``, ``"light"`` (default) or ``"strong"``: a prior on each pixel's
            ln C_m and ln C_h centred on the median of its neighbourhood (edge-preserving), of
            standard deviation 0.3 / 0.05 over 3 x 3 / 5 x 5 pixels, combined with the population prior
            (weighed against the colour by ``colour_noise``: at 1 % noise light keeps ~95 % of a pixel's own
            value, strong ~30 %);
            ``prior=False`` (maximum likelihood) turns it off as well.
        colour_chart: ``True`` finds a ColorChecker in the frame and fits the image in the colours
            its correction matrix gives (``skinfit.colorimetry``; the white balance is then
            ``"none"`` unless given); or a ``ChartCalibration`` from another shot of the same setup.
            Reconstructions and renders go back through the matrix to the camera's values.
        model: the ``SkinModel`` (default: the package default); ``method`` overrides its forward
            method as in ``fit_pixels``.
        out_of_core: keep the input (when read from a file) and the maps in temporary files mapped
            from disk, read and written a band of rows at a time, so that the process's memory is
            set by a band, not by the image (``skinfit._scratch``); default: from 8 MP on (or
            ``$SKINFIT_OUT_OF_CORE``). The maps come back as arrays mapped from those files.
        **options: passed to ``fit_pixels`` (prior, colour_noise, max_delta_e, chunk_size, ...).

    Spatial coherence: the fold's branches differ in shading by 2-5x, and shading varies smoothly
    over a face, so after a first pass the branch of every pixel whose shading is far from the
    smooth shading field of its surroundings is chosen again against that field (unless
    ``shading_reference`` is given).
    """


    start, stage = time.perf_counter(), _Stages()
    model = model_with_options(model, method=method)
    if regularisation not in REGULARISATION:
        raise SkinfitInputError(f"regularisation must be one of {', '.join(REGULARISATION)}, got {regularisation!r}")
    alpha, encoding = None, "linear sRGB array"
    if _is_path(image):
        with stage("read"):
            # float32: a file holds no more (float, half or integer); decoded in float64 a chunk at a time
            rgb, alpha, encoding = read_image(image, input_space, np.float32, out_of_core=out_of_core)
    else:
        if isinstance(image, tuple) and len(image) == 3 and isinstance(image[2], str):
            raise SkinfitInputError("fit_image takes a path or an (h, w, 3) array, got read_image's "
                                    "(rgb, alpha, encoding) tuple: pass its rgb, or the path itself")
        try:
            rgb = np.asarray(image, dtype=float)
        except (TypeError, ValueError) as error:
            raise SkinfitInputError(f"fit_image takes a path or an (h, w, 3) array of numbers: {error}") from None
        if rgb.ndim != 3 or rgb.shape[-1] != 3:
            raise SkinfitInputError(f"expected an image of shape (h, w, 3), got {rgb.shape}")
    on_disk = scratch.out_of_core(rgb.shape[0] * rgb.shape[1], out_of_core)
    if _is_path(mask):
        mask = read_mask(mask)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.ndim == 3 and mask.shape[-1] == 1:
            mask = mask[..., 0]
        if mask.shape != rgb.shape[:2]:
            raise SkinfitInputError(f"mask has shape {mask.shape}, the image {rgb.shape[:2]}")
    if segmentation not in ("faces", "none"):
        raise SkinfitInputError(f"segmentation must be 'faces' or 'none', got {segmentation!r}")
    region, faces, skin_from = None, None, "model gamut" if mask is None else "mask"
    people = None  # (h, w) labels of the pixels that share a blend
    if mask is None and segmentation == "faces":
        with stage("segmentation"):
            found = _segment(rgb)
        if found is not None:
            faces = len(found.faces)
            if faces:
                region, mask, skin_from = found.region, found.skin, "faces"
                people = found.face_index
            else:
                warnings.warn("no face found in the image: fitting every pixel, the skin model's gamut deciding what is skin "
                              "(give a mask, or segmentation='none' to silence this)", stacklevel=2)
    if use_alpha and alpha is not None:
        mask = alpha if mask is None else np.minimum(mask, alpha)
    chart = None
    if isinstance(white_balance, str) and white_balance == "chart":
        colour_chart = colour_chart if isinstance(colour_chart, ChartCalibration) else True
        white_balance = "none"
    if colour_chart is not False and colour_chart is not None:

        chart = colour_chart if isinstance(colour_chart, ChartCalibration) else chart_calibration(rgb)
        rgb = chart.apply(rgb)
        if isinstance(white_balance, str) and white_balance == "auto":
            white_balance = "none"
    if blend_regions is not None:
        people = np.asarray(blend_regions)
        if people.shape != rgb.shape[:2] or not np.issubdtype(people.dtype, np.integer):
            raise SkinfitInputError(f"blend_regions must be integer labels of shape {rgb.shape[:2]}, got {people.dtype} {people.shape}")
    # per face where a population prior on the blend can weigh it: without one (DJ2006, prior=False),
    # blends that fit every colour (a photo's) cannot be chosen among, and the fit takes DJ2006's 0.7
    blend_prior = model.prior is not None and "melanin_blend" in model.prior.names and options.get("prior") is not False
    per_face = melanin_blend is None and not fit_blend and blend_prior
    if melanin_blend is None:
        melanin_blend = population_blend(model)
    if isinstance(white_balance, bool):
        white_balance = "auto" if white_balance else "none"
    gains, gains_sd = np.ones(3), None
    if fit_blend or (isinstance(white_balance, str) and white_balance == "auto"):

        with stage("white balance"):
            calibration = calibrate(
                _fittable_pixels(rgb, mask, options), melanin_blend=None if fit_blend else melanin_blend, white_balance=white_balance == "auto",
                illuminant=illuminant, model=model, colour_noise=options.get("colour_noise", 0.003), prior=options.get("prior"),
            )
        melanin_blend, gains = calibration.melanin_blend, np.asarray(calibration.white_balance)
        gains_sd = calibration.white_balance_sd if white_balance == "auto" else None
    elif isinstance(white_balance, str):
        if white_balance != "none":
            raise SkinfitInputError(f"white_balance must be 'auto', 'none', 'chart' or three positive gains, got {white_balance!r}")
    else:
        gains = np.asarray(white_balance, dtype=float)
        if gains.shape != (3,) or not np.all(gains > 0):
            raise SkinfitInputError(f"white_balance must be 'auto', 'none', 'chart' or three positive gains, got {white_balance}")
    options = dict(melanin_blend=melanin_blend, illuminant=illuminant, model=model, **options)
    if input_type not in ("photo", "albedo"):
        raise SkinfitInputError(f"input_type must be 'photo' or 'albedo', got {input_type!r}")
    shading_scale, estimates = None, {}
    with stage("blends and albedo scale"):
        if input_type == "albedo":
            shading_scale = _albedo_shading_scale(rgb, gains, mask, options)
            options["shading_prior"] = (shading_scale, ALBEDO_SHADING_SD)
        if people is None:
            people = np.ones(rgb.shape[:2], np.int16)
        faces_pixels = _face_pixels(rgb, mask, people, options) if per_face else {}
        if per_face and input_type == "albedo":
            # scale and blends together: the scale found at the population's blend is biased for faces
            # far from it (and, with the blend free, the colours alone barely tell the scale)
            shading_scale, estimates = _albedo_scale_and_blends(faces_pixels, gains, options, shading_scale)
            if len({e.melanin_blend for e in estimates.values()}) == 1 and not any(e.dark_box for e in estimates.values()):
                # one blend (one face): the scale again, finely, on the full table at it (the joint
                # search's coarse grid and tables leave it ~3 % off), and the blend at that scale
                blend = next(iter(estimates.values())).melanin_blend
                shading_scale = _albedo_shading_scale(rgb, gains, mask, dict(options, melanin_blend=blend))
                estimates = _face_blends(faces_pixels, gains, dict(options, shading_prior=(shading_scale, ALBEDO_SHADING_SD)))
            options["shading_prior"] = (shading_scale, ALBEDO_SHADING_SD)
        elif per_face:
            estimates = _face_blends(faces_pixels, gains, options)
        del faces_pixels  # every face's pixels: not needed by the fits
    dark = np.zeros(rgb.shape[:2], bool)  # the pixels fitted on the dark-skin box
    # each group is fitted on maps of its own (its spatial steps see its pixels only); the smaller
    # groups go first and keep only their own pixels' values, so that one full set of maps is held
    # at a time whatever the number of groups (the groups are disjoint: the order changes nothing)
    groups, earlier = _blend_groups(people, mask, estimates, melanin_blend)[::-1], []
    for i, ((blend, dark_box), where) in enumerate(groups):
        group = dict(options, melanin_blend=blend)
        if dark_box:
            group["table"] = colour_table(blend, illuminant, DARK_MELANIN_MAX, DARK_HAEMOGLOBIN_MAX, model=model)
            dark |= where
        maps, field = _fit_one_blend(rgb, gains, where, group, regularisation, progress, stage, on_disk)
        if i < len(groups) - 1:
            earlier.append((where, {k: v[where] for k, v in maps.items()}, field[where]))
            maps = field = None
    field = np.array(field, dtype=np.float32) if not scratch.is_on_disk(field) else field  # writable, the groups' parts go in
    for where, values, part_field in earlier:
        for k, v in values.items():
            maps[k][where] = v
        field[where] = part_field
    del earlier
    with stage("statuses"):
        _classify(rgb, gains, maps, field, model, dark)
    with stage("standard errors"):
        blend_sd = _honest_standard_errors(maps, people, estimates, model, options, regularisation, dark)
    blend_sd = blend_sd if per_face else None
    fitted = maps.pop("fitted_rgb")
    if chart is not None:
        fitted = chart.invert(fitted).astype(fitted.dtype)
    return ImageFit(**maps, fitted_linear_rgb=fitted, seconds=time.perf_counter() - start, white_balance=tuple(float(g) for g in gains),
                    model=model, colour_chart=chart, input_encoding=encoding, white_balance_sd=gains_sd, region=region, faces=faces,
                    skin_from=skin_from, input_type=input_type, shading_scale=shading_scale, melanin_blend_sd=blend_sd,
                    blends=tuple({"label": int(k), **e.as_dict()} for k, e in estimates.items()), stage_seconds=stage.seconds)


def _fit_one_blend(rgb, gains, mask, options, regularisation, progress, stage, on_disk=False):
    """The maps and shading field of the pixels ``mask`` at one blend: the first fit, the
    branches chosen against the shading field, the spatial regularisation (timed by ``stage``);
    ``on_disk``: the maps out of core (``skinfit._scratch``)."""
    with stage("first fit"):
        maps = _fit_in_bands(rgb, gains, mask, options, progress, on_disk=on_disk)
    with stage("branches against the shading field"):
        if options.get("shading_reference") is None:
            field = _coherent_branches(rgb, gains, maps, options)
        else:
            field = np.broadcast_to(np.asarray(options["shading_reference"], dtype=float), rgb.shape[:2])
    if REGULARISATION[regularisation] is not None and options.get("prior") is not False:
        with stage("regularised refit"):
            _regularise(rgb, gains, maps, field, options, *REGULARISATION[regularisation])
    return maps, field


#: Fewest fittable pixels a face needs for a blend of its own; smaller ones take the population's.
_MIN_FACE_PIXELS = 16


def _face_pixels(rgb, mask, people, options) -> dict[int, np.ndarray]:
    """Each labelled face's fittable pixels (n_k, 3), for faces of at least ``_MIN_FACE_PIXELS``."""
    fittable = _fittable(rgb, mask, options)
    # one pass over the image whatever the number of faces (a crowd's hundreds): the fittable
    # pixels sorted by label, then split
    labels = people[fittable]
    order = np.argsort(labels, kind="stable")
    labels, pixels = labels[order], _gathered(rgb, fittable)[order]
    found, starts, counts = np.unique(labels, return_index=True, return_counts=True)
    return {int(k): pixels[a : a + n] for k, a, n in zip(found, starts, counts) if k > 0 and n >= _MIN_FACE_PIXELS}


def _face_blends(faces: dict[int, np.ndarray], gains, options) -> dict[int, BlendEstimate]:
    """Each face's blend (``estimate_blends``) from its pixels (``_face_pixels``)."""
    if not faces:
        return {}
    found = estimate_blends(list(faces.values()), model=options["model"], illuminant=options["illuminant"], white_balance=tuple(gains),
                            shading_prior=options.get("shading_prior"), prior=options.get("prior"))
    return dict(zip(faces, found))


#: ln of the shading scales tried, with the faces' blends free, about the first estimate.
_JOINT_SCALE_GRID = np.linspace(np.log(0.6), np.log(1.6), 11)


def _albedo_scale_and_blends(faces, gains, options, first_scale):
    """The albedo capture's one scale and its faces' blends, jointly: for each scale of a grid
    about ``first_scale``, every face's best blend score (``estimate_blends``); the scale of the
    least sum over faces (refined by a parabola through the best three), then the faces' blends at it."""
    totals = []
    for log_scale in _JOINT_SCALE_GRID:
        found = _face_blends(faces, gains, dict(options, shading_prior=(first_scale * np.exp(log_scale), ALBEDO_SHADING_SD)))
        totals.append(sum(float(np.min(e.score)) for e in found.values()) if found else np.inf)
    totals = np.array(totals)
    if not np.isfinite(totals).any():
        return first_scale, {}
    scale = float(first_scale * np.exp(_parabola_minimum(_JOINT_SCALE_GRID, totals)))
    return scale, _face_blends(faces, gains, dict(options, shading_prior=(scale, ALBEDO_SHADING_SD)))


def _blend_groups(people, mask, estimates, default_blend):
    """((blend, dark box), pixels (h, w) bool) for each blend and box in use: the faces that share
    them, and the pixels of no estimated face at ``default_blend`` on the default box; largest first."""
    wanted = np.ones(people.shape, bool) if mask is None else np.asarray(mask) > 0
    groups: dict[tuple[float, bool], np.ndarray] = {}
    assigned = np.zeros(people.shape, bool)
    labels_of: dict[tuple[float, bool], list[int]] = {}
    for label, estimate in estimates.items():
        labels_of.setdefault((estimate.melanin_blend, estimate.dark_box), []).append(label)
    for key, labels in labels_of.items():  # one pass per blend, not per face
        where = wanted & np.isin(people, labels)
        groups[key] = where
        assigned |= where
    rest = wanted & ~assigned
    if rest.any() or not groups:
        key = (float(default_blend), False)
        groups[key] = groups.get(key, np.zeros(people.shape, bool)) | rest
    return sorted(groups.items(), key=lambda item: -item[1].sum())


def _honest_standard_errors(maps, people, estimates, model, options, regularisation, dark) -> np.ndarray:
    """Turn the fit's standard errors (colour noise ``colour_noise``, priors as fitted) into ones that
    hold the skin's value: in ln C, the colour's information at the model's discrepancy on real
    skin (``MODEL_DISCREPANCY`` added to the noise), with the population prior but not the
    neighbourhood's (the same face, not more evidence), and each face's blend uncertainty (the
    slope d ln C / d beta at a fixed colour times the blend's sd), in quadrature. Sets the blend
    map's sd and returns it (h, w)."""
    blend_sd = scratch.like(maps["melanin"])
    noise = options.get("colour_noise", 0.003)
    shrink = noise**2 / (noise**2 + MODEL_DISCREPANCY**2)  # the colour's information at the model's discrepancy
    population = model.prior if options.get("prior") is not False else None
    # per-label lookup tables (faces are labelled from 1; 0: no face): one pass over the image whatever the number of faces
    size = max(int(people.max()), max(estimates, default=0)) + 1
    tables, known = np.zeros((3, size), np.float32), np.zeros(size, bool)
    for label, e in estimates.items():
        tables[:, label] = (e.sd, e.melanin_log_slope * e.sd, e.haemoglobin_log_slope * e.sd)
        known[label] = True
    for band in scratch.row_bands(*blend_sd.shape):  # bounded float64 temporaries
        here = maps["status"][band] <= PixelStatus.OUT_OF_MODEL
        owner = np.where(here & (people[band] > 0), people[band], 0)
        face = known[owner]
        blend_sd[band][face] = tables[0][owner[face]]
        slopes = {"melanin": np.zeros(here.shape, np.float32), "haemoglobin": np.zeros(here.shape, np.float32)}
        slopes["melanin"][face] = tables[1][owner[face]]
        slopes["haemoglobin"][face] = tables[2][owner[face]]
        for name, top, dark_top in (("melanin", MELANIN_MAX, DARK_MELANIN_MAX), ("haemoglobin", HAEMOGLOBIN_MAX, DARK_HAEMOGLOBIN_MAX)):
            top = np.where(dark[band][here], dark_top, top)
            value, se = maps[name][band][here].astype(float), maps[f"{name}_se"][band][here].astype(float)
            prior_precision = 0.0
            if population is not None:
                prior_precision = 1.0 / population.moments(name)[1] ** 2
            fit_precision = prior_precision
            if REGULARISATION[regularisation] is not None and population is not None:
                fit_precision = fit_precision + 1.0 / REGULARISATION[regularisation][0] ** 2
            with np.errstate(divide="ignore"):
                colour = np.maximum(1.0 / np.maximum(se / np.maximum(value, 1e-12), 1e-12) ** 2 - fit_precision, 0.0) * shrink
                log_se = np.sqrt(1.0 / (colour + prior_precision) + slopes[name][here].astype(float) ** 2)
            # an unidentified value reports the whole box, as the fit's own standard errors do
            maps[f"{name}_se"][band][here] = np.minimum(value * np.nan_to_num(log_se, nan=np.inf, posinf=np.inf), top)
    return blend_sd


#: Standard deviation of ln shading about the image's one scale for ``input_type="albedo"``: what
#: is left of the face's relief in an albedo capture.
ALBEDO_SHADING_SD = 0.05

#: ln of the shading scales tried for an albedo capture, about the first fits' median shading.
_SCALE_GRID = np.linspace(np.log(0.4), np.log(2.5), 22)


def _fittable(rgb, mask, options) -> np.ndarray:
    """(h, w) bool: the pixels that a fit would take: not black, saturated, masked or invalid
    (screened a band of rows at a time: no full-size temporaries)."""
    h, w, _ = rgb.shape
    fittable = np.empty((h, w), bool)
    for rows in scratch.row_bands(h, w):
        part = rgb[rows]
        screened, _ = screen_pixels(part.reshape(-1, 3), None if mask is None else mask[rows], options.get("black_level", 1e-4),
                                    options.get("saturation_level", 0.999))
        fittable[rows] = (screened == PixelStatus.SUCCESS).reshape(part.shape[:2])
    return fittable


def _fittable_pixels(rgb, mask, options) -> np.ndarray:
    """The pixels (n, 3) that a fit would take."""
    fittable = _fittable(rgb, mask, options)
    if not fittable.any():
        raise SkinfitInputError("no pixel of the image can be fitted (all black, saturated, masked or invalid)")
    return _gathered(rgb, fittable)


def _gathered(image, where) -> np.ndarray:
    """``image[where]`` ((n, ...) in row-major order), gathered a band of rows at a time (an
    out-of-core image's pages given back after each)."""
    h, w = where.shape
    out = np.empty((int(np.count_nonzero(where)), *image.shape[2:]), image.dtype)
    start = 0
    for rows in scratch.row_bands(h, w):
        part = image[rows][where[rows]]
        out[start : start + len(part)] = part
        start += len(part)
    return out


def _albedo_shading_scale(rgb, gains, mask, options, sample_size: int = 2048, trim: float = 0.8, seed: int = 0) -> float:
    """The one shading scale of an albedo capture: on a sample of its fittable pixels, the scale
    under which (shading held to it) the trimmed mean of the pixels' relative colour residuals is
    least, on a grid about the free-shading fits' median, refined by a parabola through the best
    three."""
    fittable = _fittable_pixels(rgb, mask, options)
    sample = fittable[np.random.default_rng(seed).choice(len(fittable), min(sample_size, len(fittable)), replace=False)]
    base = {k: v for k, v in options.items() if k not in ("shading_reference", "prior_mean", "prior_sd", "shading_prior")}
    base.update(white_balance=tuple(gains), progress=False, prior=False, lm_max_steps=0, max_straggler_rounds=8)
    free = fit_pixels(sample, **base)
    centre = float(np.median(free["shading"][free["status"] <= PixelStatus.OUT_OF_MODEL]))

    def score(log_scale):
        fit = fit_pixels(sample, shading_prior=(centre * np.exp(log_scale), ALBEDO_SHADING_SD), **base)
        residual = np.linalg.norm(sample / gains - fit["fitted_rgb"], axis=-1) / np.linalg.norm(sample / gains, axis=-1)
        residual = np.sort(residual[fit["status"] <= PixelStatus.OUT_OF_MODEL] ** 2)
        return float(np.mean(residual[: max(1, int(trim * residual.size))])) if residual.size else np.inf

    return float(centre * np.exp(_parabola_minimum(_SCALE_GRID, np.array([score(x) for x in _SCALE_GRID]))))


def _parabola_minimum(grid: np.ndarray, values: np.ndarray) -> float:
    """The minimum of ``values`` on an even ``grid``, refined by a parabola through the best point and
    its neighbours (at most one step off it; the best interior point where the parabola is not convex)."""
    best = int(np.clip(np.argmin(values), 1, len(grid) - 2))
    x, y = grid[best - 1 : best + 2], values[best - 1 : best + 2]
    curvature = y[0] - 2 * y[1] + y[2]
    step = x[1] - x[0]
    offset = 0.5 * step * (y[0] - y[2]) / curvature if curvature > 0 and np.all(np.isfinite(y)) else 0.0
    return float(x[1] + np.clip(offset, -step, step))


#: Pixels per chunk of the encoding that the face models see.
_ENCODE_CHUNK = 1 << 18


def _segment(rgb: np.ndarray) -> FaceSegmentation | None:
    """The faces of a linear sRGB image, on its sRGB encoding (as the face models saw photos);
    None where the runtime is missing."""
    try:
        # encoded a band of rows at a time, padded to one of few sizes (whole, a 48 MP photo's JAX
        # temporaries take gigabytes), into an array out of core where the image is
        h, w, _ = rgb.shape
        size = bucket_size(h * w, max(_ENCODE_CHUNK, w))
        encoded = scratch.like(rgb, np.float32)
        for rows in scratch.row_bands(h, w, size):
            part = rgb[rows].reshape(-1, 3)
            linear = jnp.asarray(padded_rows(part, size)).astype(jnp.float32)
            encoded[rows] = np.asarray(srgb_encode(jnp.clip(linear, 0.0, 1.0)))[: len(part)].reshape(-1, w, 3)
        return segment_faces(encoded)
    except SegmentationUnavailable as error:
        warnings.warn(f"{error}: fitting every pixel, the skin model's gamut deciding what is skin", stacklevel=3)
        return None


def population_blend(model: SkinModel) -> float:
    """The blend a fit uses when none is given: the population prior's mean, else DJ2006's 0.7."""
    prior = model.prior
    if prior is None or "melanin_blend" not in prior.names:
        return 0.7
    logit, _ = prior.moments("melanin_blend")
    var = VARIABLES["melanin_blend"]
    return round(var.low + (var.high - var.low) / (1.0 + np.exp(-logit)), 3)


#: Shading ratio to the smooth field beyond which a pixel's branch is chosen again.
_FAR_FROM_FIELD = np.log(1.1)


def _fitted(status) -> np.ndarray:
    """Pixels (of the ``status`` codes given) whose maps hold a fit: SUCCESS or MAX_STEPS."""
    return (status == PixelStatus.SUCCESS) | (status == PixelStatus.MAX_STEPS)


def _field_sigma(shape) -> float:
    """Smoothing scale of the shading field: 1 % of the image's larger side, at least 2 pixels."""
    return max(2.0, 0.01 * max(shape))


def _shading_field(maps, sigma: float | None = None) -> np.ndarray:
    """Smooth ln-shading field of the fitted pixels at scale ``sigma`` (pixels; default
    ``_field_sigma``), twice: the second leaves out pixels far from the first (those on the other
    branch)."""

    shading = maps["shading"]
    log_k = scratch.Rows(shading.shape, lambda rows: np.log(np.maximum(shading[rows], np.float32(1e-12))))  # float32, as the maps
    fitted = scratch.Rows(shading.shape, lambda rows: _fitted(maps["status"][rows]))
    sigma = _field_sigma(shading.shape) if sigma is None else sigma
    field = smooth_field(log_k, fitted, sigma, out=scratch.like(shading))
    near = scratch.Rows(shading.shape, lambda rows: fitted[rows] & (np.abs(log_k[rows] - field[rows]) <= _FAR_FROM_FIELD))
    return smooth_field(log_k, near, sigma, out=field)  # in place: smooth_field reads all of near before it writes


def _refit(rgb, gains, maps, where, options, band_pixels: int = 1 << 18, **overrides):
    """Fit again the pixels ``where`` (h, w) with ``overrides`` (per-pixel arrays (h, w, ...) are
    taken at those pixels) and write the results into ``maps``, ``band_pixels`` at a time (the
    working memory of a 4096 x 4096 image stays that of one band)."""
    for index in _pixel_chunks(where, band_pixels):
        pick = lambda v: v[index] if isinstance(v, np.ndarray) and v.ndim >= 2 else v  # noqa: E731
        extra = {k: tuple(pick(a) for a in v) if isinstance(v, tuple) else pick(v) for k, v in overrides.items()}
        part = fit_pixels(rgb[index], white_balance=tuple(gains), progress=False, **dict(options, **extra))
        part["fitted_rgb"] = part["fitted_rgb"] * gains
        for k, v in part.items():
            maps[k][index] = v
        scratch.release_pages()


def _pixel_chunks(where, size: int):
    """(rows, cols) of the pixels ``where`` (h, w) in row-major order, ``size`` at a time (the
    chunks of ``np.nonzero(where)``), found a band of rows at a time: no index arrays of the
    whole image (a 48 MP photo's would take 0.8 GB)."""
    h, w = where.shape
    pending_rows, pending_cols, count = [], [], 0
    for rows in scratch.row_bands(h, w, max(size, w)):
        r, c = np.nonzero(where[rows])
        pending_rows.append(r + rows.start)
        pending_cols.append(c)
        count += r.size
        while count >= size:
            r, c = np.concatenate(pending_rows), np.concatenate(pending_cols)
            yield r[:size], c[:size]
            pending_rows, pending_cols, count = [r[size:]], [c[size:]], r.size - size
    if count:
        yield np.concatenate(pending_rows), np.concatenate(pending_cols)


#: Scales of the coarser shading fields the branches are first chosen against, as fractions of the
#: image's larger side. The first pass chooses against one shading for a whole band, so where the
#: shading spans 2x a region as large as the fold (a third of a smooth map over the whole box) can
#: come out on the other branch; a field at the fine scale alone then follows that region.
_COARSE_FIELD_SCALES = (0.15, 0.05)


#: Distance in log colour (``ColourTable.colour_distance``) within which the model has a colour:
#: the table's sampling leaves up to 0.028 between a pixel over its true shading and its nearest node.
_COLOUR_REACH = 0.03


def _has_colour_at(table, albedo) -> np.ndarray:
    """Whether the model has a colour near each of ``albedo`` (n, 3): a pixel whose colour over the
    field's shading is not one (on a real capture, almost no pixel 1.3x off its fitted shading) has
    no branch there, and a refit could not move it."""
    return table.colour_distance(albedo, upper_bound=_COLOUR_REACH) <= _COLOUR_REACH


def _coherent_branches(rgb, gains, maps, options) -> np.ndarray:
    """Choose the fold's branch again against smooth shading fields, coarse to fine, where the
    shading so far is far from them; returns the finest field (h, w) (linear shading)."""
    table = options.get("table") or colour_table(options["melanin_blend"], options["illuminant"], model=options["model"])
    size = max(maps["shading"].shape)
    for sigma in (*(max(2.0, scale * size) for scale in _COARSE_FIELD_SCALES), None):
        field = _shading_field(maps, sigma)
        far = np.zeros(field.shape, bool)
        for rows in scratch.row_bands(*field.shape):  # no full-size temporaries
            field[rows] = np.exp(field[rows])
            # out-of-model pixels (hair, background) have no branch worth choosing, and are the slowest to refit;
            # a face's own shading strays 1.1x from a coarse field at most pixels, but few have a colour there
            here = _fitted(maps["status"][rows])
            here &= np.abs(np.log(np.maximum(maps["shading"][rows], np.float32(1e-12)) / field[rows])) > _FAR_FROM_FIELD
            here[here] = _has_colour_at(table, rgb[rows][here] / gains / field[rows][here][:, None])
            far[rows] = here
        if far.any():
            _refit(rgb, gains, maps, far, options, shading_reference=field)
    return field


def _regularise(rgb, gains, maps, field, options, sd, size):
    """Refit every fitted pixel under a prior centred on its neighbourhood's median ln C (an
    edge-preserving centre), combined with the population prior (precisions add)."""

    fitted = _fitted(maps["status"])
    if not fitted.any():
        return
    model = options["model"]
    # float32: a 4096 x 4096 image's centres in 134 MB (out of core with the maps)
    centres, sds = scratch.like(maps["melanin"], shape=(*fitted.shape, 2)), []
    population = model.prior
    rows, halo = max(1, _CLASSIFY_CHUNK // max(fitted.shape[1], 1)), size // 2
    for i, name in enumerate(("melanin", "haemoglobin")):
        values = maps[name]
        log_values = scratch.Rows(fitted.shape, lambda band: np.log(np.maximum(values[band], np.float32(1e-9))))
        fill = smooth_field(log_values, fitted, _field_sigma(fitted.shape), out=scratch.like(values))
        if population is not None and options.get("prior", True) is not False:
            p_mean, p_sd = population.moments(name)
            precision = 1.0 / sd**2 + 1.0 / p_sd**2
            combined = np.sqrt(1.0 / precision)
        else:
            combined = sd
        # the medians a band of rows at a time, with the rows the neighbourhood reaches beyond it
        # (the same values as over the whole image, without its full-size temporaries)
        for top in range(0, fitted.shape[0], rows):
            lo, hi = max(0, top - halo), min(fitted.shape[0], top + rows + halo)
            log_c = np.log(np.maximum(maps[name][lo:hi], np.float32(1e-9)))
            centre = neighbourhood_median(log_c, fitted[lo:hi], size, fill[lo:hi])[top - lo : top - lo + rows]
            if population is not None and options.get("prior", True) is not False:
                centre = (centre / sd**2 + p_mean / p_sd**2) / precision
            centres[top : top + rows, :, i] = centre
            scratch.release_pages()
        sds.append(combined)
        del fill
    _refit(rgb, gains, maps, fitted, options, prior_mean=centres, prior_sd=np.array(sds),
           shading_reference=field, prior=True, initial=(maps["melanin"], maps["haemoglobin"]))


#: Candidate pixels per chunk of the glint test.
_CLASSIFY_CHUNK = 1 << 18

#: Relative residual below which a pixel is the neighbourhood's skin colour plus white (a glint).
_SPECULAR_FIT = 0.03

#: |ln(shading / shading field)| beyond which a pixel is another surface than the skin around it
#: (a factor 3: the fold's branches differ by 2-5x, but the field has chosen among them already).
_OTHER_SURFACE = np.log(3.0)

#: Population-prior standard deviations of ln C beyond which a fit is not skin (5: C_m outside
#: 0.5-85 %, C_h outside 0.08-62 % for the calibrated model's prior).
_IMPLAUSIBLE_Z = 5.0

#: Standard error, as a fraction of the table's top, below which (and below the value itself) the colour sets a value.
_IDENTIFIED = 0.25

#: CIEDE2000 within which a fit on the box's top reproduces its pixel: the colour lies inside the
#: box. Two colour pipelines (skinfit's and colour-science's) differ by up to 0.08 at the top.
_EXACT_DE = 0.15

#: Largest |ln(value / edge)| that a fit which reproduces its colour (within ``_EXACT_DE``) may lie
#: beyond the skin box (two standard errors up to this): a skin on the box's edge fits up to 20 %
#: (1.25x) beyond it; wall and cloth lie further.
_EDGE_MARGIN = np.log(1.5)


def skin_box(model: SkinModel, melanin_max: float = MELANIN_MAX, haemoglobin_max: float = HAEMOGLOBIN_MAX) -> dict[str, tuple[float, float]]:
    """The melanin and haemoglobin that an image fit calls skin, ``{name: (low, high)}``: the
    colour table's box (up to ``MELANIN_MAX``, ``HAEMOGLOBIN_MAX``), narrowed by the model's
    population prior to within ``_IMPLAUSIBLE_Z`` of its standard deviations. A fit outside it
    is ``NOT_SKIN``; every colour of a skin inside it is
    fitted as skin (``benchmarks/fit_image_box.py``)."""
    box = {"melanin": (0.0, melanin_max), "haemoglobin": (0.0, haemoglobin_max)}
    population = resolve_model(model).prior
    if population is None:
        return box
    for name, (low, high) in box.items():
        mean, sd = population.moments(name)  # in ln C (prior_coordinate)
        box[name] = (max(low, float(np.exp(mean - _IMPLAUSIBLE_Z * sd))), min(high, float(np.exp(mean + _IMPLAUSIBLE_Z * sd))))
    return box


def _classify(rgb, gains, maps, field, model, dark=None):
    """Statuses of pixels that fit the model badly or implausibly: ``SPECULAR`` (the smooth local
    skin colour at no less than 80 % of the local shading plus a white component of at least 10 %
    of the pixel), ``NOT_SKIN`` (outside ``skin_box`` by more than two standard errors, at most
    ``_EDGE_MARGIN``, where the colour identifies the value; pinned at the box's top by a colour
    beyond it, or a shading 3x off the smooth field of its surroundings:
    hair, brows, eyes); ``dark`` (h, w): the pixels fitted on the dark-skin box, judged against it.
    Their maps are zeroed: a value no skin has is never presented as skin."""

    status = maps["status"]
    dark = np.zeros(status.shape, bool) if dark is None else dark
    boxes = skin_box(model), skin_box(model, DARK_MELANIN_MAX, DARK_HAEMOGLOBIN_MAX)
    rows = max(1, _CLASSIFY_CHUNK // max(status.shape[1], 1))
    for top in range(0, status.shape[0], rows):  # per-pixel tests in bands: no full-size float64 temporaries
        band = slice(top, top + rows)
        implausible = _implausible({k: v[band] for k, v in maps.items()}, field[band].astype(float), dark[band], boxes)
        part = status[band]
        part[(part <= PixelStatus.OUT_OF_MODEL) & implausible] = PixelStatus.NOT_SKIN
        scratch.release_pages()

    # glints: t = a L + s g, with L the local skin colour per unit shading and g the white (gains)
    candidates = scratch.Rows(status.shape, lambda band: (status[band] == PixelStatus.OUT_OF_MODEL) | (status[band] == PixelStatus.NOT_SKIN))
    skin = scratch.Rows(status.shape, lambda band: status[band] == PixelStatus.SUCCESS)
    if _any(candidates) and _any(skin):
        sigma = _field_sigma(status.shape)
        fitted_rgb, shading = maps["fitted_rgb"], maps["shading"]
        fields = [smooth_field(scratch.Rows(status.shape, lambda band, c=c: fitted_rgb[band][..., c] / np.maximum(shading[band], np.float32(1e-12))),
                               skin, sigma, out=scratch.like(shading)) for c in range(3)]
        for index in _pixel_chunks(candidates, _CLASSIFY_CHUNK):  # bounded temporaries on a 4096^2 image
            local = np.stack([f[index] for f in fields], axis=-1)
            t = rgb[index]
            basis = np.stack([local, np.broadcast_to(gains, local.shape)], axis=-1)  # (n, 3, 2)
            # normal equations of the two columns, batched (1e-30: a black local colour)
            gram = np.einsum("nck,ncl->nkl", basis, basis) + 1e-30 * np.eye(2)
            coef = np.linalg.solve(gram, np.einsum("nck,nc->nk", basis, t)[..., None])[..., 0]
            residual = np.linalg.norm(t - np.einsum("nck,nk->nc", basis, coef), axis=-1) / np.maximum(np.linalg.norm(t, axis=-1), 1e-12)
            white_share = coef[:, 1] * np.mean(gains) / np.maximum(np.mean(t, axis=-1), 1e-12)
            glint = (coef[:, 0] > 0.8 * field[index].astype(float)) & (white_share > 0.1) & (residual < _SPECULAR_FIT)
            status[tuple(i[glint] for i in index)] = PixelStatus.SPECULAR
    for band in scratch.row_bands(*status.shape):
        not_skin = status[band] >= PixelStatus.NOT_SKIN
        for name in ("melanin", "haemoglobin", "shading", "melanin_se", "haemoglobin_se"):
            maps[name][band][not_skin] = 0.0


def _any(image) -> bool:
    """Whether any pixel of a (h, w) bool image (or ``Rows`` expression) is set, a band at a time."""
    return any(bool(np.any(image[rows])) for rows in scratch.row_bands(*image.shape[:2]))


def _implausible(maps, field, dark, boxes) -> np.ndarray:
    """``_classify``'s test of fits no skin has, on (a band of) the maps: outside the skin box
    (``boxes``: the usual and the dark-skin one, each pixel against the one it was fitted on) where
    the colour identifies the value, pinned at the box's top by a colour beyond it, or a shading 3x
    off the smooth ``field``."""
    box, dark_skin_box = boxes
    implausible = np.zeros(dark.shape, bool)
    # the colour reproduced: the margin beyond the box applies only there (a skin on the edge fits
    # exactly; a glint, skin plus white, fits as the lightest skin with a CIEDE2000 of 0.5)
    exact = maps["residual_dE2000"] <= _EXACT_DE
    for name, top, dark_top in (("melanin", MELANIN_MAX, DARK_MELANIN_MAX), ("haemoglobin", HAEMOGLOBIN_MAX, DARK_HAEMOGLOBIN_MAX)):
        value, top = maps[name], np.where(dark, dark_top, top)
        low, high = np.where(dark, dark_skin_box[name][0], box[name][0]), np.where(dark, dark_skin_box[name][1], box[name][1])
        # outside the skin box, or pinned at the table's top by a colour beyond it (missed by more
        # than _EXACT_DE: a skin at the box's top fits exactly). Only a value the colour identifies
        # counts: one it does not (haemoglobin under heavy melanin: a standard error larger than the
        # value, or than a quarter of the box) is skin of unknown C_h, wherever the solver left it.
        se = maps[f"{name}_se"]
        identified = se < np.minimum(_IDENTIFIED * top, value)
        pinned = (value >= 0.999 * top) & ~exact
        margin = np.where(exact, np.exp(np.minimum(2.0 * se / np.maximum(value, 1e-12), _EDGE_MARGIN)), 1.0)
        implausible |= identified & (pinned | (value * margin < low) | (value > high * margin))
    # another surface than the skin around it (hair, brows, eyes): a shading far from the field
    return implausible | (np.abs(np.log(np.maximum(maps["shading"], 1e-12) / field)) > _OTHER_SURFACE)


def _fit_in_bands(rgb, gains, mask, options, progress, band_pixels: int = 1 << 18, on_disk: bool = False):
    """``fit_pixels`` over bands of rows of at most ``band_pixels`` pixels, into preallocated
    float32 maps (as the EXR stores them; ``fit_pixels`` returns float64; out of core with
    ``on_disk``): the working memory of a 4096 x 4096 image stays that of one band. The shading
    reference that picks the fold's branch comes from the first band."""
    h, w, _ = rgb.shape
    rows = max(1, band_pixels // max(w, 1))
    maps = None
    bands = range(0, h, rows)
    if progress is None:
        progress = len(bands) > 1
    if progress and len(bands) > 1:
        from tqdm.auto import tqdm

        bands = tqdm(bands, desc="fitting bands", unit="band")
    for top in bands:
        # the camera's values: black and clipped pixels are judged before the white balance divides them
        part = fit_pixels(rgb[top : top + rows], mask=None if mask is None else mask[top : top + rows], white_balance=tuple(gains),
                          progress=False, **options)
        part["fitted_rgb"] = part["fitted_rgb"] * gains
        if maps is None:
            maps = {k: scratch.image_array((h, w, *v.shape[2:]), np.float32 if v.dtype == np.float64 else v.dtype, on_disk)
                    for k, v in part.items()}
            if options.get("shading_reference") is None and len(range(0, h, rows)) > 1:
                fitted = part["status"] == PixelStatus.SUCCESS
                options = dict(options, shading_reference=float(np.median(part["shading"][fitted])) if fitted.any() else None)
        for k, v in part.items():
            maps[k][top : top + rows] = v
        scratch.release_pages()
    return maps


def _is_path(value) -> bool:
    return isinstance(value, (str, bytes)) or hasattr(value, "__fspath__")
