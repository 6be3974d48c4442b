"""Inverse fitting of reflectance spectra: table warm start, Gauss-Newton, optimistix fallback.

Pipeline for a batch of spectra (compiled once per wavelength grid, free set and batch size):

1. Warm start (``fit_table``): the nearest table entry in each start group, corrected by its
   precomputed Gauss-Newton step; the groups whose corrected start the linearised model predicts
   to fit best are kept.
2. Projected Gauss-Newton in lock-step over the batch, in the bounded coordinates of
   ``fit_variables`` (variables on a bound held there while their gradient pushes outward): a few
   steps from each kept start, then more from the best. From table starts it converges
   quadratically for almost every model spectrum, and a fixed step count vectorises without
   per-spectrum control flow (measured: 2-3x faster than optimistix's own loops under vmap, whose
   batched while-loops run until the slowest member finishes).
3. The spectra that have not converged (most measured spectra: large-residual problems, where
   Gauss-Newton converges linearly or not at all) are gathered into small batches for bounded
   Levenberg-Marquardt with a secant curvature term (``BoundedPolish``, in the variables' linear
   range positions), then with the exact curvature (in logarithmic positions for the multiplicative
   variables), and the few left go to optimistix Levenberg-Marquardt.
4. Diagnostics at the optimum: RMS residual, standard errors from the Jacobian, CIEDE2000 between
   measured and fitted colour under D65, iteration count and a status code per spectrum.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._batching import map_batches, pad_size
from .._caching import eager_cache
from .._validate import SkinfitInputError
from .._validate import wavelengths as _check_wavelengths
from ..colorimetry import delta_e2000, xyz_to_lab, xyz_weights
from ..model import WAVELENGTH_RANGE_NM, SkinModel, SkinParams, model_with_options
from ._linalg import solve_normal
from ._lockstep import LockstepState, evaluate_with_jacobian, placeholder
from ._transport_polish import bounded_polish
from ._variables import (
    CHROMOPHORES,
    MODEL,
    MODEL_FIELDS,
    VARIABLES,
    MeasurementModel,
    from_unbounded,
    model_constant,
    stationarity,
    to_unbounded,
)
from ._warm_start import build_fit_table


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
        model: name of the ``SkinModel`` the fit used.
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
    model: str = "custom"

    def skin_params(self):
        """The fitted skin parameters as ``SkinParams`` of shape (n,)."""
        return SkinParams(*(self.parameters[name] for name in CHROMOPHORES))

    @property
    def succeeded(self) -> np.ndarray:
        return self.status == FitStatus.SUCCESS


@dataclasses.dataclass(frozen=True)
class SolverSettings:
    """Warm start, Gauss-Newton schedule and Levenberg-Marquardt settings.

    The fit has genuine local minima (for example C_h = 0 against C_h = 0.1 for pheomelanin-rich
    dark skin, 0.02 % apart in reflectance). Each spectrum takes the ``candidates`` best corrected
    starts of the warm-start table (``table_shape`` entries over (C_m, beta_m, C_h), in
    ``start_groups`` = (blend bands, haemoglobin bands)), runs ``start_steps`` Gauss-Newton steps from
    each, keeps the best and runs ``refine_steps`` more. These steps run in lock-step over the batch
    (vectorised, no per-spectrum control flow). A spectrum whose last step was at most ``step_tol``
    (in the unbounded coordinates, and shrinking) has converged. The others are gathered (and
    continue for ``continue_steps`` more Gauss-Newton steps, 0 by default); what still has not converged
    goes to bounded Levenberg-Marquardt with NL2SOL's secant curvature (``skinfit.fit.BoundedPolish``,
    at most ``polish_steps``, converged also when first-order optimal on a bound within
    ``stationarity_tol`` or when the model step predicts a relative cost reduction below
    ``reduction_tol``: measured spectra are large-residual problems, where Gauss-Newton converges
    linearly or not at all), then to the same with the exact curvature (at most ``newton_steps``:
    fits in long curved valleys, e.g. the extended free set on measured faces), and what is left to optimistix
    Levenberg-Marquardt (``rtol``, ``atol``, ``max_steps``). A transport fit then takes at most ``transport_steps`` bounded
    Levenberg-Marquardt steps on the transport model (``skinfit.fit``).
    """

    candidates: int = 2
    start_steps: int = 2
    refine_steps: int = 3
    continue_steps: int = 0
    step_tol: float = 1e-7
    rtol: float = 1e-9
    atol: float = 1e-11
    max_steps: int = 256
    stationarity_tol: float = 1e-6
    reduction_tol: float = 1e-10
    table_shape: tuple[int, int, int] = (24, 9, 24)
    start_groups: tuple[int, int] = (2, 4)
    transport_steps: int = 40
    polish_steps: int = 60
    # the slowest of 1,000 ISSA faces (DJ2006, extended free set) took 126 exact steps, walking
    # melanin to its bound along a thin-epidermis valley; rounds cost only the spectra left in them
    newton_steps: int = 180


#: Default weight of the CIELAB (D65) colour difference in the fit's residual, per unit of Delta E:
#: a residual spectrum that shifts the colour by Delta E 1 costs as much as 0.02 of reflectance at
#: one wavelength. Measured skin spectra are fitted to their colour as well as their shape (the
#: model cannot follow every wiggle; this decides which residual it leaves).
COLOUR_WEIGHT = 0.02


def fit_spectra(
    wavelengths_nm: Sequence[float] | np.ndarray,
    reflectance: np.ndarray,
    *,
    model: SkinModel | None = None,
    free: Sequence[str] | None = None,
    fixed: Mapping[str, float] | None = None,
    weights: np.ndarray | None = None,
    port_radius_mm: float | None = None,
    specular_included_deg: float | None = None,
    bandwidth_nm: float | None = None,
    colour_weight: float = COLOUR_WEIGHT,
    prior: bool | None = None,
    max_rms: float = 0.1,
    adding: str | None = None,
    method: str | None = None,
    anisotropy: float | None = None,
    chunk_size: int = 512,
    settings: SolverSettings = SolverSettings(),
    progress: bool | None = None,
) -> SpectralFit:
    """Fit skin parameters to reflectance spectra.

    Args:
        wavelengths_nm: (m,) increasing wavelengths in nm within 250-1000.
        reflectance: (m,) or (n, m) measured reflectance (factor, 0-1).
        model: the ``SkinModel`` (default: the calibrated package default; ``SkinModel.dj2006()``
            for Donner & Jensen 2006). Its constants are traced: another model or value does not
            recompile.
        free: variables to fit (see ``skinfit.fit.VARIABLES``): any of melanin,
            melanin_blend, haemoglobin, blood_oxygenation, epidermis_thickness_mm,
            scattering_scale, carotene_umol_per_l, specular_offset, calibration_scale, oil. Default:
            the three chromophores, and oil when the measurement includes the specular part.
        fixed: values of variables that are not free (defaults: the model's constants, no offset,
            no calibration, oil 0.3). A chromophore that is not free must be given here.
        weights: (m,) per-wavelength weights on the residual (1/sigma); e.g. 1/reflectance for a
            relative fit.
        port_radius_mm: radius of the instrument port; light re-emerging beyond it is lost
            (None: infinite port).
        specular_included_deg: the measurement includes the specular reflection of light
            incident at this angle (degrees; e.g. 8 for a d/8 sphere in SCI mode): the surface
            (oil) layer enters the model, and ``oil`` is free by default.
        bandwidth_nm: the instrument's band-pass (full width at half maximum of a triangular slit,
            e.g. 10 for a spectrophotometer reporting every 10 nm with a 10 nm band-pass); None: the
            model's monochromatic values (what ``diffuse_reflectance`` gives).
        colour_weight: weight of the CIELAB (D65) difference between fitted and measured colour, per
            unit of Delta E, beside the spectral residual (0: a purely spectral fit).
        prior: add the model's population prior (``SkinModel.prior``, Gaussian in log/logit
            coordinates) to the fit: MAP estimates, which keep weakly determined variables (the
            melanin blend) off their bounds, and standard errors of the posterior. Default: on for a
            model that has a prior (the calibrated one), off otherwise (DJ2006). ``False`` gives
            maximum-likelihood fits (exact round trips of model spectra).
        max_rms: converged fits with a larger RMS residual get ``OUT_OF_MODEL``.
        adding: override the diffusion model's adding (``"directional"`` or ``"symmetric"``).
        method: override the model's forward method: ``"diffusion"``, ``"transport"`` (tabulated
            adding-doubling, fitted like diffusion at about its cost) or ``"transport-direct"``: the
            direct adding-doubling (100x (GPU) to thousands of times (CPU) the cost per spectrum): the
            diffusion fit is the start, then bounded Levenberg-Marquardt on the direct transport model
            (``skinfit.fit``). With a finite port the captured fraction is the diffusion profile's
            (energy-corrected, as ``profile``).
        anisotropy: Henyey-Greenstein g of both layers for the transport methods (default 0.8).
        chunk_size: spectra per compiled batch (memory stays bounded). Measured on a 2-core CPU (1,024 ISSA
            face spectra): 74 us per spectrum in batches of 256 or 512 and 124 us in batches of 1,024
            for the calibrated model (its tabulated transport's stencils), 100-106 us at any size for
            DJ2006.
        settings: solver tolerances, step limits and warm-start table size.
        progress: show a progress bar (default: when there is more than one chunk).

    Returns:
        ``SpectralFit``.
    """
    lam = np.asarray(_check_wavelengths(wavelengths_nm, low=WAVELENGTH_RANGE_NM[0], high=WAVELENGTH_RANGE_NM[1]))
    if lam.size > 1 and np.any(np.diff(lam) <= 0):
        raise SkinfitInputError("wavelengths_nm must be strictly increasing")
    target = np.asarray(reflectance, dtype=float)
    single = target.ndim == 1
    target = np.atleast_2d(target)
    if target.ndim != 2 or target.shape[1] != lam.size:
        raise SkinfitInputError(f"reflectance must have shape (n, {lam.size}) to match the wavelengths, got {np.shape(reflectance)}")
    skin = model_with_options(model, adding=adding, method=method, anisotropy=anisotropy)
    direct_transport = skin.method.solves_directly
    if prior is None:
        prior = skin.prior is not None
    measurement = measurement_model(skin, free, fixed, port_radius_mm, specular_included_deg, bandwidth_nm, colour_weight, prior)
    w = np.ones(lam.size) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != lam.shape or not np.all(np.isfinite(w)) or np.any(w < 0) or not np.any(w > 0):
        raise SkinfitInputError(f"weights must be {lam.size} finite non-negative values, not all zero")

    bad = ~np.all(np.isfinite(target), axis=1) | np.any((target < -0.05) | (target > 1.5), axis=1)
    clean = np.where(bad[:, None], 0.3, np.nan_to_num(target))  # a harmless stand-in; reported as BAD_INPUT

    wavelengths, wtuple = tuple(lam.tolist()), tuple(w.tolist())
    solver = _solver(measurement.static_key, wavelengths, wtuple, settings)
    if direct_transport:
        u, steps, converged = _fit_transport(measurement, lam, w, clean, settings, chunk_size, progress)
    else:
        u, steps, converged = solver.run(measurement, clean, chunk_size, progress)

    fitted, std_err, stationarity, delta_e = solver.diagnostics(measurement, u, clean, chunk_size)
    # The optimiser's own test, or first-order optimality in physical coordinates: the latter
    # recognises optima on a bound, where (Gauss-Newton blind to curvature there) steps shrink
    # only linearly and the optimiser's step test can run out of steps.
    converged = converged | (stationarity <= settings.stationarity_tol)
    rms = np.sqrt(np.mean((fitted - clean) ** 2, axis=1))
    status = np.where(converged, FitStatus.SUCCESS, FitStatus.MAX_STEPS)
    status = np.where(converged & (rms > max_rms), FitStatus.OUT_OF_MODEL, status)
    status = np.where(bad, FitStatus.BAD_INPUT, status).astype(np.int8)

    values = {k: np.array(v) for k, v in measurement.values(np.asarray(u)).items()}
    for name in VARIABLES:  # every variable is reported: the model's own constants where not set
        if name not in values and name in MODEL_FIELDS:
            values[name] = np.full(len(clean), model_constant(skin, name))
    errors = {name: np.zeros(len(clean)) for name in VARIABLES}
    for i, name in enumerate(measurement.free):
        errors[name] = std_err[:, i]
    for arr in (*values.values(), *errors.values(), rms, delta_e, fitted):
        arr[bad] = 0.0
    result = SpectralFit(lam, measurement.free, values, errors, status, rms, delta_e, steps, fitted, skin.name)
    return _squeeze(result) if single else result


def _fit_transport(measurement, lam, w, target, settings, chunk_size, progress):
    """(u, steps, converged) of direct transport fits: the diffusion fit, then bounded
    Levenberg-Marquardt on the transport model (``skinfit.fit``)."""
    wavelengths, weights = tuple(lam.tolist()), tuple(w.tolist())
    diffusion = measurement.as_diffusion()
    u, steps, _ = _solver(diffusion.static_key, wavelengths, weights, settings).run(diffusion, target, chunk_size, progress)
    theta = np.stack([from_unbounded(name, np.asarray(u[:, i])) for i, name in enumerate(measurement.free)], axis=1)
    polish = bounded_polish(measurement.free, wavelengths, weights, settings.step_tol, settings.stationarity_tol,
                            reduction_tol=settings.reduction_tol, logarithmic=False)
    theta, more, converged = polish.run(measurement, theta, target, settings.transport_steps, chunk_size, progress)
    u = np.stack([to_unbounded(name, theta[:, i]) for i, name in enumerate(measurement.free)], axis=1)
    return u, steps + more, converged


def measurement_model(skin: SkinModel, free, fixed, port_radius_mm, specular_included_deg=None, bandwidth_nm=None,
                      colour_weight=COLOUR_WEIGHT, prior=False) -> MeasurementModel:
    """Check the fit's options and build its ``MeasurementModel``."""
    surface = specular_included_deg is not None
    if free is None:
        free = (*CHROMOPHORES, "oil") if surface else CHROMOPHORES
    if isinstance(free, str):
        raise SkinfitInputError("free must be a sequence of variable names, e.g. ('melanin', 'haemoglobin')")
    free = tuple(free)
    fixed = dict(fixed or {})
    unknown = [n for n in (*free, *fixed) if n not in VARIABLES]
    if unknown:
        raise SkinfitInputError(f"unknown fit variable(s) {', '.join(unknown)}; choose from {', '.join(VARIABLES)}")
    if not free:
        raise SkinfitInputError("nothing to fit: free is empty")
    if len(set(free)) != len(free) or set(free) & set(fixed):
        raise SkinfitInputError("each variable must be either free or fixed, once")
    if surface and not (np.isfinite(specular_included_deg) and 0.0 <= specular_included_deg < 89.0):
        raise SkinfitInputError("specular_included_deg must be an incidence angle in [0, 89) degrees, or None")
    if not surface and "oil" in (*free, *fixed):
        raise SkinfitInputError("oil acts only on the specular part: give specular_included_deg (the measurement's incidence angle)")
    values = {}
    for name, var in VARIABLES.items():
        if name in free or (name == "oil" and not surface):
            continue
        value = fixed.get(name, var.default)
        if value is None:
            raise SkinfitInputError(f"{name} is not free, so give its value in fixed={{'{name}': ...}}")
        if value == MODEL:
            continue  # the skin model's own constant
        if not var.low <= float(value) <= var.high:
            raise SkinfitInputError(f"fixed {name} = {value} is outside [{var.low}, {var.high}]")
        values[name] = float(value)
    for name in free:
        if name in MODEL_FIELDS and np.ndim(getattr(skin, name)) != 0:
            raise SkinfitInputError(f"a fit of {name} needs a model whose {name} is one value")
    if port_radius_mm is not None and not (np.isfinite(port_radius_mm) and port_radius_mm > 0):
        raise SkinfitInputError("port_radius_mm must be a finite radius > 0 mm, or None")
    if bandwidth_nm is not None and not (np.isfinite(bandwidth_nm) and 0.0 < bandwidth_nm <= 50.0):
        raise SkinfitInputError("bandwidth_nm must be a band-pass in (0, 50] nm, or None")
    if not (np.isfinite(colour_weight) and colour_weight >= 0.0):
        raise SkinfitInputError("colour_weight must be >= 0")
    if prior and skin.prior is None:
        raise SkinfitInputError(f"model {skin.name!r} has no population prior (calibrated models have one)")
    order = tuple(n for n in VARIABLES if n in free)  # a canonical order: one compilation per set
    names = tuple(sorted(values))
    return MeasurementModel(
        order, names, jnp.asarray([values[n] for n in names], dtype=float), skin,
        None if port_radius_mm is None else float(port_radius_mm),
        None if specular_included_deg is None else float(specular_included_deg),
        None if bandwidth_nm is None else float(bandwidth_nm), float(colour_weight), bool(prior),
    )


class _Solver:
    """Warm start, polish and diagnostics for one measurement structure and wavelength grid.

    The measurement (skin model constants, fixed values) is an argument of every compiled method,
    so one solver serves every model of the same structure without recompiling.
    """

    def __init__(self, wavelengths: tuple, weights: tuple, settings: SolverSettings):
        self.settings = settings
        self.wavelengths = wavelengths
        self.lam = np.asarray(wavelengths)
        self.w = jnp.asarray(weights)
        self.xyz = xyz_weights(self.lam)  # (3, m) D65, CIE 1931 2 degree

    def table(self, measurement: MeasurementModel):
        # The warm-start table is always diffusion's or the tabulated model's: a direct transport
        # table would cost thousands of times more to build, and direct transport fits start from
        # the diffusion fit.
        if measurement.skin.method.solves_directly:
            measurement = measurement.as_diffusion()
        s = self.settings
        return build_fit_table(measurement, self.wavelengths, tuple(np.asarray(self.w).tolist()), tuple(s.table_shape),
                               tuple(s.start_groups))

    def residual(self, measurement, u, target):
        return measurement.residual(u, target, self.lam, self.w)

    # -- lock-step Gauss-Newton ---------------------------------------------------------------
    # State per spectrum (a LockstepState): the best iterate u so far, its cost, and as its carry the
    # Gauss-Newton step proposed at u.
    # Iterations take full, undamped steps, one Jacobian evaluation each, in lock-step over a batch.
    # Undamped steps can leave a local basin for a better one, which damped steps measured worse at
    # (wrong minima from table starts); they can also wander where a direction is weakly
    # determined, so the best iterate, not the last, is kept, and the fallback starts there.
    #
    # Bounds: in the sine coordinates a bound is u = +-pi/2, where d theta / du = 0. An optimum on or
    # near a bound (the melanin blend at 0 for 95 % of the ISSA face spectra under DJ2006) is a trap for
    # plain Gauss-Newton there: the variable's Jacobian column vanishes, its step grows to the clip and
    # the iterate folds back and forth across the bound without converging. So the step is solved in
    # the range fraction x = (theta - low) / span (where the bound is a plane and the column does not
    # vanish), as projected Gauss-Newton: a variable on a bound whose gradient pushes outward is held
    # there. The same step is taken in u (as before) for variables far from the bounds, and in x,
    # clipped to the box, for those near one or crossing one.
    def _evaluate(self, measurement, u):
        """The model's evaluation at u and its Jacobian with respect to u: the costly part of an
        iteration (``MeasurementModel.evaluation``)."""
        return evaluate_with_jacobian(lambda x: measurement.evaluation(x, self.lam), u)

    def _propose(self, measurement, u, evaluation, target):
        """Cost at u and the projected Gauss-Newton step from u (in u), from the model's evaluation
        at u and its Jacobian."""
        r, jacobian_u = measurement.linearised_residual(*evaluation, target, self.lam, self.w)
        cost = jnp.sum(r**2)
        x = 0.5 * (1.0 + jnp.sin(u))
        slope = 0.5 * jnp.cos(u)  # dx/du, never exactly 0 in floating point (cos(pi/2) = 6e-17)
        jacobian = jacobian_u / jnp.where(jnp.abs(slope) > 1e-300, slope, 1e-300)
        gradient = jacobian.T @ r
        # the same point in the principal interval [-pi/2, pi/2] (table starts may lie beyond it)
        principal = jnp.arcsin(jnp.clip(2.0 * x - 1.0, -1.0, 1.0))
        dx_du = jnp.maximum(0.5 * jnp.cos(principal), 1e-300)
        held = ((x <= 0.0) & (gradient > 0.0)) | ((x >= 1.0) & (gradient < 0.0))
        keep = ~held
        normal = jnp.where(keep[:, None] & keep[None, :], jacobian.T @ jacobian, 0.0) + jnp.diag(jnp.where(keep, 0.0, 1.0))
        step_x = solve_normal(normal, jnp.where(keep, -gradient, 0.0))
        ok = jnp.all(jnp.isfinite(step_x)) & jnp.isfinite(cost)
        # u spans pi: a longer step is a poor linearisation, never a useful move (x spans 1: a quarter)
        in_u = jnp.clip(principal + jnp.clip(step_x / dx_du, -0.5, 0.5), -_HALF_PI, _HALF_PI)
        in_x = jnp.arcsin(2.0 * jnp.clip(x + jnp.clip(step_x, -0.25, 0.25), 0.0, 1.0) - 1.0)
        near = (jnp.minimum(x, 1.0 - x) < _NEAR_BOUND) | (x + step_x <= 0.0) | (x + step_x >= 1.0)
        step = jnp.where(near, in_x, in_u) - u
        return jnp.where(ok, cost, jnp.inf), jnp.where(ok, step, 0.0)

    def _iterate(self, measurement, state, target, count):
        """``count`` iterations (model evaluations) from ``state``; a state with no proposal yet
        (cost NaN) spends its first evaluation on the start.

        Each loop step first proposes from the evaluation the previous step left in the loop's carry,
        then evaluates the next trial: the residual's Jacobian is formed from a carried buffer, which
        XLA does not fuse with the model (see ``MeasurementModel.evaluation``)."""
        round_off = 1e3 * jnp.finfo(state.point.dtype).eps ** 2 * jnp.sum((self.w * target) ** 2)

        def decide(best, trial, evaluation):
            current = LockstepState(trial, *self._propose(measurement, trial, evaluation, target))
            better = jnp.isnan(best.cost) | (current.cost <= best.cost + round_off)  # equal within round-off: converged runs end there
            return current.keep_where(better, best), current

        def body(k, carry):
            best, current, trial, evaluation = carry
            # (the first step has nothing to decide yet: its proposal is computed and dropped)
            decided = decide(best, trial, evaluation)
            best, current = jax.tree_util.tree_map(lambda a, b: jnp.where(k > 0, a, b), decided, (best, current))
            trial = jnp.where(jnp.isnan(current.cost), current.point, current.point + current.carry)
            return best, current, trial, self._evaluate(measurement, trial)

        evaluation = placeholder(lambda u: self._evaluate(measurement, u), state.point)
        best, _, trial, evaluation = jax.lax.fori_loop(0, count, body, (state, state, state.point, evaluation))
        return decide(best, trial, evaluation)[0]

    def _unevaluated(self, u) -> LockstepState:
        return LockstepState(u, jnp.full(u.shape[:-1], jnp.nan, u.dtype), jnp.zeros_like(u))

    def _finish(self, state):
        """(u, converged) from batched states: converged when the step proposed at the best point is
        at most ``step_tol``; that last step is then taken too (it is the quadratically small one)."""
        u, step = state.point, state.carry
        converged = jnp.max(jnp.abs(step), axis=-1) <= self.settings.step_tol
        return jnp.where(converged[:, None], u + step, u), converged

    @eqx.filter_jit
    def _warm_start(self, measurement, table, target):
        """Table candidates -> Gauss-Newton on each -> the best -> more Gauss-Newton, per target."""
        s = self.settings
        count = min(s.candidates, table.grid_u.shape[0])
        u = table.candidates(target, count)  # (n, count, f)
        iterate = lambda st, t, k: self._iterate(measurement, st, t, k)  # noqa: E731
        each = lambda uc, t: jax.vmap(lambda a: iterate(self._unevaluated(a), t, 1 + s.start_steps))(uc)  # noqa: E731
        states = jax.vmap(each)(u, target)
        best = jnp.argmin(states.cost, axis=1)
        state = jax.tree_util.tree_map(lambda a: a[jnp.arange(a.shape[0]), best], states)
        state = jax.vmap(lambda st, t: iterate(st, t, s.refine_steps))(state, target)
        return self._finish(state)

    @eqx.filter_jit
    def _continue(self, measurement, u, target):
        one = lambda a, t: self._iterate(measurement, self._unevaluated(a), t, 1 + self.settings.continue_steps)  # noqa: E731
        return self._finish(jax.vmap(one)(u, target))

    # -- optimistix fallback ------------------------------------------------------------------
    def _solve_one(self, measurement, u0, target, max_steps):
        solver = optx.LevenbergMarquardt(rtol=self.settings.rtol, atol=self.settings.atol)
        fn = lambda u, t: self.residual(measurement, u, t)  # noqa: E731
        sol = optx.least_squares(fn, solver, u0, args=target, max_steps=max_steps, throw=False)
        u = jnp.where(jnp.all(jnp.isfinite(sol.value)), sol.value, u0)
        return u, sol.stats["num_steps"], sol.result == optx.RESULTS.successful

    @eqx.filter_jit
    def _resume(self, measurement, u, target, max_steps):
        return jax.vmap(lambda a, t: self._solve_one(measurement, a, t, max_steps))(u, target)

    def run(self, measurement: MeasurementModel, target: np.ndarray, chunk_size: int, progress):
        """Fit every row of ``target``; returns (u, steps, converged)."""
        s = self.settings
        n = len(target)
        table = self.table(measurement)
        count = min(s.candidates, table.grid_u.shape[0])
        steps = np.full(n, count * (s.start_steps + 1) + s.refine_steps, dtype=np.int64)
        warm = lambda t: self._warm_start(measurement, table, t)  # noqa: E731
        u, done = map_batches(warm, (target,), pad_size(n, chunk_size), progress, "fitting spectra")

        # What has not converged: optionally more Gauss-Newton steps in smaller gathered batches (off by
        # default: on measured spectra they rarely finish what the polish below finishes in fewer steps).
        todo = np.flatnonzero(~done)
        if todo.size and s.continue_steps:
            more = lambda a, t: self._continue(measurement, a, t)  # noqa: E731
            u[todo], done[todo] = map_batches(more, (u[todo], target[todo]), _GATHERED_BATCH)
            steps[todo] += s.continue_steps + 1
        # First-order optimal on a bound is converged (the polish tests this itself).
        todo = np.flatnonzero(~done)
        if todo.size and not s.polish_steps:
            done[todo] = self.diagnostics(measurement, u[todo], target[todo], _GATHERED_BATCH, fixed_batch=True)[2] <= s.stationarity_tol
        todo = np.flatnonzero(~done)
        if todo.size and s.polish_steps:  # bounded quasi-Newton for what Gauss-Newton left
            self._polish(measurement, u, steps, done, target, todo, s.polish_steps, logarithmic=False)
        todo = np.flatnonzero(~done)
        if todo.size and s.newton_steps:  # the same with the exact second-order term, for valleys
            self._polish(measurement, u, steps, done, target, todo, s.newton_steps, exact_curvature=True)
        todo = np.flatnonzero(~done)
        if todo.size:  # Levenberg-Marquardt for the rest
            resume = lambda a, t: self._resume(measurement, a, t, s.max_steps)  # noqa: E731
            u[todo], steps_lm, done[todo] = map_batches(resume, (u[todo], target[todo]), _GATHERED_BATCH)
            steps[todo] += steps_lm
        return u, steps, done

    def _polish(self, measurement, u, steps, done, target, todo, max_steps, **options):
        """Bounded polish (``bounded_polish`` with ``options``) of the rows ``todo``, updating u, steps
        and done in place."""
        s = self.settings
        theta = np.stack([from_unbounded(n, np.asarray(u[todo, i])) for i, n in enumerate(measurement.free)], axis=1)
        polish = bounded_polish(measurement.free, self.wavelengths, tuple(np.asarray(self.w).tolist()), s.step_tol, s.stationarity_tol,
                                reduction_tol=s.reduction_tol, **options)
        theta, more, done[todo] = polish.run(measurement, theta, target[todo], max_steps, _POLISH_BATCH, False, fixed_batch=True)
        u[todo] = np.stack([to_unbounded(n, theta[:, i]) for i, n in enumerate(measurement.free)], axis=1)
        steps[todo] += more

    # -- diagnostics ------------------------------------------------------------------------
    @eqx.filter_jit
    def _diagnose(self, measurement, u, target):
        m = self.lam.size

        def one(ui, ti):
            # Jacobian with respect to the physical values of the free variables (not u); the colour
            # term weighs the fit but is no measurement, so the errors come from the spectrum (and
            # the prior, whose rows make them the posterior's)
            theta = jnp.stack([from_unbounded(name, ui[i]) for i, name in enumerate(measurement.free)])
            # one evaluation gives the fitted spectrum (its first m rows) and, through the cheap rest,
            # the residual and its Jacobian (rows: spectrum, colour (3, if on), prior)
            evaluation = evaluate_with_jacobian(lambda th: measurement.evaluation_of_free(th, self.lam), theta)
            r_full, jac = measurement.linearised_residual(*evaluation, ti, self.lam, self.w)
            fitted = evaluation[0][:m]
            jac_m = jnp.concatenate([jac[:m], jac[m + measurement.colour_rows :]])
            dof = jnp.maximum(m - theta.size, 1)
            s2 = jnp.sum(r_full[:m] ** 2) / dof
            evals, evecs = jnp.linalg.eigh(jac_m.T @ jac_m)
            evals = jnp.maximum(evals, 1e-30 * jnp.maximum(evals.max(), 1e-300))
            errors = jnp.sqrt(jnp.sum(evecs**2 / evals, axis=1) * s2)
            return fitted, errors, stationarity(measurement.free, theta, 2.0 * jac.T @ r_full, jnp.sum(r_full**2))

        fitted, errors, optimality = jax.vmap(one)(u, target)
        # CIEDE2000 of measured against fitted colour (D65, 2 degree; negative reflectance counts as 0)
        xyz = jnp.asarray(self.xyz.T, fitted.dtype)
        lab = lambda spectra: xyz_to_lab(jnp.maximum(spectra, 0.0) @ xyz)  # noqa: E731
        return fitted, errors, optimality, delta_e2000(lab(target), lab(fitted))

    def diagnostics(self, measurement, u, target, chunk_size, fixed_batch: bool = False):
        """Fitted spectra, standard errors, the stationarity measure and CIEDE2000 of each fit (in batches of
        ``chunk_size`` exactly with ``fixed_batch``: subsets of varying size then share one program)."""
        diagnose = lambda a, t: self._diagnose(measurement, a, t)  # noqa: E731
        return map_batches(diagnose, (u, target), chunk_size if fixed_batch else pad_size(len(u), chunk_size))


@eager_cache(maxsize=16)
def _solver(static_key, wavelengths: tuple, weights: tuple, settings: SolverSettings) -> _Solver:
    """One solver per measurement structure and grid: later calls, whatever their model's values,
    reuse its compilations (``static_key`` only keys the cache)."""
    return _Solver(wavelengths, weights, settings)


#: Batch size of the gathered stragglers (Gauss-Newton continuation and Levenberg-Marquardt).
_GATHERED_BATCH = 64
#: Batch size of the polish's rounds (``BoundedPolish.run``; it takes smaller ones for the last few).
_POLISH_BATCH = 128
_HALF_PI = float(np.pi / 2)  # the bounds of the sine coordinates (``to_unbounded`` gives exactly these)
#: Range fraction from a bound within which Gauss-Newton steps are taken in the range fraction, not u.
_NEAR_BOUND = 0.01


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
