"""Homogeneous media that a renderer's exact transport turns into the model's colour and scale.

A renderer that path-traces a medium behind a smooth dielectric boundary (Mitsuba 3's volumetric
path tracer; pbrt-v4's subsurface material, whose photon-beam-diffusion table is built to
approach it; Blender Cycles' random walk) solves the radiative transfer equation exactly. A
medium matched to a colour through diffusion theory then renders too dark: diffusion
overestimates the reflectance of absorbing media (by up to 35 % for the dark preset's channels).
Here each channel's medium is matched with exact transport instead:

- **Colour.** A semi-infinite homogeneous medium of index n under air, with Henyey-Greenstein
  phase function g, has a diffuse reflectance (normal incidence, specular excluded, entry
  Fresnel included: the convention of every reflectance in skinfit) that depends on its
  single-scattering albedo a = sigma_s / sigma_t alone. R(a) is computed by the adding-doubling
  of ``skinfit.model`` (32 streams) on 321 nodes uniform in logit(a) over a in
  [1e-3, 1 - 1e-6], and inverted by a cubic spline of logit(a) over logit(R / R_max),
  R_max = 1 - F0 (within 1e-9 of the direct adding-doubling between the nodes, tested). That
  covers diffuse albedos from 6e-5 to 0.87 at n 1.4; skin lies inside.
- **Scale.** The same medium's radial profile scales with sigma_t exactly, R(r) = sigma_t^2
  f_a(sigma_t r), so its median energy radius is c(a) / sigma_t. c(a), in mean free paths, is
  measured by the radially resolved Monte Carlo (``skinfit.model.monte_carlo_reflectance``) at 20
  albedos, 1 - a in [5e-4, 0.99] (1,000,000 photons each: a standard error of 0.1-0.9 % in c,
  median 0.23 %, largest where absorption dominates), interpolated monotonically in log c over
  log(1 - a); against fresh Monte Carlo runs between the nodes it is within 0.4 % (1.2 standard
  errors; ``benchmarks/results/medium_table.json``). sigma_t = c(a) / r50 then gives the medium
  the model's median energy radius r50.

The tables depend on (n, g) only: ``medium_table`` returns the shipped one for the default
conventions (n 1.4, g 0: ``skinfit.spectra``, built by ``python -m benchmarks.build_medium_table``
in 7 minutes on 2 cores) and builds and caches others (as long, mostly the Monte Carlo).

The conventions assumed are stated with every export: radii and mean free paths in mm,
coefficients in mm^-1 (a scene in metres multiplies them by 1000), index n of the medium and of
its smooth boundary, air (index 1) outside, isotropic scattering unless g is given, the slab deep
enough to be semi-infinite (more than ~20 mean free paths of its reddest channel's diffusion
length), and the renderer's own specular reflection on top (F0 = ((n - 1) / (n + 1))^2, 0.0278
at n 1.4, which the model's diffuse albedo excludes).
"""

from __future__ import annotations

import dataclasses
import functools
import importlib.resources
import json
import os
import uuid
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.interpolate

from .._caching import eager_cache, eager_cached_property
from .._compilation_cache import cache_root
from .._validate import SkinfitInputError
from ..model import (
    SKIN_IOR,
    Layer,
    monte_carlo_reflectance,
    normal_fresnel_reflectance,
    stack_reflectance_transport,
)

#: Streams of the adding-doubling behind R(a): 16 streams err by 7e-4 at a = 0.5 against 32.
MEDIUM_STREAMS = 32
#: Single-scattering albedos of the colour curve: uniform in logit(a) over [1e-3, 1 - 1e-6].
_CURVE_LOGIT = np.linspace(np.log(1e-3 / (1 - 1e-3)), np.log((1 - 1e-6) / 1e-6), 321)
#: 1 - a at the Monte Carlo nodes of the median radius.
_MEDIAN_ABSORPTION = np.geomspace(5e-4, 0.99, 20)
MEDIAN_PHOTONS = 1_000_000
#: Radii (in mean free paths) at which the Monte Carlo tallies the energy within.
_TALLY_RADII = np.geomspace(1e-4, 1e4, 1601)
_FORMAT = 1


