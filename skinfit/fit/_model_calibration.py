"""Calibrating a skin model's shared constants on a population of measured spectra.

Every spectrum i has its own chromophores u_i (the fit variables of ``fit_spectra``); the model's
constants theta (epidermis thickness, scattering laws, oxygenation, ...) are shared by all. The
calibration minimises the sum over spectra of the fit residual |r_i(u_i, theta)|^2 jointly:

    min_theta  sum_i  min_{u_i} |r_i(u_i, theta)|^2,

by variable projection (Golub & Pereyra 1973) with Kaufman's Jacobian: for given theta, every u_i is
solved (lock-step Levenberg-Marquardt over the batch, warm-started from the last solve); the reduced
problem in theta then has the Jacobian P_i J_theta,i with P_i = I - J_u,i (J_u,i^T J_u,i)^-1 J_u,i^T,
the part of the constants' effect that no per-spectrum parameter can absorb. Levenberg-Marquardt on
theta (a dozen unknowns) with these normal equations, summed over the spectra, converges in tens of
steps; each costs one batched Jacobian per spectrum. (Alternating between theta and the u_i was the
alternative: it zig-zags along the valleys where a constant and the chromophores trade off, e.g.
epidermis thickness against melanin, which variable projection removes exactly.)

Constants live in bounded coordinates (the sine transform of ``fit_variables``, in log for
positive scales). Their uncertainties are reported two ways: the Gauss-Newton covariance s^2 H^-1
(which assumes independent residuals, and is optimistic because the model's errors are shared),
and a cluster-robust sandwich H^-1 (sum_c g_c g_c^T) H^-1 over groups (subjects), which is not.
Cross-validation: the subjects are split into folds, the constants calibrated without each fold and
its spectra fitted with them through ``fit_spectra``.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._batching import map_batches, pad_size
from .._caching import BoundedCache
from .._validate import SkinfitInputError
from ..model import PopulationPrior, SkinModel, cache_key
from ._spectra import (
    COLOUR_WEIGHT,
    FitStatus,
    SpectralFit,
    fit_spectra,
    measurement_model,
)
from ._variables import VARIABLES, prior_coordinate, to_unbounded


@dataclasses.dataclass(frozen=True)
class Constant:
    """A calibratable constant of ``SkinModel``: its field path, range and scale."""

    path: str
    low: float
    high: float
    log: bool
    doc: str


#: The constants ``calibrate_model`` can fit, with the ranges it searches.
CONSTANTS: dict[str, Constant] = {c.path: c for c in (
    Constant("epidermis_thickness_mm", 0.015, 0.3, True, "epidermis thickness, mm"),
    Constant("epidermis_scattering.mie_mm", 0.3, 100.0, True, "epidermis reduced scattering, Mie part at 500 nm, mm^-1"),
    Constant("epidermis_scattering.mie_power", 0.0, 4.0, False, "epidermis Mie power"),
    Constant("epidermis_scattering.rayleigh_mm", 1e-3, 100.0, True, "epidermis reduced scattering, Rayleigh part at 500 nm, mm^-1"),
    Constant("dermis_scattering.mie_mm", 0.3, 100.0, True, "dermis reduced scattering, Mie part at 500 nm, mm^-1"),
    Constant("dermis_scattering.mie_power", 0.0, 4.0, False, "dermis Mie power"),
    Constant("dermis_scattering.rayleigh_mm", 1e-3, 100.0, True, "dermis reduced scattering, Rayleigh part at 500 nm, mm^-1"),
    Constant("blood_oxygenation", 0.3, 1.0, False, "HbO2 fraction of the blood"),
    Constant("epidermal_blood", 1e-4, 2.0, True, "epidermal blood fraction / dermal"),
    Constant("vessel_radius_mm", 1e-5, 0.05, True, "vessel radius for pigment packaging, mm"),
    Constant("baseline_scale", 0.1, 10.0, True, "factor on the baseline absorption"),
    Constant("carotene_umol_per_l", 0.01, 300.0, True, "epidermal beta-carotene, umol/L"),
    Constant("surface_ior", 1.3, 1.7, False, "index of the surface lobe's Fresnel factor"),
)}

#: What the shipped model calibrates (``benchmarks/calibrate_model.py``). Not the epidermis
#: thickness: 1-D transport depends on the epidermis only through sigma_a / sigma_s' and the
#: optical thickness sigma_s' d, so d and the epidermis's scattering trade off exactly (apart from
#: the small baseline absorption): the shipped model fixes d and calibrates the scattering. Nor the
#: surface index: with oil free per spectrum only oil x the lobe's albedo is seen.
#: Nor the Mie powers: freeing them (two more constants) changed the held-out CIEDE2000 of the
#: ISSA face spectra by less than 0.03 and left them undetermined (measured while choosing).
DEFAULT_CONSTANTS = (
    "epidermis_scattering.mie_mm",
    "dermis_scattering.mie_mm",
    "blood_oxygenation",
    "epidermal_blood",
    "vessel_radius_mm",
)


def _getter(path: str):
    names = path.split(".")

    def get(model):
        for name in names:
            model = getattr(model, name)
        return model

    return get


def _scalar(model: SkinModel, path: str) -> float:
    value = np.asarray(_getter(path)(model), dtype=float)
    if value.ndim:
        raise SkinfitInputError(f"the start model's {path} must be one value to calibrate it")
    return float(value)


def _to_coordinate(c: Constant, value: float) -> float:
    lo, hi, v = (np.log(c.low), np.log(c.high), np.log(max(value, c.low))) if c.log else (c.low, c.high, value)
    return float(np.arcsin(np.clip(2.0 * (v - lo) / (hi - lo) - 1.0, -1.0, 1.0)))


def _from_coordinate(c: Constant, s):
    lo, hi = (np.log(c.low), np.log(c.high)) if c.log else (c.low, c.high)
    x = lo + (hi - lo) * 0.5 * (1.0 + jnp.sin(s))
    return jnp.exp(x) if c.log else x


def with_constants(model: SkinModel, names: Sequence[str], coordinates) -> SkinModel:
    """``model`` with the named constants set from their bounded coordinates (traceable)."""
    for i, name in enumerate(names):
        value = _from_coordinate(CONSTANTS[name], coordinates[i])
        model = eqx.tree_at(_getter(name), model, value)
    return model


@dataclasses.dataclass(frozen=True)
class ModelCalibration:
    """Result of ``calibrate_model``.

    Attributes:
        model: the calibrated ``SkinModel`` (with its population prior).
        constants: each calibrated constant's value.
        standard_errors: cluster-robust standard error of each (over ``groups``; per spectrum
            without groups).
        naive_standard_errors: Gauss-Newton standard errors (independent residuals assumed).
        fit: the per-spectrum fits with the calibrated model (``SpectralFit``, through ``fit_spectra``).
        cross_validation: per held-out spectrum: fold, RMS residual, CIEDE2000, status (None
            without ``folds``), and the constants of each fold.
        history: cost after each accepted outer step.
        seconds: wall time of the calibration on all spectra (cross-validation not included; its
            own time is ``cross_validation["seconds"]``).
    """

    model: SkinModel
    constants: dict[str, float]
    standard_errors: dict[str, float]
    naive_standard_errors: dict[str, float]
    fit: object
    cross_validation: dict | None
    history: list[float]
    seconds: float

    def record(self) -> dict:
        """A JSON-ready summary (what ``SkinModel.save`` stores beside the constants)."""
        out = {
            "constants": self.constants,
            "standard_errors": self.standard_errors,
            "naive_standard_errors": self.naive_standard_errors,
            "in_sample": _summary(self.fit.rms_residual, self.fit.delta_e2000, self.fit.status),
            "outer_cost": self.history,
            "seconds": self.seconds,
        }
        if self.cross_validation is not None:
            cv = self.cross_validation
            ml = cv["maximum_likelihood"]
            out["cross_validation"] = {
                "folds": int(cv["folds"]),
                "with_prior": {**_summary(cv["rms_residual"], cv["delta_e2000"], cv["status"]), "on_bound_fraction": float(np.mean(cv["on_bound"]))},
                "maximum_likelihood": {**_summary(ml["rms_residual"], ml["delta_e2000"], ml["status"]),
                                       "on_bound_fraction": float(np.mean(ml["on_bound"]))},
                "fold_constants": cv["fold_constants"], "seconds": cv["seconds"]}
        return out


def on_a_bound(fit, tolerance: float = 1e-6) -> np.ndarray:
    """Per spectrum of a ``SpectralFit``: whether any free variable lies within ``tolerance`` of its
    range's size from a bound."""
    hits = np.zeros(np.shape(fit.status), bool)
    for name in fit.free:
        var = VARIABLES[name]
        value, span = np.asarray(fit.parameters[name]), var.high - var.low
        hits |= (value - var.low <= tolerance * span) | (var.high - value <= tolerance * span)
    return hits


