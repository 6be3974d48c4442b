"""Where a measured spectrum's fit spends its time, and what a better start buys (issue: the fast path).

    python -m benchmarks.spectra_starts [--data ../shared/data] [--issa 1000] [--repeats 5] [--out benchmarks/results]

On measured spectra (the 100 NIST forearm averages shipped in ``data/``; ``--issa`` ISSA face spectra
from the shared data folder, never shipped, the draw of ``benchmarks.fit_measured``), with the default
model, for the chromophores and for the chromophores + oil (specular included at 8 degrees):

1. **Stages of today's fit**: microseconds per spectrum in the warm start (table, Gauss-Newton), the bounded polish and
   the diagnostics (the solver's private stages, timed around their calls; the fastest of
   ``--repeats`` calls).
2. **Start schedules** (``SolverSettings``), timed interleaved in one process (minimum and median of
   ``--repeats`` calls each): the default (two table starts, two Gauss-Newton steps each, three more
   from the better); one table start straight to the polish; the better of two table starts (one
   evaluation each) straight to the polish. Each with its mean evaluations (``iterations``), its
   statuses and how its optima compare with the default's (relative cost).
3. **A start from the table's quadratic model** (an experiment, not in the package): each table entry
   also holds the spectrum's Hessian in physical coordinates, and a target's start is a damped
   projected Newton on that quadratic model (colour and prior terms exact), in each start group, the
   best kept. Reported: its distance from the default fit's optimum (range fractions) against the
   Gauss-Newton-corrected table start the solver uses, and the bounded polish's evaluations from each.

Writes ``spectra_starts.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import skinfit
from benchmarks._record import provenance
from benchmarks.fit_measured import measured_spectra
from benchmarks.fit_realistic import WAVELENGTHS, nist_spectra
from skinfit.fit import SolverSettings, _spectra
from skinfit.fit._transport_polish import bounded_polish
from skinfit.fit._variables import VARIABLES, from_unbounded
from skinfit.model import model_with_options

ROOT = Path(__file__).resolve().parents[1]
CHROMOPHORES = ("melanin", "melanin_blend", "haemoglobin")
FREE_SETS = {
    "chromophores": {"free": CHROMOPHORES},
    "+ oil": {"free": (*CHROMOPHORES, "oil"), "specular_included_deg": 8.0},
}
SCHEDULES = {
    "default: 2 table starts, 2 + 3 Gauss-Newton steps": SolverSettings(),
    "1 table start, straight to the polish": SolverSettings(candidates=1, start_steps=0, refine_steps=0),
    "better of 2 table starts, straight to the polish": SolverSettings(candidates=2, start_steps=0, refine_steps=0),
}


def stage_seconds(spectra, options, repeats: int) -> dict:
    """Microseconds per spectrum by stage of the fastest of ``repeats`` default fits (after compilation),
    timed around the solver's stages."""
    solver = _spectra._Solver
    spent = {"run": 0.0, "_polish": 0.0, "diagnostics": 0.0}
    originals = {name: getattr(solver, name) for name in spent}

    def timed(name):
        def call(*args, **kwargs):
            start = time.perf_counter()
            out = originals[name](*args, **kwargs)
            spent[name] += time.perf_counter() - start
            return out
        return call

    try:
        for name in spent:
            setattr(solver, name, timed(name))
        skinfit.fit_spectra(WAVELENGTHS, spectra, progress=False, **options)  # compiles
        best = None
        for _ in range(repeats):  # the call with the least total time, and its stages
            for name in spent:
                spent[name] = 0.0
            start = time.perf_counter()
            skinfit.fit_spectra(WAVELENGTHS, spectra, progress=False, **options)
            total = time.perf_counter() - start
            if best is None or total < best[0]:
                best = (total, dict(spent))
    finally:
        for name, original in originals.items():
            setattr(solver, name, original)
    total, spent = best
    n = len(spectra)
    return {"us_per_spectrum": {"total": 1e6 * total / n, "warm_start": 1e6 * (spent["run"] - spent["_polish"]) / n,
                                "polish": 1e6 * spent["_polish"] / n, "diagnostics": 1e6 * spent["diagnostics"] / n,
                                "rest": 1e6 * (total - spent["run"] - spent["diagnostics"]) / n}}


