"""Run time against error: the settings that trade one for the other, swept, with Pareto plots.

A point is on the Pareto front when no other point of its sweep is at least as good in both time
and error and clearly better in one; "clearly" means beyond 10 % in time and a factor 2 in error,
so that timing noise on a shared machine does not decide, and errors below a floor that nobody
can see or measure (``ERROR_FLOORS``) count as equal (``dominates``).

Every point is timed after compilation (median of ``repeats`` runs; the compile-and-first-run time
is reported apart) and its error is measured against a high-accuracy reference computed in the
same run. A plain NumPy/SciPy implementation of the same job (what users write today) is timed in
the same run, and each point carries its speed ratio against it.

Sweeps:
- ``profile_quadrature``: Hankel quadrature order and panel phase, float32 against float64;
  ``profile_radii``: radii count (error of log-r interpolation); ``profile_wavelengths``:
  wavelength count (error of the RGB profile); reference: a refined quadrature (q up to
  1000 mm^-1, 32 nodes per panel); baseline: the 2-D FFT recipe (N 2048, dx 0.02 mm) per profile.
- ``colour``: wavelength sampling of reflectance spectra (1, 5, 10, 20 nm over 380-780 nm) and the
  planner's RGB-only grids, against the CIEDE2000 of the 1 nm (360-830 nm) colour; baseline: a
  NumPy loop over spectra at 5 nm.
- ``spectral_fit``: solver settings (step tolerance, refinement steps, starts, warm-start table),
  error against the true parameters of noise-free spectra; baseline: SciPy least_squares.
- ``image_fit``: table only against polish, steps, straggler rounds, spline and inverse-table
  resolution, exact polish; error against the true maps of the round-trip image; baseline: SciPy
  least_squares per pixel.
- ``planner``: reflectance only against reflectance plus profiles for the same parameters.
"""

from __future__ import annotations

import csv
import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize

import skinfit
from skinfit.colorimetry import delta_e2000, linear_srgb_to_lab, linear_srgb_weights
from skinfit.fit import SolverSettings
from skinfit.model import HankelQuadrature
from skinfit.planning import plan, rgb_wavelengths

#: These timings compare skinfit with NumPy/SciPy ports of Donner & Jensen 2006's diffusion model, so
#: they evaluate that model (the calibrated default is re-measured by benchmarks.fit_measured).
MODEL = skinfit.SkinModel.dj2006()

REFERENCE_QUADRATURE = HankelQuadrature(q_max=1000.0, nodes_per_panel=32, phase_per_panel=5.0, max_panel_width=1.0)


@dataclasses.dataclass
class Point:
    sweep: str
    setting: str
    time_s: float
    compile_s: float
    error: float
    error_unit: str
    default: bool = False
    baseline_s: float = float("nan")
    note: str = ""

    @property
    def speedup_vs_baseline(self) -> float:
        return self.baseline_s / self.time_s


def measure(function: Callable[[], object], repeats: int = 3) -> tuple[object, float, float]:
    """(result, median seconds after compilation, seconds of the first call including compilation)."""
    start = time.perf_counter()
    jax.block_until_ready(function())
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = jax.block_until_ready(function())
        times.append(time.perf_counter() - start)
    return out, float(np.median(times)), first


def _presets() -> skinfit.SkinParams:
    params = [skinfit.preset(name) for name in skinfit.PRESET_NAMES]
    return skinfit.SkinParams(*(np.array([float(getattr(p, f)) for p in params]) for f in ("melanin", "melanin_blend", "haemoglobin")))


def _peak_error(values, reference) -> float:
    """Largest |error| relative to each profile's peak."""
    values, reference = np.asarray(values, float), np.asarray(reference, float)
    return float(np.max(np.abs(values - reference) / np.max(np.abs(reference), axis=-1, keepdims=True)))