def _summary(rms, delta_e, status) -> dict:
    rms, delta_e, status = np.asarray(rms), np.asarray(delta_e), np.asarray(status)
    return {
        "spectra": int(rms.size),
        "rms_median": float(np.median(rms)),
        "rms_p95": float(np.percentile(rms, 95)),
        "delta_e2000_median": float(np.median(delta_e)),
        "delta_e2000_p95": float(np.percentile(delta_e, 95)),
        "success_fraction": float(np.mean(status == FitStatus.SUCCESS)),
        "max_steps": int(np.sum(status == FitStatus.MAX_STEPS)),
    }


def calibrate_model(
    wavelengths_nm: Sequence[float] | np.ndarray,
    spectra: np.ndarray,
    *,
    model: SkinModel | None = None,
    constants: Sequence[str] = DEFAULT_CONSTANTS,
    groups: Sequence | None = None,
    free: Sequence[str] | None = None,
    specular_included_deg: float | None = None,
    bandwidth_nm: float | None = None,
    port_radius_mm: float | None = None,
    colour_weight: float = COLOUR_WEIGHT,
    folds: int = 0,
    max_steps: int = 40,
    inner_steps: int = 6,
    name: str = "calibrated",
    chunk_size: int = 512,
    progress: bool = True,
) -> ModelCalibration:
    """Fit a skin model's shared constants to measured spectra, each with its own chromophores.

    Args:
        wavelengths_nm: (m,) increasing wavelengths, nm.
        spectra: (n, m) measured reflectance.
        model: the start (and template) ``SkinModel``: its forward method and the constants not
            calibrated are kept (default ``SkinModel.default()``).
        constants: names of the constants to calibrate (``CONSTANTS``).
        groups: (n,) subject labels: cross-validation folds and the robust standard errors keep a
            subject's spectra together (default: every spectrum its own subject).
        free: each spectrum's fit variables (as ``fit_spectra``; default chromophores, and oil with
            ``specular_included_deg``).
        specular_included_deg, bandwidth_nm, port_radius_mm, colour_weight: the measurement, as in
            ``fit_spectra``.
        folds: subject folds for cross-validation (0: none; the model is then calibrated once).
        max_steps: outer Levenberg-Marquardt steps (each re-solves every spectrum).
        inner_steps: per-spectrum Levenberg-Marquardt steps after each outer trial step.
        name: the calibrated model's name.

    Returns:
        ``ModelCalibration``.
    """
    start = time.perf_counter()
    lam = np.asarray(wavelengths_nm, dtype=float)
    target = np.asarray(spectra, dtype=float)
    if target.ndim != 2 or target.shape[1] != lam.size:
        raise SkinfitInputError(f"spectra must have shape (n, {lam.size}), got {target.shape}")
    if not np.all(np.isfinite(target)):
        raise SkinfitInputError("spectra must be finite (drop or fill incomplete records first)")
    unknown = [c for c in constants if c not in CONSTANTS]
    if unknown:
        raise SkinfitInputError(f"unknown constant(s) {', '.join(unknown)}; choose from {', '.join(CONSTANTS)}")
    constants = tuple(constants)
    model = SkinModel.default() if model is None else model.check()
    groups = np.arange(len(target)) if groups is None else np.asarray(groups)
    if groups.shape != (len(target),):
        raise SkinfitInputError(f"groups must hold one label per spectrum ({len(target)})")
    options = dict(free=free, specular_included_deg=specular_included_deg, bandwidth_nm=bandwidth_nm,
                   port_radius_mm=port_radius_mm, colour_weight=colour_weight)

    calibrated, errors, naive, history = _calibrate(lam, target, model, constants, groups, options, max_steps, inner_steps,
                                                    chunk_size, progress)
    ml = fit_spectra(lam, target, model=calibrated, progress=progress, prior=False, **options)
    calibrated, fit = _with_prior(calibrated, ml, lam, target, options)
    calibrated = calibrated.replace(name=name)  # a static label: the MAP fit under the final prior stands
    fit = dataclasses.replace(fit, model=calibrated.name)

    seconds = time.perf_counter() - start

    cross_validation = None
    if folds:
        start_cv = time.perf_counter()
        cross_validation = _cross_validate(lam, target, model, constants, groups, options, folds, max_steps, inner_steps, chunk_size,
                                           progress)
        cross_validation["seconds"] = time.perf_counter() - start_cv
    values = {c: _scalar(calibrated, c) for c in constants}
    return ModelCalibration(calibrated, values, errors, naive, fit, cross_validation, history, seconds)