class RendererConventions(eqx.Module):
    """How the renderer treats the exported medium (see the module docstring).

    Attributes:
        ior: refractive index of the medium and of its smooth dielectric boundary (skin: 1.4).
        anisotropy: Henyey-Greenstein g of the renderer's phase function (0: isotropic, the
            cheapest to path-trace; sigma_s = sigma_s' / (1 - g) otherwise).
    """

    ior: float = eqx.field(static=True, default=SKIN_IOR)
    anisotropy: float = eqx.field(static=True, default=0.0)

    def __check_init__(self):
        if not 1.0 < float(self.ior) < 3.0:
            raise SkinfitInputError(f"renderer ior must be in (1, 3), got {self.ior}")
        if not -0.95 < float(self.anisotropy) < 0.95:
            raise SkinfitInputError(f"renderer anisotropy g must be in (-0.95, 0.95), got {self.anisotropy}")

    @property
    def specular(self) -> float:
        """Normal-incidence reflectance F0 of the boundary, which the renderer adds on top."""
        return float(normal_fresnel_reflectance(self.ior))

    def describe(self) -> dict:
        return {
            "boundary": f"smooth dielectric, index {self.ior:g} inside, 1 (air) outside",
            "phase_function": "isotropic" if self.anisotropy == 0 else f"Henyey-Greenstein g {self.anisotropy:g}",
            "units": "coefficients in mm^-1, lengths in mm (multiply coefficients by 1000 for a scene in metres)",
            "geometry": "semi-infinite homogeneous medium (a slab deeper than ~20 diffusion lengths of its reddest channel)",
            "albedo": "diffuse reflectance at normal incidence, specular excluded, entry Fresnel included; "
                      f"the renderer adds the boundary's specular F0 = {self.specular:.4f}",
            "matched_by": "exact transport (adding-doubling for the colour, Monte Carlo for the median energy radius)",
        }


DEFAULT_CONVENTIONS = RendererConventions()


@dataclasses.dataclass(frozen=True)
class MediumTable:
    """R(a) and the median radius c(a) of the semi-infinite medium of one set of conventions.

    Attributes:
        conventions: the (n, g) they hold.
        albedo_logit: (k,) logit(a) of the colour curve's nodes.
        reflectance: (k,) R(a) there, by adding-doubling.
        median_absorption: (m,) 1 - a of the Monte Carlo nodes.
        median_radius: (m,) c(a): median energy radius in mean free paths (1 / sigma_t).
        median_error: (m,) its relative standard error (Monte Carlo).
        photons: photons per Monte Carlo node.
    """

    conventions: RendererConventions
    albedo_logit: np.ndarray
    reflectance: np.ndarray
    median_absorption: np.ndarray
    median_radius: np.ndarray
    median_error: np.ndarray
    photons: int

    @property
    def max_reflectance(self) -> float:
        return 1.0 - self.conventions.specular

    @eager_cached_property
    def _albedo_of_reflectance(self):
        r = self.reflectance / self.max_reflectance
        return scipy.interpolate.CubicSpline(np.log(r / (1.0 - r)), self.albedo_logit)

    @eager_cached_property
    def _median(self):
        return scipy.interpolate.PchipInterpolator(np.log(self.median_absorption), np.log(self.median_radius))

    @eager_cached_property
    def reflectance_range(self) -> tuple[float, float]:
        """The diffuse reflectances the table inverts: the colour curve's lowest, and the one at
        the Monte Carlo's most weakly absorbing node (where the median radius ends)."""
        r = self.reflectance / self.max_reflectance
        forward = scipy.interpolate.CubicSpline(self.albedo_logit, np.log(r / (1.0 - r)))
        q = self.median_absorption[0]
        y = float(forward(np.log((1.0 - q) / q)))
        return float(self.reflectance[0]), self.max_reflectance / (1.0 + np.exp(-y))

    def single_scattering_albedo(self, reflectance) -> np.ndarray:
        """a with R(a) = ``reflectance`` (any shape; within ``reflectance_range``)."""
        r = np.asarray(reflectance, dtype=float)
        low, high = self.reflectance_range
        if np.any(~np.isfinite(r)) or np.any(r < low) or np.any(r > high):
            raise SkinfitInputError(f"a channel's albedo is outside what a homogeneous medium renders here "
                                    f"({low:.2g} to {high:.3g} at index {self.conventions.ior:g}, g {self.conventions.anisotropy:g}); "
                                    f"got {np.min(r):.4g} to {np.max(r):.4g}")
        x = r / self.max_reflectance
        return 1.0 / (1.0 + np.exp(-self._albedo_of_reflectance(np.log(x / (1.0 - x)))))

    def unit_median_radius(self, albedo) -> np.ndarray:
        """c(a): the median energy radius in mean free paths (constant beyond the strongly
        absorbing node, where single scattering sets it)."""
        one_minus = np.clip(1.0 - np.asarray(albedo, dtype=float), self.median_absorption[0], self.median_absorption[-1])
        return np.exp(self._median(np.log(one_minus)))


@functools.partial(jax.jit, static_argnames=("ior", "anisotropy"))
def _reflectance(albedo, *, ior: float, anisotropy: float):
    def one(a):
        return stack_reflectance_transport(jnp.atleast_1d(1.0 - a), jnp.atleast_1d(a * (1.0 - anisotropy)), jnp.array([jnp.inf]),
                                           jnp.atleast_1d(anisotropy), ior=ior, ior_above=1.0, semi_infinite=True, streams=MEDIUM_STREAMS)

    return jax.vmap(one)(albedo)


