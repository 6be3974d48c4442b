"""Inverse fitting of reflectance spectra: optimistix least squares from a table warm start.

Pipeline for a batch of spectra (compiled once per wavelength grid, free set and chunk size):

1. Warm start. A table of model spectra over (C_m, beta_m, C_h) (log-spaced in C_m and C_h)
   stores, for each entry, its spectrum and the Gauss-Newton step operator (J^T W J)^-1 J^T W.
   The table is split into groups (bands of beta_m and C_h); each target takes its nearest entry in
   every group and applies the precomputed Gauss-Newton correction. Variables the table does not
   cover start at their fixed/default values.
2. Polish: optimistix Gauss-Newton from the best few candidates, in the bounded coordinates of
   ``fit_variables``; the best converged run is the answer.
3. Fallback: spectra with no converged run continue with optimistix Levenberg-Marquardt.
3. Diagnostics at the optimum: RMS residual, standard errors from the Jacobian, CIEDE2000 between
   measured and fitted colour under D65, iteration count and a status code per spectrum.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from . import chromophores as chrom
from ._validate import SkinfitInputError, wavelengths as _check_wavelengths
from .fit_variables import CHROMOPHORES, STARTS, VARIABLES, MeasurementModel, from_unbounded, to_unbounded


class FitStatus(enum.IntEnum):
    """Per-spectrum outcome, in the spirit of ``optimistix.RESULTS``."""

    SUCCESS = 0  #: converged to the tolerances
    MAX_STEPS = 1  #: stopped at the step limit; values are the best iterate
    OUT_OF_MODEL = 2  #: converged, but the RMS residual exceeds ``max_rms``: the model cannot explain it
    BAD_INPUT = 3  #: NaN/Inf or reflectance outside [-0.05, 1.5]; values are zeros, not estimates


@dataclasses.dataclass(frozen=True)
class SpectralFit:
    """Result of ``fit_spectra`` for n spectra (NumPy arrays).

    Attributes:
        wavelengths_nm: (m,)
        free: names of the fitted variables.
        parameters: every fit variable (free and fixed), each (n,).
        standard_errors: each free variable's standard error, (n,); 0 for fixed ones.
        status: (n,) ``FitStatus`` codes.
        rms_residual: (n,) root-mean-square of fitted - measured (reflectance units, unweighted).
        delta_e2000: (n,) CIEDE2000 between measured and fitted spectrum colours (D65, 2 degree).
        iterations: (n,) optimiser steps.
        fitted: (n, m) model spectra at the optimum.
    """

    wavelengths_nm: np.ndarray
    free: tuple[str, ...]
    parameters: dict[str, np.ndarray]
    standard_errors: dict[str, np.ndarray]
    status: np.ndarray
    rms_residual: np.ndarray
    delta_e2000: np.ndarray
    iterations: np.ndarray
    fitted: np.ndarray

    def skin_params(self):
        """The fitted skin parameters as ``SkinParams`` of shape (n,)."""
        from .params import SkinParams

        return SkinParams(*(self.parameters[name] for name in CHROMOPHORES))

    @property
    def succeeded(self) -> np.ndarray:
        return self.status == FitStatus.SUCCESS


@dataclasses.dataclass(frozen=True)
class SolverSettings:
    """Warm start and Levenberg-Marquardt settings.

    The fit has genuine local minima (for example C_h = 0 against C_h = 0.1 for pheomelanin-rich
    dark skin, 0.02 % apart in reflectance), so it takes the nearest table entry in each of
    ``start_groups`` = (blend bands, haemoglobin bands) of the table, keeps the ``candidates`` that
    fit best after a precomputed Gauss-Newton correction, runs Gauss-Newton (``gauss_newton_steps``
    at most) from each and keeps the best converged result. Spectra where no Gauss-Newton run
    converges fall back to Levenberg-Marquardt (``max_steps``). Gauss-Newton steps cost about a fifth
    of Levenberg-Marquardt steps here and converge quadratically from table starts.
    """

    rtol: float = 1e-9
    atol: float = 1e-11
    candidates: int = 4
    gauss_newton_steps: int = 16
    max_steps: int = 256
    stationarity_tol: float = 1e-6
    table_shape: tuple[int, int, int] = (24, 9, 24)
    start_groups: tuple[int, int] = (2, 4)


def fit_spectra(
    wavelengths_nm: Sequence[float] | np.ndarray,
    reflectance: np.ndarray,
    *,
    free: Sequence[str] = CHROMOPHORES,
    fixed: Mapping[str, float] | None = None,
    weights: np.ndarray | None = None,
    port_radius_mm: float | None = None,
    adding: str = "directional",
    max_rms: float = 0.1,
    chunk_size: int = 1024,
    settings: SolverSettings = SolverSettings(),
    progress: bool | None = None,
) -> SpectralFit:
    """Fit skin parameters to reflectance spectra.

    Args:
        wavelengths_nm: (m,) increasing wavelengths in nm within 250-1000.
        reflectance: (m,) or (n, m) measured reflectance (factor, 0-1).
        free: variables to fit (see ``skinfit.fit_variables.VARIABLES``): any of melanin,
            melanin_blend, haemoglobin, blood_oxygenation, epidermis_thickness_mm,
            scattering_scale, specular_offset, calibration_scale.
        fixed: values of variables that are not free (defaults: DJ2006 constants, no offset, no
            calibration). A chromophore that is not free must be given here.
        weights: (m,) per-wavelength weights on the residual (1/sigma); e.g. 1/reflectance for a
            relative fit.
        port_radius_mm: radius of the instrument port; light re-emerging beyond it is lost
            (None: infinite port).
        adding: ``"directional"`` or ``"symmetric"``.
        max_rms: converged fits with a larger RMS residual get ``OUT_OF_MODEL``.
        chunk_size: spectra per compiled batch (memory stays bounded).
        settings: solver tolerances, step limits and warm-start table size.
        progress: show a progress bar (default: when there is more than one chunk).

    Returns:
        ``SpectralFit``.
    """
    lam = np.asarray(_check_wavelengths(wavelengths_nm, low=chrom.WAVELENGTH_RANGE_NM[0], high=chrom.WAVELENGTH_RANGE_NM[1]))
    if lam.size > 1 and np.any(np.diff(lam) <= 0):
        raise SkinfitInputError("wavelengths_nm must be strictly increasing")
    target = np.asarray(reflectance, dtype=float)
    single = target.ndim == 1
    target = np.atleast_2d(target)
    if target.ndim != 2 or target.shape[1] != lam.size:
        raise SkinfitInputError(f"reflectance must have shape (n, {lam.size}) to match the wavelengths, got {np.shape(reflectance)}")
    model = _measurement_model(free, fixed, port_radius_mm, adding)
    w = np.ones(lam.size) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != lam.shape or not np.all(np.isfinite(w)) or np.any(w < 0) or not np.any(w > 0):
        raise SkinfitInputError(f"weights must be {lam.size} finite non-negative values, not all zero")

    bad = ~np.all(np.isfinite(target), axis=1) | np.any((target < -0.05) | (target > 1.5), axis=1)
    clean = np.where(bad[:, None], 0.3, np.nan_to_num(target))  # a harmless stand-in; reported as BAD_INPUT

    solver = _solver(model, tuple(lam.tolist()), tuple(w.tolist()), settings)
    u, steps, converged = solver.run(clean, chunk_size, progress)

    fitted, std_err, stationarity = solver.diagnostics(u, clean, chunk_size)
    # The optimiser's own test, or first-order optimality in physical coordinates: the latter
    # recognises optima on a bound, where (Gauss-Newton blind to curvature there) steps shrink
    # only linearly and the optimiser's step test can run out of steps.
    converged = converged | (stationarity <= settings.stationarity_tol)
    rms = np.sqrt(np.mean((fitted - clean) ** 2, axis=1))
    delta_e = _delta_e2000(lam, clean, fitted)
    status = np.where(converged, FitStatus.SUCCESS, FitStatus.MAX_STEPS)
    status = np.where(converged & (rms > max_rms), FitStatus.OUT_OF_MODEL, status)
    status = np.where(bad, FitStatus.BAD_INPUT, status).astype(np.int8)

    values = {k: np.array(v) for k, v in model.values(jnp.asarray(u)).items()}
    errors = {name: np.zeros(len(clean)) for name in VARIABLES}
    for i, name in enumerate(model.free):
        errors[name] = std_err[:, i]
    for arr in (*values.values(), *errors.values(), rms, delta_e, fitted):
        arr[bad] = 0.0
    result = SpectralFit(lam, model.free, values, errors, status, rms, delta_e, steps, fitted)
    return _squeeze(result) if single else result


def _measurement_model(free, fixed, port_radius_mm, adding) -> MeasurementModel:
    free = tuple(free)
    fixed = dict(fixed or {})
    unknown = [n for n in (*free, *fixed) if n not in VARIABLES]
    if unknown:
        raise SkinfitInputError(f"unknown fit variable(s) {', '.join(unknown)}; choose from {', '.join(VARIABLES)}")
    if not free:
        raise SkinfitInputError("nothing to fit: free is empty")
    if len(set(free)) != len(free) or set(free) & set(fixed):
        raise SkinfitInputError("each variable must be either free or fixed, once")
    values = {}
    for name, var in VARIABLES.items():
        if name in free:
            continue
        value = fixed.get(name, var.default)
        if value is None:
            raise SkinfitInputError(f"{name} is not free, so give its value in fixed={{'{name}': ...}}")
        if not var.low <= float(value) <= var.high:
            raise SkinfitInputError(f"fixed {name} = {value} is outside [{var.low}, {var.high}]")
        values[name] = float(value)
    if port_radius_mm is not None and not (np.isfinite(port_radius_mm) and port_radius_mm > 0):
        raise SkinfitInputError("port_radius_mm must be a finite radius > 0 mm, or None")
    if adding not in ("directional", "symmetric"):
        raise SkinfitInputError(f"adding must be 'directional' or 'symmetric', got {adding!r}")
    order = tuple(n for n in VARIABLES if n in free)  # a canonical order: one compilation per set
    return MeasurementModel(order, tuple(sorted(values.items())), None if port_radius_mm is None else float(port_radius_mm), adding)


class _Solver:
    """Warm start, polish and diagnostics for one measurement model and wavelength grid."""

    def __init__(self, model: MeasurementModel, wavelengths: tuple, weights: tuple, settings: SolverSettings):
        self.model, self.settings = model, settings
        self.lam = jnp.asarray(wavelengths)
        self.w = jnp.asarray(weights)
        self.table = _build_table(model, wavelengths, weights, tuple(settings.table_shape), tuple(settings.start_groups))

    def residual(self, u, target):
        return self.w * (self.model.spectrum(u, self.lam) - target)

    # -- warm start -------------------------------------------------------------------------
    def candidates(self, target):
        """(n, groups, n_free) corrected table starts: the nearest entry of each table group."""
        grid_u, spectra, step_op, group = self.table
        ws = self.w * spectra
        dist = jnp.sum(ws**2, axis=1)[None] - 2.0 * (self.w * target) @ ws.T  # (n, N)
        out = []
        for g in range(int(group.max()) + 1):
            idx = jnp.argmin(jnp.where(jnp.asarray(group == g)[None], dist, jnp.inf), axis=1)
            correction = jnp.einsum("nfm,nm->nf", step_op[idx], target - spectra[idx])
            out.append(grid_u[idx] + jnp.clip(correction, -0.5, 0.5))  # u spans pi: keep the step local
        return jnp.stack(out, axis=1)

    # -- polish -----------------------------------------------------------------------------
    def _solve_one(self, u0, target, max_steps):
        solver = optx.LevenbergMarquardt(rtol=self.settings.rtol, atol=self.settings.atol)
        sol = optx.least_squares(self.residual, solver, u0, args=target, max_steps=max_steps, throw=False)
        u = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, u0)
        return u, sol.stats["num_steps"], sol.result == optx.RESULTS.successful

    def _gauss_newton(self, u0, target):
        solver = optx.GaussNewton(rtol=self.settings.rtol, atol=self.settings.atol)
        sol = optx.least_squares(self.residual, solver, u0, args=target, max_steps=self.settings.gauss_newton_steps, throw=False)
        ok = (sol.result == optx.RESULTS.successful) & jnp.all(jnp.isfinite(sol.value))
        u = jnp.where(ok, sol.value, u0)
        cost = jnp.sum(self.residual(u, target) ** 2)
        return u, jnp.where(ok & jnp.isfinite(cost), cost, jnp.inf), ok, sol.stats["num_steps"]

    @eqx.filter_jit
    def _first_pass(self, target):
        """Candidates -> Gauss-Newton from the best few -> best converged run, per target."""
        cand = self.candidates(target)  # (n, groups, f)
        n = cand.shape[0]
        start_cost = jnp.sum(jax.vmap(jax.vmap(self.residual), in_axes=(1, None), out_axes=1)(cand, target) ** 2, axis=-1)
        start_cost = jnp.where(jnp.isfinite(start_cost), start_cost, jnp.inf)
        order = jnp.argsort(start_cost, axis=1)[:, : self.settings.candidates]
        starts = jnp.take_along_axis(cand, order[:, :, None], axis=1)
        u, cost, ok, steps = jax.vmap(jax.vmap(self._gauss_newton, in_axes=(0, None)))(starts, target)
        best = jnp.argmin(cost, axis=1)
        rows = jnp.arange(n)
        return u[rows, best], ok[rows, best], steps.sum(axis=1), starts[:, 0]

    @eqx.filter_jit
    def _resume(self, u, target, max_steps):
        return jax.vmap(lambda a, t: self._solve_one(a, t, max_steps))(u, target)

    def run(self, target: np.ndarray, chunk_size: int, progress):
        """Fit every row of ``target``; returns (u, steps, converged)."""
        n, n_free = len(target), len(self.model.free)
        u = np.zeros((n, n_free))
        fallback_start = np.zeros((n, n_free))
        steps = np.zeros(n, dtype=np.int64)
        done = np.zeros(n, dtype=bool)
        for start, stop, chunk in _chunks(target, _pad_size(n, chunk_size), progress, "fitting spectra"):
            out = self._first_pass(jnp.asarray(chunk))
            u[start:stop], done[start:stop], steps[start:stop], fallback_start[start:stop] = (
                np.asarray(a)[: stop - start] for a in out
            )
        todo = np.flatnonzero(~done)
        if todo.size:  # Levenberg-Marquardt from the best start, for the few Gauss-Newton could not finish
            u_lm, steps_lm, done_lm = self._polish(fallback_start[todo], target[todo], chunk_size)
            u[todo], done[todo] = u_lm, done_lm
            steps[todo] += steps_lm
        return u, steps, done

    def _polish(self, u0: np.ndarray, target: np.ndarray, chunk_size: int):
        """Levenberg-Marquardt to convergence (``max_steps`` at most), chunk by chunk."""
        u = np.zeros_like(u0)
        steps = np.zeros(len(u0), dtype=np.int64)
        done = np.zeros(len(u0), dtype=bool)
        # A fixed batch size: the fallback set varies from call to call, its compilation should not.
        for start, stop, idx in _chunks(np.arange(len(u0)), min(_FALLBACK_BATCH, chunk_size), False, ""):
            uc, sc, dc = self._resume(jnp.asarray(u0[idx]), jnp.asarray(target[idx]), self.settings.max_steps)
            u[start:stop], steps[start:stop], done[start:stop] = (np.asarray(a)[: stop - start] for a in (uc, sc, dc))
        return u, steps, done

    @eqx.filter_jit
    def _residual_batch(self, u, target):
        return jax.vmap(self.residual)(u, target)

    def _residuals(self, u, target, chunk_size):
        out = np.zeros_like(target)
        for start, stop, idx in _chunks(np.arange(len(u)), _pad_size(len(u), chunk_size), False, ""):
            out[start:stop] = np.asarray(self._residual_batch(jnp.asarray(u[idx]), jnp.asarray(target[idx])))[: stop - start]
        return out

    # -- diagnostics ------------------------------------------------------------------------
    @eqx.filter_jit
    def _diagnose(self, u, target):
        fitted = self.model.spectrum(u, self.lam)

        def std_errors(ui, ti):
            # Jacobian with respect to the physical values of the free variables (not u).
            theta = jnp.stack([from_unbounded(name, ui[i]) for i, name in enumerate(self.model.free)])
            residual = lambda th: self.w * (self.model.spectrum_of_free(th, self.lam) - ti)  # noqa: E731
            jac = jax.jacfwd(residual)(theta)
            r = residual(theta)
            dof = jnp.maximum(r.size - theta.size, 1)
            s2 = jnp.sum(r**2) / dof
            evals, evecs = jnp.linalg.eigh(jac.T @ jac)
            evals = jnp.maximum(evals, 1e-30 * jnp.maximum(evals.max(), 1e-300))
            errors = jnp.sqrt(jnp.sum(evecs**2 / evals, axis=1) * s2)
            return errors, _stationarity(self.model.free, theta, 2.0 * jac.T @ r, jnp.sum(r**2))

        errors, stationarity = jax.vmap(std_errors)(u, target)
        return fitted, errors, stationarity

    def diagnostics(self, u, target, chunk_size):
        """Fitted spectra, standard errors and the stationarity measure of each fit."""
        fitted = np.zeros_like(target)
        errors = np.zeros_like(u)
        stationarity = np.zeros(len(u))
        for start, stop, idx in _chunks(np.arange(len(u)), _pad_size(len(u), chunk_size), False, ""):
            out = self._diagnose(jnp.asarray(u[idx]), jnp.asarray(target[idx]))
            fitted[start:stop], errors[start:stop], stationarity[start:stop] = (np.asarray(a)[: stop - start] for a in out)
        return fitted, errors, stationarity


def _stationarity(free, theta, gradient, cost):
    """First-order optimality in physical coordinates, as a fraction of the cost.

    The largest change of the cost that a full-range move of one variable would give to first
    order, counting only moves that stay inside the box (a variable on a bound whose gradient
    pushes outward is optimal there), divided by the cost. Converged fits have ~0.
    """
    low = jnp.array([VARIABLES[n].low for n in free])
    high = jnp.array([VARIABLES[n].high for n in free])
    span = high - low
    at_low = theta - low <= 1e-6 * span
    at_high = high - theta <= 1e-6 * span
    projected = jnp.where(at_low, jnp.minimum(gradient, 0.0), jnp.where(at_high, jnp.maximum(gradient, 0.0), gradient))
    return jnp.max(jnp.abs(projected) * span) / jnp.maximum(cost, 1e-300)


@functools.lru_cache(maxsize=8)
def _solver(model: MeasurementModel, wavelengths: tuple, weights: tuple, settings: SolverSettings) -> _Solver:
    """One solver (table and compiled functions) per problem: later calls reuse its compilations."""
    return _Solver(model, wavelengths, weights, settings)


@functools.lru_cache(maxsize=8)
def _build_table(model: MeasurementModel, wavelengths: tuple, weights: tuple, shape: tuple, groups: tuple):
    """Grid in u, model spectra, Gauss-Newton step operators and start groups (free chromophores)."""
    axes = {
        "melanin": np.geomspace(5e-4, 0.8, shape[0]),
        # interior blends only: starts away from the bounds
        "melanin_blend": np.linspace(0.05, 0.95, shape[1]),
        "haemoglobin": np.geomspace(5e-4, 0.5, shape[2]),
    }
    free_axes = [axes[n] if n in CHROMOPHORES else np.array([STARTS.get(n, VARIABLES[n].default)]) for n in model.free]
    mesh = np.meshgrid(*free_axes, indexing="ij")
    grid_u = np.stack([to_unbounded(n, m.ravel()) for n, m in zip(model.free, mesh)], axis=-1)
    lam, w = jnp.asarray(wavelengths), jnp.asarray(weights)

    def entry(gu):
        spectrum = model.spectrum(gu, lam)
        jw = w[:, None] * jax.jacfwd(lambda x: model.spectrum(x, lam))(gu)  # (m, f)
        normal = jw.T @ jw + 1e-10 * jnp.eye(gu.shape[-1])
        return spectrum, jnp.linalg.solve(normal, jw.T * w[None, :])  # (f, m)

    @jax.jit
    def build(gu):
        # batched so that memory stays bounded (the finite-port model carries a q axis)
        return jax.lax.map(entry, gu, batch_size=256)

    spectra, step_op = build(jnp.asarray(grid_u))
    # Start groups: bands of the blend and haemoglobin axes (one group if neither is free).
    index = np.meshgrid(*(np.arange(len(a)) for a in free_axes), indexing="ij")
    group = np.zeros(grid_u.shape[0], dtype=int)
    bands = dict(zip(("melanin_blend", "haemoglobin"), groups))
    for name, count in bands.items():
        if name in model.free:
            axis = model.free.index(name)
            size = len(free_axes[axis])
            group = group * count + index[axis].ravel() * count // size
    return jnp.asarray(grid_u), spectra, step_op, group


_FALLBACK_BATCH = 64


def _pad_size(n: int, chunk_size: int) -> int:
    """Batch size for n items: the chunk size, or the next power of two below it (few compilations)."""
    size = 1
    while size < min(n, chunk_size):
        size *= 2
    return min(size, chunk_size)


def _chunks(items: np.ndarray, size: int, progress, desc: str):
    """(start, stop, padded chunk) over ``items`` in fixed-size chunks; the last is padded by repetition."""
    n = len(items)
    starts = range(0, n, size)
    if progress is None:
        progress = len(starts) > 1
    if progress:
        from tqdm.auto import tqdm

        starts = tqdm(starts, desc=desc, unit="chunk")
    for start in starts:
        stop = min(start + size, n)
        chunk = items[start:stop]
        if len(chunk) < size:
            chunk = np.concatenate([chunk, np.repeat(chunk[-1:], size - len(chunk), axis=0)])
        yield start, stop, chunk


def _delta_e2000(wavelengths, measured, fitted) -> np.ndarray:
    """CIEDE2000 between measured and fitted spectra (D65, CIE 1931 2 degree), via colour-science."""
    import colour

    from .colorimetry import xyz_weights

    weights = xyz_weights(wavelengths)
    white = colour.xy_to_XYZ(colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])
    lab = [colour.XYZ_to_Lab(np.clip(s, 0, None) @ weights.T, colour.XYZ_to_xy(white)) for s in (measured, fitted)]
    return np.asarray(colour.delta_E(lab[0], lab[1], method="CIE 2000"), dtype=float)


def _squeeze(fit: SpectralFit) -> SpectralFit:
    pick = lambda a: a[0]  # noqa: E731
    return dataclasses.replace(
        fit,
        parameters={k: pick(v) for k, v in fit.parameters.items()},
        standard_errors={k: pick(v) for k, v in fit.standard_errors.items()},
        status=pick(fit.status),
        rms_residual=pick(fit.rms_residual),
        delta_e2000=pick(fit.delta_e2000),
        iterations=pick(fit.iterations),
        fitted=pick(fit.fitted),
    )