def _cross_validate(lam, target, model, constants, groups, options, folds, max_steps, inner_steps, chunk_size, progress):
    """Calibrate without each fold of subjects; fit the fold's spectra with ``fit_spectra``."""
    labels = np.unique(groups)
    rng = np.random.default_rng(0)
    fold_of_label = dict(zip(labels[rng.permutation(len(labels))], np.arange(len(labels)) % folds))
    fold = np.array([fold_of_label[g] for g in groups])
    rms, delta_e, status = np.zeros(len(target)), np.zeros(len(target)), np.zeros(len(target), np.int8)
    rms_ml, delta_e_ml, status_ml = np.zeros(len(target)), np.zeros(len(target)), np.zeros(len(target), np.int8)
    on_bound, on_bound_ml = np.zeros(len(target), bool), np.zeros(len(target), bool)
    fold_constants = []
    for k in range(folds):
        train, test = fold != k, fold == k
        fitted_model = _calibrate(lam, target[train], model, constants, groups[train], options, max_steps, inner_steps, chunk_size,
                                  progress)[0]
        fit = fit_spectra(lam, target[train], model=fitted_model, progress=False, prior=False, **options)
        fitted_model, _ = _with_prior(fitted_model, fit, lam, target[train], options)
        fold_constants.append({c: _scalar(fitted_model, c) for c in constants})
        held_out = fit_spectra(lam, target[test], model=fitted_model, progress=False, **options)
        rms[test], delta_e[test], status[test] = held_out.rms_residual, held_out.delta_e2000, held_out.status
        ml = fit_spectra(lam, target[test], model=fitted_model, prior=False, progress=False, **options)
        rms_ml[test], delta_e_ml[test], status_ml[test] = ml.rms_residual, ml.delta_e2000, ml.status
        on_bound[test], on_bound_ml[test] = on_a_bound(held_out), on_a_bound(ml)
    return {"folds": folds, "fold": fold, "rms_residual": rms, "delta_e2000": delta_e, "status": status, "on_bound": on_bound,
            "maximum_likelihood": {"rms_residual": rms_ml, "delta_e2000": delta_e_ml, "status": status_ml, "on_bound": on_bound_ml},
            "fold_constants": fold_constants}