def semi_infinite_reflectance(albedo, conventions: RendererConventions = DEFAULT_CONVENTIONS) -> np.ndarray:
    """Diffuse reflectance of the semi-infinite medium of single-scattering albedo ``albedo``
    (any shape) under ``conventions``, by adding-doubling (the reference of the tables)."""
    a = np.asarray(albedo, dtype=float)
    flat = jnp.asarray(a.reshape(-1), dtype=jnp.float64)
    return np.asarray(_reflectance(flat, ior=float(conventions.ior), anisotropy=float(conventions.anisotropy))).reshape(a.shape)


def unit_medium_layer(albedo: float, conventions: RendererConventions = DEFAULT_CONVENTIONS) -> Layer:
    """The semi-infinite ``Layer`` with sigma_t = 1 mm^-1 and single-scattering albedo ``albedo``."""
    g = float(conventions.anisotropy)
    return Layer(absorption=1.0 - albedo, reduced_scattering=albedo * (1.0 - g), thickness=float("inf"), ior=conventions.ior, anisotropy=g)


def median_of_unit_medium(albedo: float, conventions: RendererConventions = DEFAULT_CONVENTIONS, *, photons: int = MEDIAN_PHOTONS,
                          seed: int = 0) -> tuple[float, float]:
    """(c, relative standard error): the Monte Carlo median energy radius of the unit medium."""
    mc = monte_carlo_reflectance([unit_medium_layer(albedo, conventions)], photons=photons, seed=seed, radii_mm=_TALLY_RADII)
    fraction = np.maximum.accumulate(mc.reflectance_within / mc.reflectance)
    c = float(np.exp(np.interp(0.5, fraction, np.log(_TALLY_RADII))))
    k = int(np.clip(np.searchsorted(_TALLY_RADII, c), 1, _TALLY_RADII.size - 1))
    slope = (fraction[k] - fraction[k - 1]) / (np.log(_TALLY_RADII[k]) - np.log(_TALLY_RADII[k - 1]))  # d fraction / d ln r
    error = float(mc.reflectance_within_error[k] / mc.reflectance / max(slope, 1e-12))
    return c, error


def _median_node(args):
    albedo, ior, anisotropy, photons, seed = args
    return median_of_unit_medium(albedo, RendererConventions(ior, anisotropy), photons=photons, seed=seed)


def build_medium_table(conventions: RendererConventions = DEFAULT_CONVENTIONS, *, photons: int = MEDIAN_PHOTONS,
                       processes: int | None = None, progress: bool = True) -> MediumTable:
    """Build the tables of ``conventions``: the adding-doubling curve (seconds) and the Monte
    Carlo medians (minutes; ``processes`` workers, default the CPU count)."""
    albedo = 1.0 / (1.0 + np.exp(-_CURVE_LOGIT))
    reflectance = semi_infinite_reflectance(albedo, conventions)
    jobs = [(1.0 - float(q), float(conventions.ior), float(conventions.anisotropy), photons, k) for k, q in enumerate(_MEDIAN_ABSORPTION)]
    workers = processes or min(os.cpu_count() or 1, len(jobs))
    if progress:
        print(f"skinfit: building the renderer medium table for n {conventions.ior:g}, g {conventions.anisotropy:g} "
              f"({len(jobs)} Monte Carlo nodes x {photons} photons; minutes)", flush=True)
    if workers > 1:
        import concurrent.futures
        import multiprocessing

        with concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            medians = list(pool.map(_median_node, jobs[::-1]))[::-1]  # the slow, weakly absorbing nodes first
    else:
        medians = [_median_node(job) for job in jobs]
    c, error = (np.array(v) for v in zip(*medians))
    return MediumTable(conventions, _CURVE_LOGIT.copy(), reflectance, _MEDIAN_ABSORPTION.copy(), c, error, int(photons))