def profile_sweep(repeats: int) -> list[Point]:
    params = _presets()
    wl = np.arange(400.0, 701.0, 10.0)
    radii = np.geomspace(1e-3, 20.0, 256)
    count = len(skinfit.PRESET_NAMES) * wl.size

    # baseline: the 2-D FFT recipe per profile (N 2048, dx 0.02 mm), two profiles timed
    layers = skinfit.model.skin_layers(skinfit.preset("light"), wl[:2], model=MODEL)
    freq = 2 * np.pi * np.fft.fftfreq(2048, 0.02)
    qgrid = np.sqrt(freq[:, None] ** 2 + freq[None, :] ** 2)
    transfer = jax.jit(lambda q: skinfit.model.stack_transfer([jax.tree_util.tree_map(lambda a: a[..., None, None], layer) for layer in layers], q))
    transfer(qgrid)
    start = time.perf_counter()
    for grid in np.asarray(transfer(qgrid)):
        np.real(np.fft.ifft2(grid))
    baseline = (time.perf_counter() - start) / 2 * count

    reference = np.asarray(skinfit.profile(params, wl, radii, quadrature=REFERENCE_QUADRATURE, model=MODEL))
    points = []
    settings = [("16 nodes/panel, phase 20 (default)", HankelQuadrature(), jnp.float64, True)]
    settings += [(f"{n} nodes/panel, phase 20", HankelQuadrature(nodes_per_panel=n), jnp.float64, False) for n in (4, 8, 12, 24)]
    settings += [(f"16 nodes/panel, phase {p:g}", HankelQuadrature(phase_per_panel=p), jnp.float64, False) for p in (80.0, 40.0, 10.0)]
    settings += [("16 nodes/panel, phase 20, float32", HankelQuadrature(), jnp.float32, False)]
    for label, quadrature, dtype, default in settings:
        typed = jax.tree_util.tree_map(lambda a: jnp.asarray(a, dtype), params)
        lam = jnp.asarray(wl, dtype)
        values, seconds, first = measure(lambda: skinfit.profile(typed, lam, radii, quadrature=quadrature, model=MODEL), repeats)
        points.append(Point("profile_quadrature", label, seconds, first, _peak_error(values, reference),
                            "max |R - R_ref| / peak", default, baseline))

    fine_radii = np.geomspace(1e-3, 20.0, 1024)
    fine = np.asarray(skinfit.profile(params, wl, fine_radii, quadrature=REFERENCE_QUADRATURE, model=MODEL))
    for n in (32, 64, 128, 256):
        coarse_radii = np.geomspace(1e-3, 20.0, n)
        values, seconds, first = measure(lambda: skinfit.profile(params, wl, coarse_radii, model=MODEL), repeats)
        interpolated = np.apply_along_axis(lambda row: np.interp(np.log(fine_radii), np.log(coarse_radii), row), -1, np.asarray(values))
        points.append(Point("profile_radii", f"{n} log-spaced radii, 1e-3-20 mm", seconds, first, _peak_error(interpolated, fine),
                            "max |R - R_ref| / peak (log-r interpolation)", n == 256, baseline))

    colour_reference_wl = np.arange(380.0, 781.0, 2.0)
    rgb_reference = np.einsum("cw,pwr->pcr", linear_srgb_weights(colour_reference_wl),
                              np.asarray(skinfit.profile(params, colour_reference_wl, radii, model=MODEL)))
    for step in (50.0, 20.0, 10.0, 5.0):
        grid = np.arange(400.0, 701.0, step)
        weights = jnp.asarray(linear_srgb_weights(grid))
        values, seconds, first = measure(lambda: jnp.einsum("cw,pwr->pcr", weights, skinfit.profile(params, grid, radii, model=MODEL)), repeats)
        points.append(Point("profile_wavelengths", f"{grid.size} wavelengths ({step:g} nm, 400-700)", seconds, first,
                            _peak_error(values, rgb_reference), "max |RGB - RGB_ref| / peak", step == 10.0,
                            baseline * grid.size / wl.size))
    return points


def colour_sweep(repeats: int) -> list[Point]:
    from benchmarks.forward_model import chromophore_table, numpy_reflectance

    rng = np.random.default_rng(4)
    n = 16384  # enough work that dispatch overhead does not decide the timing
    repeats = max(repeats, 7)
    params = skinfit.SkinParams(10 ** rng.uniform(-3, np.log10(0.5), n), rng.uniform(0, 1, n), 10 ** rng.uniform(-3, -1, n))
    fine = np.arange(360.0, 831.0, 1.0)
    reference = linear_srgb_to_lab(skinfit.diffuse_reflectance(params, fine, model=MODEL) @ jnp.asarray(linear_srgb_weights(fine)).T)

    grid5 = np.arange(380.0, 781.0, 5.0)
    table = chromophore_table(grid5)
    c_m, beta, c_h = (np.asarray(v) for v in (params.melanin, params.melanin_blend, params.haemoglobin))
    start = time.perf_counter()
    for i in range(256):
        numpy_reflectance(c_m[i], beta[i], c_h[i], table)
    baseline_5nm = (time.perf_counter() - start) / 256 * n

    settings = [(f"spectra every {s:g} nm (380-780)", np.arange(380.0, 781.0, s), False) for s in (1.0, 5.0, 10.0, 20.0)]
    for tolerance in (0.3, 0.1, 0.03):
        grid = np.asarray(rgb_wavelengths("D65", tolerance)[0])
        settings.append((f"RGB only, planner tolerance {tolerance:g} ({grid.size} wavelengths)", grid, tolerance == 0.1))
    points = []
    for label, grid, default in settings:
        weights = jnp.asarray(linear_srgb_weights(grid))
        lam = jnp.asarray(grid)
        rgb_of = jax.jit(lambda p: skinfit.diffuse_reflectance(p, lam, model=MODEL) @ weights.T)
        rgb, seconds, first = measure(lambda: rgb_of(params), repeats)
        error = float(jnp.max(delta_e2000(reference, linear_srgb_to_lab(rgb))))
        points.append(Point("colour", label, seconds, first, error, "max CIEDE2000 vs 1 nm", default,
                            baseline_5nm * grid.size / grid5.size, f"{n} spectra"))
    return points