def _with_prior(model: SkinModel, fit, lam, target, options, rounds: int = 3) -> tuple[SkinModel, SpectralFit]:
    """The population prior of the spectra (empirical Bayes): each free variable's median and robust
    spread (1.4826 MAD, floored at 0.05) in its prior coordinate, re-estimated ``rounds`` times from
    the MAP fits under the previous estimate. The first estimate comes from the maximum-likelihood
    fits, where a weakly determined variable (the melanin blend) often sits on a bound: far out in
    its logit coordinate; the MAP fits pull those in and the spread settles. The noise scale that
    weighs the prior is the median RMS residual of the maximum-likelihood fits. Returns the model and
    its MAP fits of the spectra."""
    noise = float(np.median(fit.rms_residual[fit.status == FitStatus.SUCCESS]))
    current = fit
    for _ in range(rounds):
        ok = current.status == FitStatus.SUCCESS
        names, mean, sd = [], [], []
        for name in current.free:
            z = np.asarray(prior_coordinate(name, np.asarray(current.parameters[name][ok], dtype=float)))
            centre = float(np.median(z))
            names.append(name), mean.append(centre), sd.append(max(1.4826 * float(np.median(np.abs(z - centre))), 0.05))
        model = model.replace(prior=PopulationPrior(tuple(names), jnp.asarray(mean), jnp.asarray(sd), jnp.asarray(noise)))
        current = fit_spectra(lam, target, model=model, prior=True, progress=False, **options)
    return model, current