def save_medium_table(table: MediumTable, path) -> Path:
    """Write ``table`` as JSON (atomically)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    content = {
        "format": _FORMAT,
        "ior": table.conventions.ior, "anisotropy": table.conventions.anisotropy,
        "streams": MEDIUM_STREAMS, "photons": table.photons,
        "albedo_logit": table.albedo_logit.tolist(), "reflectance": table.reflectance.tolist(),
        "median_absorption": table.median_absorption.tolist(), "median_radius_mfp": table.median_radius.tolist(),
        "median_relative_error": table.median_error.tolist(),
        "what": "semi-infinite homogeneous medium under air behind a smooth dielectric boundary: diffuse reflectance R(a) "
                "by adding-doubling and median energy radius c(a) in mean free paths by Monte Carlo (skinfit.export)",
    }
    temporary = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex}.tmp")
    try:
        temporary.write_text(json.dumps(content, indent=0), encoding="utf-8")
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return path


def load_medium_table(text: str) -> MediumTable:
    data = json.loads(text)
    if data.get("format") != _FORMAT:
        raise ValueError(f"medium table format {data.get('format')}, expected {_FORMAT}")
    return MediumTable(RendererConventions(float(data["ior"]), float(data["anisotropy"])), np.array(data["albedo_logit"]),
                       np.array(data["reflectance"]), np.array(data["median_absorption"]), np.array(data["median_radius_mfp"]),
                       np.array(data["median_relative_error"]), int(data["photons"]))


def _file_name(conventions: RendererConventions) -> str:
    return f"renderer_medium_n{conventions.ior:.3f}_g{conventions.anisotropy:.2f}.json"


def _cache_dir() -> Path:
    return cache_root() / "media"


@eager_cache()
def medium_table(conventions: RendererConventions = DEFAULT_CONVENTIONS, *, progress: bool = True) -> MediumTable:
    """The tables of ``conventions``: shipped (n 1.4, g 0), cached (``$SKINFIT_CACHE_DIR/media`` or
    ~/.cache/skinfit/media) or built now and cached."""
    name = _file_name(conventions)
    shipped = importlib.resources.files("skinfit.spectra").joinpath(name)
    if shipped.is_file():
        return load_medium_table(shipped.read_text(encoding="utf-8"))
    path = _cache_dir() / name
    if path.exists():
        try:
            table = load_medium_table(path.read_text(encoding="utf-8"))
            if table.conventions == conventions and table.photons >= MEDIAN_PHOTONS:
                return table
        except (OSError, ValueError, KeyError):
            pass  # unreadable or stale: rebuild over it
    table = build_medium_table(conventions, progress=progress)
    save_medium_table(table, path)
    return table


@dataclasses.dataclass(frozen=True)
class RendererMedium:
    """Per channel (or wavelength), the homogeneous medium a renderer with exact transport renders
    with the target diffuse albedo and median energy radius (arrays of one shape).

    Attributes:
        conventions: the renderer conventions it was matched under.
        albedo: the target diffuse reflectance (specular excluded).
        median_radius_mm: the target median energy radius.
        single_scattering_albedo: a = sigma_s / sigma_t.
        extinction_per_mm, absorption_per_mm, scattering_per_mm: sigma_t, sigma_a, sigma_s (the
            phase function's, not reduced).
        reduced_scattering_per_mm: sigma_s (1 - g).
        mean_free_path_mm: 1 / sigma_t.
    """

    conventions: RendererConventions
    albedo: np.ndarray
    median_radius_mm: np.ndarray
    single_scattering_albedo: np.ndarray
    extinction_per_mm: np.ndarray

    @property
    def absorption_per_mm(self) -> np.ndarray:
        return (1.0 - self.single_scattering_albedo) * self.extinction_per_mm

    @property
    def scattering_per_mm(self) -> np.ndarray:
        return self.single_scattering_albedo * self.extinction_per_mm

    @property
    def reduced_scattering_per_mm(self) -> np.ndarray:
        return self.scattering_per_mm * (1.0 - self.conventions.anisotropy)

    @property
    def mean_free_path_mm(self) -> np.ndarray:
        return 1.0 / self.extinction_per_mm

    def to_dict(self) -> dict:
        """Lists per channel, and the conventions (for JSON exports)."""
        fields = ("albedo", "median_radius_mm", "single_scattering_albedo", "extinction_per_mm", "absorption_per_mm",
                  "scattering_per_mm", "reduced_scattering_per_mm", "mean_free_path_mm")
        return {**{f: np.asarray(getattr(self, f)).tolist() for f in fields},
                "anisotropy": self.conventions.anisotropy, "ior": self.conventions.ior, "conventions": self.conventions.describe()}


def transport_medium(albedo, median_radius_mm, conventions: RendererConventions = DEFAULT_CONVENTIONS) -> RendererMedium:
    """The media (one per element of ``albedo``, e.g. per RGB channel, per wavelength or per
    texel) whose exact transport under ``conventions`` gives diffuse reflectance ``albedo`` and
    median energy radius ``median_radius_mm`` (same shape, mm)."""
    albedo = np.asarray(albedo, dtype=float)
    median = np.broadcast_to(np.asarray(median_radius_mm, dtype=float), albedo.shape)
    if np.any(~np.isfinite(median)) or np.any(median <= 0):
        raise SkinfitInputError("median radii must be finite and > 0 mm")
    table = medium_table(conventions)
    a = table.single_scattering_albedo(albedo)
    extinction = table.unit_median_radius(a) / median
    return RendererMedium(conventions, albedo, np.array(median), a, extinction)