def spectral_fit_sweep(repeats: int) -> list[Point]:
    from benchmarks.fit_spectra import box_spectra
    from benchmarks.forward_model import chromophore_table, numpy_reflectance

    wl, truth, spectra = box_spectra(1000, np.random.default_rng(7))
    table = chromophore_table(wl)
    start = time.perf_counter()
    for i in range(20):
        scipy.optimize.least_squares(lambda x: numpy_reflectance(x[0], x[1], x[2], table) - spectra[i], x0=[0.05, 0.5, 0.02],
                                     bounds=([0, 0, 0], [1, 1, 1]), xtol=1e-12, ftol=1e-12, gtol=1e-12)
    baseline = (time.perf_counter() - start) / 20 * len(spectra)

    settings = [
        ("default", SolverSettings(), True),
        ("step_tol 1e-4", SolverSettings(step_tol=1e-4), False),
        ("step_tol 1e-10", SolverSettings(step_tol=1e-10), False),
        ("refine_steps 0, continue_steps 0", SolverSettings(refine_steps=0, continue_steps=0), False),
        ("refine_steps 6", SolverSettings(refine_steps=6), False),
        ("candidates 1", SolverSettings(candidates=1), False),
        ("candidates 4", SolverSettings(candidates=4), False),
        ("warm-start table 12x5x12", SolverSettings(table_shape=(12, 5, 12)), False),
        ("warm-start table 48x17x48", SolverSettings(table_shape=(48, 17, 48)), False),
    ]
    points = []
    for label, settings_, default in settings:
        fit, seconds, first = measure(lambda: skinfit.fit_spectra(wl, spectra, model=MODEL, settings=settings_, progress=False), repeats)
        error = np.max(np.abs(np.column_stack([fit.parameters[k] for k in ("melanin", "melanin_blend", "haemoglobin")]) - truth), axis=1)
        points.append(Point("spectral_fit", label, seconds, first, float(np.percentile(error, 99)),
                            "p99 of max |parameter error|", default, baseline, f"{len(spectra)} spectra, 31 wavelengths"))
    return points