def _calibrate(lam, target, model, constants, groups, options, max_steps, inner_steps, chunk_size, progress):
    """(model, robust errors, naive errors, cost history) of one calibration."""
    cs = [CONSTANTS[c] for c in constants]
    s = jnp.asarray([_to_coordinate(c, _scalar(model, c.path)) for c in cs])
    measurement = measurement_model(model, options["free"], None, options["port_radius_mm"], options["specular_included_deg"],
                                    options["bandwidth_nm"], options["colour_weight"])
    w = jnp.ones(lam.size)
    kernels = _kernels(measurement, constants, tuple(lam.tolist()))

    # per-spectrum starts: the fit with the start model
    first = fit_spectra(lam, target, model=model, progress=progress, prior=False, **options)
    u = np.stack([to_unbounded(n, first.parameters[n]) for n in measurement.free], axis=1)
    size = pad_size(len(target), chunk_size)

    def solve(s, u, steps):
        return map_batches(lambda a, t: (kernels.inner(s, a, t, w, steps),), (u, target), size)[0]

    def reduced(s, u):
        h, g, cost = map_batches(lambda a, t: kernels.reduced(s, a, t, w), (u, target), size)
        return h, g, cost

    u = solve(s, u, 2 * inner_steps)
    h, g, cost = reduced(s, u)
    total = float(cost.sum())
    history = [total]
    damping = 1e-3
    bar = _progress(progress, max_steps)
    for _ in range(max_steps):
        hs, gs = h.sum(0), g.sum(0)
        scale = np.maximum(np.diag(hs), 1e-12 * np.max(np.diag(hs)) + 1e-300)
        step = -np.linalg.solve(hs + damping * np.diag(scale), gs)
        trial = s + jnp.asarray(np.clip(step, -0.5, 0.5))
        u_trial = solve(trial, u, inner_steps)
        h_trial, g_trial, cost_trial = reduced(trial, u_trial)
        if float(cost_trial.sum()) < total:
            improvement = (total - float(cost_trial.sum())) / total
            s, u, h, g, total = trial, u_trial, h_trial, g_trial, float(cost_trial.sum())
            history.append(total)
            damping = max(damping / 3.0, 1e-9)
            if bar is not None:
                bar.set_postfix(cost=f"{total:.4g}")
            if improvement < 1e-7 and np.max(np.abs(step)) < 1e-4:
                break
        else:
            damping *= 4.0
            if damping > 1e8:
                break
        if bar is not None:
            bar.update()
    if bar is not None:
        bar.close()

    calibrated = with_constants(model, constants, s)
    calibrated = jax.tree_util.tree_map(lambda x: jnp.asarray(np.asarray(x)) if isinstance(x, jax.Array) else x, calibrated)
    robust, naive = _standard_errors(cs, s, h.sum(0), g, groups, total, target.size - len(target) * len(measurement.free) - len(cs))
    return calibrated.check(), dict(zip(constants, robust)), dict(zip(constants, naive)), history


