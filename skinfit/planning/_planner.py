"""Compute only what a request needs: a planner from "what I want" to the smallest computation.

A ``Request`` names the outputs (spectral reflectance at given wavelengths, linear sRGB colour,
radial profiles, derivatives) and the scale of the scene (the pixel footprint on the skin, the
largest radius that matters). ``plan`` turns it into a ``Plan``:

- reflectance only: one frequency (q = 0) per wavelength; no profile work at all;
- RGB: the coarsest of a ladder of uniform wavelength grids whose colour error against the 1 nm
  integral stays within ``colour_tolerance`` (CIEDE2000, worst case over a probe set spanning the
  parameter box), shared with the spectral wavelengths where they coincide;
- profiles: radii log-spaced from half the pixel footprint (finer detail is not resolved) to the
  largest radius that matters; with concrete parameters, a profile that keeps at least
  ``1 - energy_tolerance`` of its energy within half the footprint is reported as not needed
  (the surface can be shaded with the reflectance alone) and skipped;
- derivatives: forward-mode derivatives of each requested output with respect to melanin,
  melanin blend and haemoglobin (three tangents, whatever the number of outputs).

``plan(...).describe()`` (and ``skinfit plan`` on the command line) prints what will and will not
be computed; ``plan(...).evaluate(params)`` runs it.

    >>> the_plan = skinfit.plan(rgb=True, profiles=True, pixel_footprint_mm=0.5)
    >>> print(the_plan.describe())
    >>> result = the_plan.evaluate(skinfit.preset("medium"))   # result.rgb, result.rgb_profiles
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._caching import eager_cache
from .._validate import SkinfitInputError, check_range
from ..colorimetry import (
    DEFAULT_ILLUMINANT,
    delta_e2000,
    linear_srgb_to_lab,
    linear_srgb_weights,
)
from ..model import (
    PRESET_NAMES,
    WAVELENGTH_RANGE_NM,
    HankelQuadrature,
    SkinModel,
    SkinParams,
    captured_reflectance,
    diffuse_reflectance,
    inverse_kernel,
    model_with_options,
    preset,
    resolve_model,
    skin_profile,
    skin_reflectance,
)

#: Uniform wavelength grids the RGB planner tries (nm): every start, end and step that fit together.
RGB_STARTS_NM = (380.0, 400.0, 410.0, 420.0, 430.0, 440.0)
RGB_ENDS_NM = (640.0, 650.0, 660.0, 670.0, 680.0, 690.0, 700.0, 720.0, 740.0, 780.0)
RGB_STEPS_NM = (60.0, 50.0, 40.0, 30.0, 20.0, 15.0, 10.0, 5.0, 2.0, 1.0)
#: The derivatives a request can ask for (the SkinParams fields the model depends on).
DERIVATIVE_NAMES = ("melanin", "melanin_blend", "haemoglobin")


@dataclasses.dataclass(frozen=True)
class Request:
    """What a caller wants computed.

    Attributes:
        wavelengths_nm: spectral reflectance wanted at these wavelengths (nm); None: no spectrum.
        rgb: linear sRGB colour under ``illuminant`` wanted.
        colour_tolerance: CIEDE2000 the RGB output may differ from the 1 nm colour integral.
        profiles: radial profiles wanted (at the spectral wavelengths, and in RGB when ``rgb``).
        pixel_footprint_mm: size of one pixel on the skin (mm); None: resolve from 1e-3 mm.
        max_radius_mm: largest radius that matters in the scene (mm).
        energy_tolerance: a profile keeping at least 1 - this of its energy within half the
            footprint is not needed.
        derivatives: derivatives of the outputs with respect to ``DERIVATIVE_NAMES`` wanted.
        profile_radii: number of log-spaced radii of a profile.
    """

    wavelengths_nm: tuple[float, ...] | None = None
    rgb: bool = False
    illuminant: str = DEFAULT_ILLUMINANT
    colour_tolerance: float = 0.1
    profiles: bool = False
    pixel_footprint_mm: float | None = None
    max_radius_mm: float = 20.0
    energy_tolerance: float = 3e-3
    derivatives: bool = False
    profile_radii: int = 256

    def __post_init__(self):
        if self.wavelengths_nm is not None:
            lam = np.asarray(self.wavelengths_nm, dtype=float).ravel()
            low, high = WAVELENGTH_RANGE_NM
            if lam.size == 0 or not np.all(np.isfinite(lam)) or np.any((lam < low) | (lam > high)):
                raise SkinfitInputError(f"wavelengths_nm must be finite values within {low:g}-{high:g} nm")
            if lam.size > 1 and np.any(np.diff(lam) <= 0):
                raise SkinfitInputError("wavelengths_nm must be strictly increasing")
            object.__setattr__(self, "wavelengths_nm", tuple(lam.tolist()))
        if self.wavelengths_nm is None and not self.rgb:
            raise SkinfitInputError("a request needs wavelengths_nm (a spectrum) or rgb=True (a colour)")
        for name in ("colour_tolerance", "max_radius_mm", "energy_tolerance"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise SkinfitInputError(f"{name} must be a finite value > 0, got {value}")
        footprint = self.pixel_footprint_mm
        if footprint is not None and not (np.isfinite(footprint) and 0 < footprint < 2 * self.max_radius_mm):
            raise SkinfitInputError(f"pixel_footprint_mm must be > 0 and below 2 * max_radius_mm, got {footprint}")
        if int(self.profile_radii) < 2:
            raise SkinfitInputError("profile_radii must be at least 2")


@dataclasses.dataclass(frozen=True)
class Plan:
    """The smallest computation for a ``Request`` (see ``describe``).

    Attributes:
        request: what was asked.
        model_wavelengths_nm: every wavelength the model is evaluated at (sorted, unique).
        spectral_index: positions of the requested spectrum in ``model_wavelengths_nm``.
        colour_index: positions of the RGB wavelengths in ``model_wavelengths_nm``.
        colour_wavelengths_nm: the RGB grid (None without RGB).
        colour_error: worst CIEDE2000 of that grid against the 1 nm integral on the probe set.
        radii_mm: profile radii (None: no profile work).
        notes: one line per decision, for people.
    """

    request: Request
    model_wavelengths_nm: tuple[float, ...]
    spectral_index: tuple[int, ...] | None
    colour_index: tuple[int, ...] | None
    colour_wavelengths_nm: tuple[float, ...] | None
    colour_error: float | None
    radii_mm: tuple[float, ...] | None
    notes: tuple[str, ...]

    @property
    def computes_profiles(self) -> bool:
        return self.radii_mm is not None

    def evaluate(self, params: SkinParams, **model_options) -> "Result":
        """Run the plan for ``params``; see ``evaluate``."""
        return evaluate(self, params, **model_options)

    def describe(self) -> str:
        lines = [f"plan: the model at {len(self.model_wavelengths_nm)} wavelengths"]
        lines += [f"  - {note}" for note in self.notes]
        return "\n".join(lines)


def plan(request: Request | None = None, params: SkinParams | None = None, *, model: SkinModel | None = None,
         **request_fields) -> Plan:
    """The smallest computation for ``request`` (or a ``Request`` built from keyword arguments).

    ``params`` (concrete) lets the planner check whether profiles are wider than a pixel, for
    ``model`` (default: the package default); without them a requested profile is always computed.
    """
    if request is None:
        request = Request(**request_fields)
    elif request_fields:
        request = dataclasses.replace(request, **request_fields)
    notes = []
    spectral = np.asarray(request.wavelengths_nm) if request.wavelengths_nm is not None else np.zeros(0)
    if spectral.size:
        notes.append(f"spectral reflectance at {spectral.size} wavelengths ({spectral[0]:g}-{spectral[-1]:g} nm)")
    else:
        notes.append("spectral reflectance: not requested")

    colour_grid, error = np.zeros(0), None
    if request.rgb:
        grid, error = rgb_wavelengths(request.illuminant, request.colour_tolerance)
        colour_grid = np.asarray(grid)
        step = colour_grid[1] - colour_grid[0] if colour_grid.size > 1 else 0.0
        notes.append(
            f"RGB ({request.illuminant}) from {colour_grid.size} wavelengths, {colour_grid[0]:g}-{colour_grid[-1]:g} nm "
            f"in {step:g} nm steps: worst CIEDE2000 {error:.3g} against the 1 nm integral over the probe set "
            f"(tolerance {request.colour_tolerance:g}; 5 nm spectra over 380-780 nm take 81)"
        )
    else:
        notes.append("RGB: not requested")

    model_grid = np.unique(np.concatenate([spectral, colour_grid]))
    spectral_index = tuple(np.searchsorted(model_grid, spectral).tolist()) if spectral.size else None
    colour_index = tuple(np.searchsorted(model_grid, colour_grid).tolist()) if colour_grid.size else None

    radii = None
    if not request.profiles:
        notes.append("profiles: not requested (no Hankel quadrature, reflectance at q = 0 only)")
    else:
        inner = 0.5 * request.pixel_footprint_mm if request.pixel_footprint_mm is not None else 1e-3
        kept = None if params is None else _energy_within(params, model_grid, inner, resolve_model(model))
        if kept is not None and kept >= 1.0 - request.energy_tolerance:
            notes.append(
                f"profiles: not needed: at most {100 * max(1.0 - kept, 0.0):.2g} % of the energy lies beyond half the "
                f"pixel footprint ({inner:g} mm) at any wavelength: shade with the reflectance"
            )
        else:
            radii = tuple(np.geomspace(inner, request.max_radius_mm, int(request.profile_radii)).tolist())
            why = "" if kept is None else f"; {100 * (1.0 - kept):.2g} % of the energy lies beyond {inner:g} mm"
            notes.append(
                f"profiles: {len(radii)} radii {inner:g}-{request.max_radius_mm:g} mm at {model_grid.size} wavelengths{why}"
            )
    if request.derivatives:
        notes.append(f"derivatives: forward mode, {len(DERIVATIVE_NAMES)} tangents ({', '.join(DERIVATIVE_NAMES)})")
    else:
        notes.append("derivatives: not requested")
    colour = tuple(colour_grid.tolist()) if colour_grid.size else None
    return Plan(request, tuple(model_grid.tolist()), spectral_index, colour_index, colour, error, radii, tuple(notes))


@dataclasses.dataclass(frozen=True)
class Result:
    """What ``evaluate`` computed; fields that were not requested are None.

    Attributes:
        reflectance: (..., n_wavelengths) diffuse reflectance at the requested wavelengths.
        rgb: (..., 3) linear sRGB.
        radii_mm: (n_radii,) profile radii.
        profiles: (..., n_wavelengths, n_radii) spectral profiles in mm^-2 (requested wavelengths).
        rgb_profiles: (..., 3, n_radii) linear-sRGB profiles in mm^-2.
        derivatives: {name: {"reflectance": ..., "rgb": ...}} per parameter, same shapes.
    """

    reflectance: jax.Array | None = None
    rgb: jax.Array | None = None
    radii_mm: np.ndarray | None = None
    profiles: jax.Array | None = None
    rgb_profiles: jax.Array | None = None
    derivatives: dict | None = None


def evaluate(plan: Plan, params: SkinParams, *, model: SkinModel | None = None, scattering_scale=1.0, **model_options) -> Result:
    """Run ``plan`` for ``params`` (any batch shape); ``model`` and its overrides (``model_options``:
    adding, blood_oxygenation, epidermis_thickness_mm, ior) as in ``diffuse_reflectance``.

    The plan compiles to one program (cached per plan; the model's constants are traced): a
    reflectance-only plan is a single dispatch of the q = 0 model.
    """
    if not isinstance(params, SkinParams):
        raise SkinfitInputError("params must be skinfit.SkinParams")
    model = model_with_options(model, **model_options)
    check_range("scattering_scale", scattering_scale, 1e-3, 1e3)
    dtype = jnp.result_type(params.melanin, params.melanin_blend, params.haemoglobin)
    outputs = _program(plan)(params, model, jnp.asarray(scattering_scale, dtype))
    radii = None if plan.radii_mm is None else np.asarray(plan.radii_mm)
    return Result(outputs.get("reflectance"), outputs.get("rgb"), radii, outputs.get("profiles"), outputs.get("rgb_profiles"),
                  outputs.get("derivatives"))


@eager_cache(maxsize=32)
def _program(plan: Plan):
    """The plan as one jitted function of (params, model, scattering_scale) -> dict of outputs."""
    request = plan.request
    lam_host = np.asarray(plan.model_wavelengths_nm)
    spectral = None if plan.spectral_index is None else np.asarray(plan.spectral_index)
    colour_index = None if plan.colour_index is None else np.asarray(plan.colour_index)
    colour = None if colour_index is None else np.asarray(linear_srgb_weights(plan.colour_wavelengths_nm, request.illuminant))
    kernel = None if plan.radii_mm is None else inverse_kernel(np.asarray(plan.radii_mm), HankelQuadrature())

    def values(params, model, scale):
        lam = jnp.asarray(lam_host, scale.dtype)
        r = skin_reflectance(params, lam, model, scale)
        out = {}
        if spectral is not None:
            out["reflectance"] = r[..., spectral]
        if colour is not None:
            out["rgb"] = r[..., colour_index] @ jnp.asarray(colour, r.dtype).T
        return out

    @eqx.filter_jit
    def run(params, model, scale):
        out = values(params, model, scale)
        if request.derivatives:
            out["derivatives"] = {
                name: jax.jvp(lambda p: values(p, model, scale), (params,), (_unit_tangent(params, name),))[1] for name in DERIVATIVE_NAMES
            }
        if kernel is not None:
            lam = jnp.asarray(lam_host, scale.dtype)
            radii = np.asarray(plan.radii_mm)
            profiles = skin_profile(params, lam, radii, *kernel, model, True, scale)
            if spectral is not None:
                out["profiles"] = profiles[..., spectral, :]
            if colour is not None:
                out["rgb_profiles"] = jnp.einsum("cw,...wr->...cr", jnp.asarray(colour, profiles.dtype), profiles[..., colour_index, :])
        return out

    return run


def _unit_tangent(params: SkinParams, name: str) -> SkinParams:
    """Tangent 1 on field ``name``, 0 elsewhere: a jvp with it is d(output)/d(name) per element."""
    zeros = jax.tree_util.tree_map(jnp.zeros_like, params)
    return eqx.tree_at(lambda p: getattr(p, name), zeros, jnp.ones_like(getattr(params, name)))


def rgb_wavelengths(illuminant: str = DEFAULT_ILLUMINANT, tolerance: float = 0.1) -> tuple[tuple[float, ...], float]:
    """The fewest wavelengths (a uniform grid) whose colour stays within ``tolerance`` CIEDE2000 of
    the 1 nm integral (360-830 nm) for every parameter set of ``probe_params``; and that error.

    Candidates: every grid start in ``RGB_STARTS_NM``, end in ``RGB_ENDS_NM`` and step in
    ``RGB_STEPS_NM`` (colour integration holds a spectrum constant beyond its ends). The model is
    evaluated once on the 1 nm grid; every candidate samples it.
    """
    return _rgb_wavelengths(str(illuminant), float(tolerance))


@eager_cache(maxsize=16)
def _rgb_wavelengths(illuminant, tolerance):
    fine = np.arange(360.0, 831.0, 1.0)
    spectra = np.asarray(diffuse_reflectance(probe_params(), jnp.asarray(fine)))

    def colours(grid):  # in NumPy: every candidate's colours then have one shape, (n_probe, 3)
        return spectra[:, np.searchsorted(fine, grid)] @ np.asarray(linear_srgb_weights(grid, illuminant)).T

    reference = colours(fine)
    candidates = sorted(
        (np.arange(start, end + 0.5 * step, step) for start in RGB_STARTS_NM for end in RGB_ENDS_NM for step in RGB_STEPS_NM
         if (end - start) % step == 0),
        key=len,
    )
    for grid in candidates:
        error = float(_worst_colour_error(reference, colours(grid)))
        if error <= tolerance:
            return tuple(grid.tolist()), error
    return tuple(fine.tolist()), 0.0


@jax.jit
def _worst_colour_error(reference_linear, linear):
    """Largest CIEDE2000 between two sets of linear sRGB colours (compiled once: the candidates'
    colours share a shape, and op-by-op evaluation of each would cost ~5 ms per candidate)."""
    return jnp.max(delta_e2000(linear_srgb_to_lab(reference_linear), linear_srgb_to_lab(linear)))


def probe_params() -> SkinParams:
    """Parameter sets the planner's colour error is measured on: a 6 x 3 x 6 grid over melanin
    0.001-0.5 (log), blend 0-1 and haemoglobin 0.001-0.3 (log), plus the three presets."""
    c_m, beta, c_h = np.meshgrid(np.geomspace(1e-3, 0.5, 6), [0.0, 0.5, 1.0], np.geomspace(1e-3, 0.3, 6), indexing="ij")
    presets = [preset(name) for name in PRESET_NAMES]
    field = lambda grid, name: np.concatenate([grid.ravel(), [float(getattr(p, name)) for p in presets]])  # noqa: E731
    return SkinParams(field(c_m, "melanin"), field(beta, "melanin_blend"), field(c_h, "haemoglobin"))


def _energy_within(params: SkinParams, wavelengths, radius_mm: float, model: SkinModel) -> float:
    """Smallest fraction (over parameters and wavelengths) of the profile energy within ``radius_mm``."""
    lam = jnp.asarray(wavelengths)
    total = diffuse_reflectance(params, lam, model=model)
    inside = captured_reflectance(params, lam, radius_mm, model=model, quadrature=HankelQuadrature())
    return float(jnp.min(inside / jnp.maximum(total, jnp.finfo(total.dtype).tiny)))