def image_fit_sweep(repeats: int, size: int = 256) -> list[Point]:
    from benchmarks.fit_image import smooth_maps
    from benchmarks.forward_model import chromophore_table, numpy_reflectance
    from skinfit.colorimetry import COLOUR_WAVELENGTHS_NM, colour_table

    melanin, haemoglobin, shading = smooth_maps(size)
    pixels = skinfit.render_maps(melanin, haemoglobin, shading, model=MODEL).reshape(-1, 3)
    truth = np.column_stack([melanin.ravel(), haemoglobin.ravel()])

    table = chromophore_table(COLOUR_WAVELENGTHS_NM)
    weights = linear_srgb_weights(COLOUR_WAVELENGTHS_NM)
    start = time.perf_counter()
    for i in range(0, len(pixels), len(pixels) // 40)[:40]:
        scipy.optimize.least_squares(lambda x: x[2] * (weights @ numpy_reflectance(x[0], 0.7, x[1], table)) - pixels[i],
                                     x0=[0.05, 0.02, 1.0], bounds=([0, 0, 0], [0.5, 0.15, np.inf]), xtol=1e-12, ftol=1e-12, gtol=1e-12)
    baseline = (time.perf_counter() - start) / 40 * len(pixels)

    settings = [
        ("table only (no iteration)", dict(steps=0, max_straggler_rounds=0, lm_max_steps=0), False),
        ("default (1 step + stragglers)", {}, True),
        ("2 steps + stragglers", dict(steps=2), False),
        ("1 step, no straggler rounds", dict(max_straggler_rounds=0), False),
        ("inverse table 128x128", dict(table=colour_table(0.7, inverse_cells=128, model=MODEL)), False),
        ("inverse table 256x256", dict(table=colour_table(0.7, inverse_cells=256, model=MODEL)), False),
        ("spline 65x65 nodes", dict(table=colour_table(0.7, nodes=65, model=MODEL)), False),
        ("+ exact polish (2 Gauss-Newton steps)", dict(exact_steps=2), False),
    ]
    points = []
    for label, options, default in settings:
        maps, seconds, first = measure(lambda: skinfit.fit.fit_pixels(pixels, progress=False, model=MODEL, **options), repeats)
        error = np.max(np.abs(np.column_stack([maps["melanin"].ravel(), maps["haemoglobin"].ravel()]) - truth), axis=1)
        points.append(Point("image_fit", label, seconds, first, float(np.percentile(error, 99)), "p99 of max |C_m, C_h error|",
                            default, baseline, f"{size}x{size} round trip, {np.mean(maps['status'] == 0):.1%} SUCCESS"))
    return points


def planner_sweep(repeats: int) -> list[Point]:
    rng = np.random.default_rng(2)
    params = skinfit.SkinParams(10 ** rng.uniform(-3, np.log10(0.5), 16), rng.uniform(0, 1, 16), 10 ** rng.uniform(-3, -1, 16))
    wl = tuple(np.arange(400.0, 701.0, 10.0))
    full = plan(wavelengths_nm=wl, profiles=True, pixel_footprint_mm=0.002, model=MODEL)
    reference = full.evaluate(params)
    points = []
    for label, the_plan in (("reflectance + profiles (256 radii)", full), ("reflectance only", plan(wavelengths_nm=wl, model=MODEL))):
        outputs, seconds, first = measure(lambda: _arrays(the_plan.evaluate(params)), repeats)
        points.append(Point("planner", label, seconds, first, float(np.max(np.abs(outputs[0] - reference.reflectance))),
                            "max |R - R(full plan)|", False, note="16 parameter sets, 31 wavelengths"))
    return points


def _arrays(result) -> list:
    """The arrays of a plan's ``Result`` (to wait for all of them)."""
    return [a for a in (result.reflectance, result.rgb, result.profiles, result.rgb_profiles) if a is not None]


SWEEPS = {
    "profiles": profile_sweep,  # three sweeps: profile_quadrature, profile_radii, profile_wavelengths
    "colour": colour_sweep,
    "spectral_fit": spectral_fit_sweep,
    "image_fit": image_fit_sweep,
    "planner": planner_sweep,
}


#: What counts as a real difference on a shared, noisy machine: 10 % in time, a factor 2 in error.
TIME_MARGIN, ERROR_MARGIN = 1.1, 2.0
#: Errors below these are equal for the comparison (rounding, or far below what anyone can see or
#: measure): profile values relative to the peak, CIEDE2000, fitted parameters.
ERROR_FLOORS = {"profile_quadrature": 1e-12, "colour": 1e-3, "spectral_fit": 1e-9, "image_fit": 1e-9, "planner": 1e-12}


def dominates(q: Point, p: Point) -> bool:
    """q is no worse than p in either (within the margins) and clearly better in one."""
    floor = ERROR_FLOORS.get(p.sweep, 0.0)
    q_error, p_error = max(q.error, floor), max(p.error, floor)
    no_worse = q.time_s <= p.time_s * TIME_MARGIN and q_error <= p_error * ERROR_MARGIN
    better = q.time_s * TIME_MARGIN < p.time_s or q_error * ERROR_MARGIN < p_error
    return no_worse and better


def pareto_front(points: list[Point]) -> list[Point]:
    """Points no other point dominates (``dominates``: margins absorb timing noise)."""
    return [p for p in points if not any(dominates(q, p) for q in points if q is not p)]


def write_csv(points: list[Point], path: Path) -> None:
    fields = ["sweep", "setting", "time_s", "compile_s", "error", "error_unit", "default", "on_pareto_front", "baseline_s", "speedup_vs_baseline", "note"]
    fronts = {id(p) for sweep in {p.sweep for p in points} for p in pareto_front([q for q in points if q.sweep == sweep])}
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields)
        writer.writeheader()
        for p in points:
            writer.writerow({**dataclasses.asdict(p), "on_pareto_front": id(p) in fronts, "speedup_vs_baseline": p.speedup_vs_baseline})


def plot(points: list[Point], sweep: str, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mine = [p for p in points if p.sweep == sweep]
    front = sorted(pareto_front(mine), key=lambda p: p.time_s)
    floor = min((p.error for p in mine if p.error > 0), default=1e-16) / 10
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    for p in mine:
        ax.scatter(p.time_s, max(p.error, floor), s=60 if p.default else 30, marker="*" if p.default else "o",
                   color="C3" if p.default else "C0", zorder=3)
        ax.annotate(p.setting, (p.time_s, max(p.error, floor)), fontsize=6.5, xytext=(4, 3), textcoords="offset points")
    ax.plot([p.time_s for p in front], [max(p.error, floor) for p in front], color="C1", lw=1, label="Pareto front", zorder=2)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time after compilation (s)")
    ax.set_ylabel(mine[0].error_unit if mine else "error")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
