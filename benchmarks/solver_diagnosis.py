"""Why measured spectra cost more than model spectra: the lock-step Gauss-Newton on real skin.

    python -m benchmarks.solver_diagnosis [--data ../shared/data] [--issa 1000] [--synthetic 1000]

On the NIST forearm set, the ISSA face spectra (the draw of ``benchmarks.fit_measured``) and 1,000
noise-free model spectra, with DJ2006's constants and with the calibrated model (chromophores free,
400-700 nm every 10 nm), it records:

- **bounds**: the fraction of the final fits (``fit_spectra``) with each variable on a bound;
- **Gauss-Newton**, with the solver's step (projected: variables on a bound held, steps near a bound
  taken in the range fraction) and with the plain sine-coordinate step it replaced: how many
  spectra the warm start leaves unconverged (they go on to the bounded polish), and from where it
  ends, 60 more undamped steps: the fraction of those unconverged whose first step sits at the 0.5
  clip, the fraction that reach a step of ``step_tol``, the median contraction per step between
  steps 10 and 20 of those still moving (linear convergence: below 1; none: 1 or more) and the
  fraction of the unconverged that made no progress from step 10 to 20.

Writes ``benchmarks/results/solver_diagnosis.json``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import skinfit
from benchmarks._record import provenance
from benchmarks.fit_measured import measured_spectra
from benchmarks.fit_realistic import WAVELENGTHS, nist_spectra, synthetic
from skinfit.fit import _spectra
from skinfit.fit._linalg import solve_normal

ROOT = Path(__file__).resolve().parents[1]
CHROMOPHORES = ("melanin", "melanin_blend", "haemoglobin")
STEPS = 60


class PlainSolver(_spectra._Solver):
    """The solver with the Gauss-Newton step it had before 2026-12-02: the sine coordinates, no bound
    handling (a bound is u = +-pi/2, where the variable's Jacobian column vanishes)."""

    def _propose(self, measurement, u, evaluation, target):
        r, jacobian = measurement.linearised_residual(*evaluation, target, self.lam, self.w)
        step = solve_normal(jacobian.T @ jacobian, -(jacobian.T @ r))
        return jnp.sum(r**2), jnp.clip(step, -0.5, 0.5)


def walk(solver, measurement, u, target):
    """``STEPS`` undamped steps of ``solver`` from u: the largest |step| component at each."""
    def body(u, _):
        _, step = solver._propose(measurement, u, solver._evaluate(measurement, u), target)
        return u + step, jnp.max(jnp.abs(step))

    return jax.lax.scan(body, u, None, length=STEPS)[1]


def gauss_newton(solver, measurement, target) -> dict:
    """The warm start, then ``STEPS`` more undamped steps from where it ends."""
    u, converged = solver._warm_start(measurement, solver.table(measurement), target)
    steps = np.asarray(jax.jit(jax.vmap(lambda a, t: walk(solver, measurement, a, t)))(u, target))
    tol = solver.settings.step_tol
    open_ = ~np.asarray(converged)
    reached = steps <= tol
    moving = open_ & (steps[:, 10] > tol)  # still moving after 10 more steps
    return {
        "unconverged_after_warm_start": int(open_.sum()),
        "step_at_clip_fraction": float(np.mean(steps[open_, 0] >= 0.5 - 1e-12)) if open_.any() else 0.0,
        "converged_within_steps_fraction": float(np.mean(reached[open_].any(axis=1))) if open_.any() else 1.0,
        # linear convergence: below 1; none: 1 or more (over ten steps, per step)
        "contraction_median": float(np.median((steps[moving, 20] / steps[moving, 10]) ** 0.1)) if moving.any() else None,
        "no_progress_fraction": float(np.sum(steps[moving, 20] >= steps[moving, 10]) / max(open_.sum(), 1)),
    }


def diagnose(label: str, spectra: np.ndarray, model) -> dict:
    measurement = _spectra.measurement_model(model, CHROMOPHORES, None, None, None, None, _spectra.COLOUR_WEIGHT,
                                             model.prior is not None)
    settings = _spectra.SolverSettings()
    grid = tuple(WAVELENGTHS.tolist())
    weights = (1.0,) * len(grid)
    target = jnp.asarray(spectra)
    fit = skinfit.fit_spectra(WAVELENGTHS, spectra, model=model, free=CHROMOPHORES, progress=False)
    out = {
        "spectra": len(spectra),
        "on_bound_fraction": {name: float(np.mean(skinfit.fit.on_a_bound(_only(fit, name)))) for name in CHROMOPHORES},
        "iterations_median": float(np.median(fit.iterations)),
        "gauss_newton_projected": gauss_newton(_spectra._solver(measurement.static_key, grid, weights, settings), measurement, target),
        "gauss_newton_plain": gauss_newton(PlainSolver(grid, weights, settings), measurement, target),
    }
    print(label, model.name, json.dumps(out), flush=True)
    return out


def _only(fit, name):
    """``fit`` with only ``name`` free (for ``on_a_bound`` per variable)."""
    import dataclasses

    return dataclasses.replace(fit, free=(name,))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(ROOT.parent / "shared" / "data"))
    parser.add_argument("--issa", type=int, default=1000, help="ISSA face spectra (0: none)")
    parser.add_argument("--synthetic", type=int, default=1000, help="noise-free model spectra")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    dj = skinfit.SkinModel.dj2006()
    sets = {"synthetic, noise-free": synthetic(dj, args.synthetic, 0.0, np.random.default_rng(2026))[1], "NIST forearm": nist_spectra()}
    if args.issa and (Path(args.data) / "issa-subset" / "issa_subset.csv").exists():
        sets[f"ISSA faces ({args.issa})"] = measured_spectra(Path(args.data), args.issa)
    rows = []
    for label, spectra in sets.items():
        for model in (dj, skinfit.SkinModel.default()):
            if label.startswith("synthetic") and model is not dj:
                continue
            rows.append({"data": label, "model": model.name, **diagnose(label, spectra, model)})
    record = {**provenance(), "wavelengths_nm": [400, 700, 10], "free": list(CHROMOPHORES), "gauss_newton_steps": STEPS,
              "rows": rows, "reproduce": "python -m benchmarks.solver_diagnosis"}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "solver_diagnosis.json").write_text(json.dumps(record, indent=1) + "\n")
    print(f"wrote {out / 'solver_diagnosis.json'}")
    return record


if __name__ == "__main__":
    main()