def compare_schedules(spectra, options, repeats: int) -> dict:
    fits = {label: skinfit.fit_spectra(WAVELENGTHS, spectra, progress=False, settings=s, **options) for label, s in SCHEDULES.items()}
    times = {label: [] for label in SCHEDULES}
    for _ in range(repeats):  # interleaved: the schedules share the machine's load
        for label, settings in SCHEDULES.items():
            start = time.perf_counter()
            skinfit.fit_spectra(WAVELENGTHS, spectra, progress=False, settings=settings, **options)
            times[label].append(time.perf_counter() - start)
    reference = next(iter(fits.values())).rms_residual ** 2
    rows = {}
    for label, fit in fits.items():
        relative = (fit.rms_residual**2 - reference) / reference
        rows[label] = {
            "us_per_spectrum_min": 1e6 * min(times[label]) / len(spectra),
            "us_per_spectrum_median": 1e6 * float(np.median(times[label])) / len(spectra),
            "evaluations_mean": float(fit.iterations.mean()),
            "evaluations_median": float(np.median(fit.iterations)),
            "max_steps": int(np.sum(fit.status == skinfit.FitStatus.MAX_STEPS)),
            "higher_cost_than_default_1e-6": int(np.sum(relative > 1e-6)),
            "lower_cost_than_default_1e-6": int(np.sum(relative < -1e-6)),
            "largest_relative_cost_increase": float(relative.max()),
        }
    return rows


class QuadraticStart:
    """Starts from the warm-start table's entries with the spectrum's Hessian: per start group, a damped
    projected Newton on the entry's second-order model of the spectrum (the colour and prior terms
    evaluated exactly on it), the best model cost kept."""

    def __init__(self, measurement, settings: SolverSettings, newton_steps: int = 5):
        self.m, self.lam, self.steps = measurement, WAVELENGTHS, newton_steps
        self.w = jnp.ones(WAVELENGTHS.size)
        solver = _spectra._Solver(tuple(WAVELENGTHS.tolist()), tuple([1.0] * WAVELENGTHS.size), settings)
        self.table = table = solver.table(measurement)
        free = measurement.free
        self.low = jnp.array([VARIABLES[n].low for n in free])
        self.span = jnp.array([VARIABLES[n].high - VARIABLES[n].low for n in free])
        groups, entries, f = table.grid_u.shape
        theta = jnp.stack([from_unbounded(n, table.grid_u[..., i]) for i, n in enumerate(free)], axis=-1).reshape(-1, f)
        spectrum = lambda t: measurement.spectrum_of_free(t, self.lam)  # noqa: E731

        def entry(t):
            return spectrum(t), jax.jacfwd(spectrum)(t), jax.jacfwd(jax.jacfwd(spectrum))(t)

        start = time.perf_counter()
        parts = jax.block_until_ready(jax.jit(lambda t: jax.lax.map(entry, t, batch_size=256))(theta))
        self.build_s = time.perf_counter() - start
        self.theta, self.spectra, self.jacobian, self.hessian = (a.reshape(groups, entries, *a.shape[1:]) for a in (theta, *parts))
        self.run = jax.jit(self._starts)

    def _model_cost(self, step, theta0, s0, j0, h0, target):
        m = self.m
        spectrum = s0 + j0 @ step + 0.5 * jnp.einsum("mij,i,j->m", h0, step, step)
        evaluation = jnp.concatenate([spectrum, m.prior_residual(m.values_of_free(theta0 + step))]) if m.use_prior else spectrum
        return jnp.sum(m.residual_of_evaluation(evaluation, target, self.lam, self.w) ** 2)

    def _newton(self, theta0, s0, j0, h0, target):
        step, damping = jnp.zeros_like(theta0), 1e-3
        cost = self._model_cost(step, theta0, s0, j0, h0, target)
        for _ in range(self.steps):
            gradient = jax.grad(self._model_cost)(step, theta0, s0, j0, h0, target) * self.span
            hessian = jax.hessian(self._model_cost)(step, theta0, s0, j0, h0, target) * jnp.outer(self.span, self.span)
            x = (theta0 + step - self.low) / self.span
            keep = ~(((x <= 1e-6) & (gradient > 0)) | ((x >= 1 - 1e-6) & (gradient < 0)))
            system = jnp.where(keep[:, None] & keep[None, :], hessian, 0.0) + jnp.diag(
                jnp.where(keep, damping * jnp.maximum(jnp.diag(hessian), 1e-12), 1.0))
            dx = jnp.clip(jnp.linalg.solve(system, jnp.where(keep, -gradient, 0.0)), -0.1, 0.1)
            trial = self.low + self.span * jnp.clip(x + dx, 0.0, 1.0) - theta0
            trial_cost = self._model_cost(trial, theta0, s0, j0, h0, target)
            better = jnp.isfinite(trial_cost) & (trial_cost <= cost)
            step, cost = jnp.where(better, trial, step), jnp.where(better, trial_cost, cost)
            damping = jnp.where(better, 0.3 * damping, 10.0 * damping)
        return theta0 + step, cost

    def _starts(self, target):
        table = self.table
        z = ((table.weights * target - table.mean) @ table.basis.T).astype(table.coords.dtype)
        nearest = table._nearest(z)
        groups = jnp.arange(nearest.shape[1])[None, :]
        picked = (a[groups, nearest] for a in (self.theta, self.spectra, self.jacobian, self.hessian))
        theta, cost = jax.vmap(jax.vmap(self._newton, in_axes=(0, 0, 0, 0, None)))(*picked, target)
        return theta[jnp.arange(theta.shape[0]), jnp.argmin(cost, axis=1)]