def _standard_errors(cs, s, hessian, gradients, groups, cost, dof):
    """Physical-unit standard errors of the constants: cluster-robust sandwich and Gauss-Newton."""
    inverse = np.linalg.pinv(hessian)
    labels, index = np.unique(groups, return_inverse=True)
    per_group = np.zeros((len(labels), gradients.shape[1]))
    np.add.at(per_group, index, gradients)
    sandwich = inverse @ (per_group.T @ per_group) * len(labels) / max(len(labels) - 1, 1) @ inverse
    naive = inverse * cost / max(dof, 1)
    # d value / d coordinate, for the delta method
    derivative = np.array([float(jax.grad(lambda x, c=c: _from_coordinate(c, x))(s[i])) for i, c in enumerate(cs)])
    return (np.sqrt(np.maximum(np.diag(sandwich), 0.0)) * np.abs(derivative)).tolist(), \
        (np.sqrt(np.maximum(np.diag(naive), 0.0)) * np.abs(derivative)).tolist()


def _progress(enabled, total):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="calibrating constants", unit="step")


_KERNELS = BoundedCache(4)


def _kernels(measurement, constants, wavelengths) -> "_Kernels":
    """One set of compiled kernels per measurement (values included: they are compiled in) and grid."""
    return _KERNELS.get((cache_key(measurement), constants, wavelengths), lambda: _Kernels(measurement, constants, wavelengths))


class _Kernels:
    """The compiled pieces of a calibration: inner solves and the reduced normal equations."""

    def __init__(self, measurement, constants, wavelengths):
        self.measurement, self.constants, self.lam = measurement, constants, np.asarray(wavelengths)

    def _residual(self, s, u, target, w):
        skin = with_constants(self.measurement.skin, self.constants, s)
        measurement = eqx.tree_at(lambda m: m.skin, self.measurement, skin)
        return measurement.residual(u, target, self.lam, w)

    @eqx.filter_jit
    def inner(self, s, u, target, w, steps):
        """``steps`` lock-step Levenberg-Marquardt iterations of every spectrum at constants s."""

        def one(u0, t):
            def body(_, state):
                u, damping = state
                jacobian, r = jax.jacfwd(lambda x: (self._residual(s, x, t, w),) * 2, has_aux=True)(u)
                normal = jacobian.T @ jacobian
                scale = jnp.maximum(jnp.diagonal(normal), 1e-12)
                step = -jnp.linalg.solve(normal + damping * jnp.diag(scale), jacobian.T @ r)
                trial = u + jnp.clip(jnp.where(jnp.all(jnp.isfinite(step)), step, 0.0), -0.5, 0.5)
                better = jnp.sum(self._residual(s, trial, t, w) ** 2) < jnp.sum(r**2)
                return jnp.where(better, trial, u), jnp.where(better, damping / 3.0, damping * 4.0)

            return jax.lax.fori_loop(0, steps, body, (u0, jnp.asarray(1e-3, u0.dtype)))[0]

        return jax.vmap(one)(u, target)

    @eqx.filter_jit
    def reduced(self, s, u, target, w):
        """Per spectrum: Kaufman's reduced normal matrix, gradient and the cost at (u, s)."""

        def one(ui, t):
            k = ui.shape[0]
            both = lambda x: (self._residual(x[k:], x[:k], t, w),) * 2  # noqa: E731 - one pass for u and s
            jacobian, r = jax.jacfwd(both, has_aux=True)(jnp.concatenate([ui, s.astype(ui.dtype)]))
            j_u, j_s = jacobian[:, :k], jacobian[:, k:]
            normal = j_u.T @ j_u + 1e-12 * jnp.eye(j_u.shape[1])
            projected = j_s - j_u @ jnp.linalg.solve(normal, j_u.T @ j_s)
            return projected.T @ projected, projected.T @ r, jnp.sum(r**2)

        return jax.vmap(one)(u, target)


def prior_table(model: SkinModel) -> dict:
    """The model's population prior as {variable: (median value, 16th, 84th percentile)} in physical units."""
    if model.prior is None:
        return {}
    out = {}
    for i, name in enumerate(model.prior.names):
        mean, sd = float(model.prior.mean[i]), float(model.prior.sd[i])
        out[name] = tuple(_from_prior_coordinate(name, z) for z in (mean, mean - sd, mean + sd))
    return out


def _from_prior_coordinate(name, z):
    var = VARIABLES[name]
    if var.prior == "log":
        return float(np.exp(z))
    if var.prior == "logit":
        return float(var.low + (var.high - var.low) / (1.0 + np.exp(-z)))
    return float(z)