def compare_starts(spectra, options) -> dict:
    skin = model_with_options(None)
    measurement = _spectra.measurement_model(skin, options["free"], None, None, options.get("specular_included_deg"), None,
                                             _spectra.COLOUR_WEIGHT, skin.prior is not None)
    free = measurement.free
    reference = skinfit.fit_spectra(WAVELENGTHS, spectra, progress=False, **options)
    optimum = np.stack([reference.parameters[n] for n in free], axis=1)
    span = np.array([VARIABLES[n].high - VARIABLES[n].low for n in free])
    quadratic = QuadraticStart(measurement, SolverSettings())
    target = jnp.asarray(spectra)
    u = np.asarray(quadratic.table.candidates(target, 1))[:, 0]
    starts = {"table entry + Gauss-Newton correction (today's candidate)":
              np.stack([from_unbounded(n, u[:, i]) for i, n in enumerate(free)], axis=1)}
    starts["quadratic model + damped Newton (experiment)"] = np.asarray(quadratic.run(target))
    start = time.perf_counter()
    jax.block_until_ready(quadratic.run(target))
    quadratic_us = 1e6 * (time.perf_counter() - start) / len(spectra)
    s = SolverSettings()
    polish = bounded_polish(free, tuple(WAVELENGTHS.tolist()), tuple([1.0] * WAVELENGTHS.size), s.step_tol, s.stationarity_tol,
                            reduction_tol=s.reduction_tol, logarithmic=False)
    cost = lambda theta: np.asarray(jnp.sum(jax.vmap(  # noqa: E731
        lambda t, y: measurement.residual_of_free(t, y, WAVELENGTHS, quadratic.w))(jnp.asarray(theta), target) ** 2, axis=1))
    reference_cost = cost(optimum)
    out = {"quadratic_start_build_s": quadratic.build_s, "quadratic_start_us_per_spectrum": quadratic_us, "starts": {}}
    for label, theta in starts.items():
        error = np.abs(theta - optimum) / span
        polished, steps, done = polish.run(measurement, theta, spectra, 120, 128, False, fixed_batch=True)
        relative = (cost(polished) - reference_cost) / reference_cost
        out["starts"][label] = {
            "range_fraction_error_median": dict(zip(free, np.median(error, axis=0).tolist())),
            "range_fraction_error_p90": dict(zip(free, np.percentile(error, 90, axis=0).tolist())),
            "polish_evaluations_mean": float(steps.mean()),
            "polish_evaluations_histogram": {int(k): int(c) for k, c in zip(*np.unique(steps, return_counts=True))},
            "polish_converged": int(done.sum()),
            "higher_cost_than_default_1e-6": int(np.sum(relative > 1e-6)),
        }
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    parser.add_argument("--issa", type=int, default=1000, help="ISSA face spectra (0: none)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    data_sets = {"NIST forearm, 100 subjects": nist_spectra()}
    if args.issa and (Path(args.data) / "issa-subset" / "issa_subset.csv").exists():
        data_sets[f"ISSA faces, {args.issa} spectra"] = measured_spectra(Path(args.data), args.issa)
    record = {**provenance(), "model": model_with_options(None).name, "repeats": args.repeats, "rows": []}
    for data_label, spectra in data_sets.items():
        for free_label, options in FREE_SETS.items():
            row = {"data": data_label, "free": free_label, "spectra": len(spectra)}
            row["stages"] = stage_seconds(spectra, options, args.repeats)
            row["schedules"] = compare_schedules(spectra, options, args.repeats)
            row["starts"] = compare_starts(spectra, options)
            record["rows"].append(row)
            print(f"{data_label}, {free_label}: stages (us/spectrum) "
                  + ", ".join(f"{k} {v:.0f}" for k, v in row["stages"]["us_per_spectrum"].items()), flush=True)
            for label, r in row["schedules"].items():
                print(f"  {label}: {r['us_per_spectrum_min']:.0f} us (min), {r['evaluations_mean']:.1f} evaluations, "
                      f"{r['higher_cost_than_default_1e-6']} higher cost", flush=True)
            for label, r in row["starts"]["starts"].items():
                print(f"  start {label}: polish {r['polish_evaluations_mean']:.1f} evaluations, error median "
                      + ", ".join(f"{k} {v:.1e}" for k, v in r["range_fraction_error_median"].items()), flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "spectra_starts.json").write_text(json.dumps(record, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
