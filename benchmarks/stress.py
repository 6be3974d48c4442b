"""Numerical stress sweep: the forward model, its derivatives and the solvers over extreme inputs.

Run: python -m benchmarks.stress [--points 1000000] [--model dj2006|default] [--out benchmarks/results/pareto]

Two models: DJ2006 on the multipole (``stress.json``) and the package default, the calibrated
constants on tabulated exact transport (``stress_default.json``). Exact transport has no validity
domain to leave: its values must be monotone at every point.

Every point is (parameters, options, wavelength) drawn over the whole valid box and a little of
its edges: melanin, blend, haemoglobin and blood oxygenation in [0, 1] (10 % of draws exactly 0 or
1), epidermis thickness 1e-4-10 mm (log-uniform, endpoints included), wavelengths 250-1000 nm
(both ends in every chunk). Counted per dtype (float64 and float32), each a violation:

- values: NaN or Inf, or reflectance outside [0, 1];
- derivatives (forward mode) with respect to melanin, blend, haemoglobin, oxygenation and
  thickness: NaN or Inf;
- monotonicity: dR/dC_m > 0 or dR/dC_h > 0 (more pigment never brightens skin);
- frequency response R12(q) for q up to 1e4 mm^-1: NaN or Inf, or |R12(q)| > R12(0);
- profiles: R(r) < 0 beyond ``PROFILE_FLOOR`` of the peak (16 eps in float32) where a refined quadrature says the
  model is not negative there (negative tails the model itself has are counted apart);
- finite differences (float64, interior points): the derivative disagrees with a Richardson-
  extrapolated central difference by more than ``FD_RTOL`` relative plus the difference's own
  error estimate (truncation and rounding);
- solvers: ``fit_spectra`` and ``fit_pixels`` on hostile targets (noise, flat, zero, one, above
  one, NaN, negative) return a NaN or Inf value, or a status outside their enums.

Where physics, not numerics, is at stake (monotonicity, |R12(q)| <= R12(0), non-negative
profiles), a violation counts inside the diffusion model's validity domain: the epidermis at
least one transport mean free path thick at that wavelength, sigma_t' d >= 1, which is the
multipole's own condition l = 1/sigma_t' <= d (model notes 5.2); for profiles also
d >= ``PROFILE_MIN_EPIDERMIS_MM``, below which the default Hankel quadrature (q up to 200 mm^-1)
does not resolve the response. Outside, the same failures are counted and reported as
``outside_validity_*``: they are the diffusion approximation's (an optically thin slab in
diffusion theory reflects more as it absorbs more), not the implementation's, and the
transport-exact method is the answer there.

``tests/test_stress.py`` runs a small version of the same sweep and property-based (hypothesis)
tests of the same properties.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import skinfit
from benchmarks._record import provenance
from skinfit.model import (
    HankelQuadrature,
    inverse_kernel,
    skin_profile,
    skin_reflectance,
    stack_transfer,
)

#: The models the sweep stresses: DJ2006 on the multipole, whose validity domain is the multipole's,
#: and the package default (the calibrated constants on tabulated exact transport, valid at any
#: optical thickness: its reflectance must be monotone everywhere).
MODELS = {"dj2006": skinfit.SkinModel.dj2006, "default": skinfit.SkinModel.default}
MODEL = MODELS["dj2006"]()

FIELDS = ("melanin", "melanin_blend", "haemoglobin", "blood_oxygenation", "epidermis_thickness_mm")
PROFILE_FLOOR = 1e-9
PROFILE_MIN_EPIDERMIS_MM = 0.05
FD_RTOL = 1e-6
FREQUENCIES_PER_MM = np.concatenate([[0.0], np.geomspace(1e-3, 1e4, 15)])
WAVELENGTHS_PER_CHUNK = 16


def draw(rng: np.random.Generator, n: int, edges: float = 0.1) -> dict[str, np.ndarray]:
    """n parameter sets over the valid box; a fraction ``edges`` of each field exactly on a bound."""
    fields = {}
    for name in FIELDS[:4]:
        value = rng.uniform(0.0, 1.0, n)
        on_edge = rng.uniform(size=n) < edges
        fields[name] = np.where(on_edge, rng.integers(0, 2, n).astype(float), value)
    thickness = 10.0 ** rng.uniform(-4.0, 1.0, n)
    on_edge = rng.uniform(size=n) < edges
    fields["epidermis_thickness_mm"] = np.where(on_edge, np.where(rng.uniform(size=n) < 0.5, 1e-4, 10.0), thickness)
    return fields


def draw_wavelengths(rng: np.random.Generator, count: int = WAVELENGTHS_PER_CHUNK) -> np.ndarray:
    return np.sort(np.concatenate([[250.0, 1000.0], rng.uniform(250.0, 1000.0, count - 2)]))


def epidermis_optical_thickness(fields: dict, lam: np.ndarray, model=MODEL) -> np.ndarray:
    """sigma_t' d of the epidermis, (n, n_wavelengths): the diffusion model needs it >= 1."""
    fields = {k: np.asarray(v, dtype=float) for k, v in fields.items()}
    epidermis, _ = _model(fields, model).layers(_params(fields), np.asarray(lam, dtype=float))
    return np.asarray(epidermis.thickness * (epidermis.absorption + epidermis.reduced_scattering))


def validity(fields: dict, lam: np.ndarray, model=MODEL) -> np.ndarray:
    """Where the physical properties must hold (n, n_wavelengths): everywhere for exact transport,
    where the epidermis is at least a transport mean free path thick for diffusion."""
    if isinstance(model.method, skinfit.Transport):
        return np.ones((len(fields["melanin"]), len(lam)), bool)
    return epidermis_optical_thickness(fields, lam, model) >= 1.0


def _split(failed: np.ndarray, valid: np.ndarray, name: str) -> dict[str, int]:
    return {name: int(np.sum(failed & valid)), f"outside_validity_{name}": int(np.sum(failed & ~valid))}


def _model(fields, model):
    return model.replace(blood_oxygenation=fields["blood_oxygenation"], epidermis_thickness_mm=fields["epidermis_thickness_mm"])


def _params(fields):
    return skinfit.SkinParams(fields["melanin"], fields["melanin_blend"], fields["haemoglobin"])


def _reflectance(fields, lam, model):
    params = _params(fields)
    return params, skin_reflectance(params, lam, _model(fields, model))


@eqx.filter_jit
def values_and_derivatives(fields, lam, model=MODEL):
    """Reflectance (n, n_wavelengths) and its derivative along each field (dict of the same shape)."""
    f = lambda x: _reflectance(x, lam, model)[1]  # noqa: E731
    value = f(fields)
    derivatives = {}
    for name in FIELDS:
        tangent = {k: jnp.zeros_like(v) if k != name else jnp.ones_like(v) for k, v in fields.items()}
        derivatives[name] = jax.jvp(f, (fields,), (tangent,))[1]
    return value, derivatives


@eqx.filter_jit
def frequency_response(fields, lam, q, model=MODEL):
    """R12(q) of shape (n, n_wavelengths, n_q) (the multipole's, for either model's layers)."""
    layers = _model(fields, model).layers(_params(fields), lam)
    expanded = [jax.tree_util.tree_map(lambda a: jnp.asarray(a)[..., None], layer) for layer in layers]
    return stack_transfer(expanded, q)


def profiles(fields, lam, radii, quadrature=HankelQuadrature(), model=MODEL):
    q, kernel = inverse_kernel(radii, quadrature)
    return skin_profile(_params(fields), lam, radii, q, kernel, _model(fields, model), False)


def check_chunk(fields: dict, lam: np.ndarray, dtype, model=MODEL) -> dict[str, int]:
    """Violation counts of values, derivatives, monotonicity and frequency response for one chunk."""
    valid = validity(fields, lam, model)
    diffusion_valid = epidermis_optical_thickness(fields, lam, model) >= 1.0  # the frequency response is the multipole's
    fields = {k: jnp.asarray(v, dtype) for k, v in fields.items()}
    lam = jnp.asarray(lam, dtype)
    value, derivatives = values_and_derivatives(fields, lam, model)
    value = np.asarray(value)
    # Derivatives are trusted to the rounding of the value they change (eps * R / delta), so a
    # sign is a violation only beyond that.
    noise = 64 * np.finfo(value.dtype).eps * np.maximum(np.abs(value), np.finfo(value.dtype).tiny)
    counts = {
        "points": int(value.size),
        "value_nan_inf": int(np.sum(~np.isfinite(value))),
        "value_outside_0_1": int(np.sum((value < 0) | (value > 1))),
        "derivative_nan_inf": int(sum(np.sum(~np.isfinite(np.asarray(d))) for d in derivatives.values())),
        "points_in_validity": int(np.sum(valid)),
        **_split(np.asarray(derivatives["melanin"]) > noise, valid, "brighter_with_melanin"),
        **_split(np.asarray(derivatives["haemoglobin"]) > noise, valid, "brighter_with_haemoglobin"),
    }
    few = {k: v[:512] for k, v in fields.items()}
    response = np.asarray(frequency_response(few, lam[:4], jnp.asarray(FREQUENCIES_PER_MM, dtype), model))
    at_zero = response[..., :1]
    counts["frequency_points"] = int(response.size)
    counts["frequency_nan_inf"] = int(np.sum(~np.isfinite(response)))
    above = np.abs(response) > at_zero * (1 + 1e-6) + np.finfo(response.dtype).eps
    counts.update(_split(above, diffusion_valid[:512, :4, None], "frequency_above_dc"))
    return counts


#: The reference quadrature that tells the model's own negative tails from quadrature error.
FINE_QUADRATURE = HankelQuadrature(q_max=1000.0, nodes_per_panel=32, phase_per_panel=10.0)


def check_profiles(fields: dict, lam: np.ndarray, radii: np.ndarray, dtype, model=MODEL) -> dict:
    """Profiles: NaN/Inf, and negative values beyond ``PROFILE_FLOOR`` of the peak.

    A negative profile inside the validity domain is checked again in float64 with
    ``FINE_QUADRATURE``: if it stays negative there it is the model's own (DJ2005's flux-only
    exitance gives a thin epidermis over a dark dermis a slightly negative tail, model notes 6) and is
    reported as ``profile_negative_model``; if it does not, the quadrature is at fault and it counts
    as a violation (``profile_negative``).
    """
    # the profile's shape is the multipole's for either method
    valid = (epidermis_optical_thickness(fields, lam, model) >= 1.0) & (fields["epidermis_thickness_mm"][:, None] >= PROFILE_MIN_EPIDERMIS_MM)
    values = np.asarray(profiles({k: jnp.asarray(v, dtype) for k, v in fields.items()}, jnp.asarray(lam, dtype), radii, model=model))
    peak = np.max(np.abs(values), axis=-1)
    floor = max(PROFILE_FLOOR, 16 * float(np.finfo(values.dtype).eps))  # float32 rounds at ~1e-7 of the peak
    negative = np.max(-values, axis=-1) > floor * peak  # (n, n_wavelengths)
    own = np.zeros_like(negative)
    for j in range(len(lam)):
        rows = np.flatnonzero(negative[:, j] & valid[:, j])
        for start in range(0, rows.size, 32):
            chunk = np.resize(rows[start:start + 32], 32)  # fixed shape: one compilation
            fine = np.asarray(profiles({k: jnp.asarray(v[chunk]) for k, v in fields.items()}, jnp.asarray(lam[j:j + 1]), radii,
                                       FINE_QUADRATURE, model))[:, 0]
            fine_peak = np.max(np.abs(fine), axis=-1)
            own[chunk, j] = np.max(-fine, axis=-1) > PROFILE_FLOOR * fine_peak
    of_peak = np.max(-values, axis=-1) / np.maximum(peak, np.finfo(values.dtype).tiny)
    return {
        "profile_points": int(values.size),
        "profile_points_in_validity": int(np.sum(valid) * radii.size),
        "profile_nan_inf": int(np.sum(~np.isfinite(values))),
        "profile_negative": int(np.sum(negative & valid & ~own)),
        "profile_negative_model": int(np.sum(negative & valid & own)),
        "profile_negative_model_worst_of_peak": float(np.max(of_peak[negative & valid & own], initial=0.0)),
        "outside_validity_profile_negative": int(np.sum(negative & ~valid)),
    }


def check_finite_differences(rng: np.random.Generator, n: int = 512, model=MODEL) -> dict[str, int]:
    """Forward-mode derivatives against central differences, float64, interior points."""
    fields = draw(rng, n, edges=0.0)
    for name in FIELDS[:4]:
        fields[name] = 0.02 + 0.96 * fields[name]
    fields["epidermis_thickness_mm"] = np.clip(fields["epidermis_thickness_mm"], 1e-3, 5.0)
    lam = draw_wavelengths(rng, 8)
    _, derivatives = values_and_derivatives({k: jnp.asarray(v) for k, v in fields.items()}, jnp.asarray(lam), model)
    values = lambda x: np.asarray(values_and_derivatives({k: jnp.asarray(v) for k, v in x.items()}, jnp.asarray(lam), model)[0])  # noqa: E731
    base = values(fields)
    mismatched = 0
    for name in FIELDS:
        step = 1e-5 * (fields[name] if name == "epidermis_thickness_mm" else np.ones(n))
        central = []
        for h in (step, 0.5 * step):
            up, down = dict(fields), dict(fields)
            up[name], down[name] = fields[name] + h, fields[name] - h
            central.append((values(up) - values(down)) / (2 * h[:, None]))
        # Richardson extrapolation; the two differences' disagreement estimates its own error.
        fd = (4 * central[1] - central[0]) / 3
        rounding = 16 * np.finfo(float).eps * np.abs(base) / (0.5 * step[:, None])
        fd_error = np.abs(central[1] - central[0]) + rounding
        ad = np.asarray(derivatives[name])
        mismatched += int(np.sum(np.abs(fd - ad) > FD_RTOL * np.abs(ad) + fd_error))
    return {"fd_points": n * lam.size * len(FIELDS), "fd_mismatch": mismatched}


def hostile_spectra(rng: np.random.Generator, n: int, m: int) -> np.ndarray:
    """Reflectance targets no skin has: noise, flat, zero, one, above one, negative, NaN, Inf."""
    kinds = [
        lambda: rng.uniform(0, 1, m),
        lambda: np.full(m, rng.uniform(0, 1)),
        lambda: np.zeros(m),
        lambda: np.ones(m),
        lambda: np.full(m, 1.2),
        lambda: -rng.uniform(0, 0.1, m),
        lambda: np.where(rng.uniform(size=m) < 0.1, np.nan, 0.3),
        lambda: np.where(rng.uniform(size=m) < 0.1, np.inf, 0.3),
        lambda: np.linspace(0.0, 1.0, m) ** rng.uniform(0.2, 5),
    ]
    return np.stack([kinds[i % len(kinds)]() for i in range(n)])


def check_solvers(rng: np.random.Generator, n_spectra: int = 180, n_pixels: int = 4096) -> dict[str, int]:
    lam = np.arange(400.0, 701.0, 10.0)
    fit = skinfit.fit_spectra(lam, hostile_spectra(rng, n_spectra, lam.size), progress=False)
    values = [fit.rms_residual, fit.delta_e2000, fit.fitted, *fit.parameters.values(), *fit.standard_errors.values()]
    spectra_bad = sum(int(np.sum(~np.isfinite(np.asarray(v)))) for v in values)
    spectra_status = int(np.sum(~np.isin(fit.status, [s.value for s in skinfit.FitStatus])))

    pixels = rng.uniform(-0.1, 1.2, (n_pixels, 3)) ** rng.choice([1.0, 3.0], (n_pixels, 1))
    pixels[rng.uniform(size=n_pixels) < 0.02, 0] = np.nan
    pixels[rng.uniform(size=n_pixels) < 0.02, 1] = np.inf
    maps = skinfit.fit.fit_pixels(pixels, progress=False)
    pixel_bad = sum(int(np.sum(~np.isfinite(v))) for k, v in maps.items() if k != "status")
    pixel_status = int(np.sum(~np.isin(maps["status"], [s.value for s in skinfit.PixelStatus])))
    return {
        "solver_spectra": n_spectra,
        "solver_pixels": n_pixels,
        "solver_nan_inf": spectra_bad + pixel_bad,
        "solver_bad_status": spectra_status + pixel_status,
    }


VIOLATIONS = (
    "value_nan_inf", "value_outside_0_1", "derivative_nan_inf", "brighter_with_melanin", "brighter_with_haemoglobin",
    "frequency_nan_inf", "frequency_above_dc", "profile_nan_inf", "profile_negative", "fd_mismatch",
    "solver_nan_inf", "solver_bad_status",
)


def sweep(points: int = 1_000_000, seed: int = 0, chunk_sets: int = 4096, profile_sets: int = 256,
          solvers: bool = True, progress: bool = True, model=MODEL) -> dict:
    """Run the sweep of ``model`` with at least ``points`` model points per dtype; returns counts per dtype."""
    rng = np.random.default_rng(seed)
    report = {}
    radii = np.geomspace(1e-3, 50.0, 64)
    for dtype in (jnp.float64, jnp.float32):
        totals: dict[str, float] = {}
        chunks = int(np.ceil(points / (chunk_sets * WAVELENGTHS_PER_CHUNK)))
        for i in range(chunks):
            counts = check_chunk(draw(rng, chunk_sets), draw_wavelengths(rng), dtype, model)
            for key, value in counts.items():
                totals[key] = totals.get(key, 0) + value
            if progress:
                print(f"  stress {model.name} {jnp.dtype(dtype).name}: chunk {i + 1}/{chunks}", end="\r", flush=True)
        counts = check_profiles(draw(rng, profile_sets), draw_wavelengths(rng), radii, dtype, model)
        totals.update(counts)
        report[jnp.dtype(dtype).name] = totals
    report["model"] = model.name
    report["float64"].update(check_finite_differences(rng, model=model))
    if solvers:
        report["solvers"] = check_solvers(rng)
    parts = [part for part in report.values() if isinstance(part, dict)]
    report["violations"] = sum(int(part.get(k, 0)) for part in parts for k in VIOLATIONS)
    report["outside_validity"] = sum(int(v) for part in parts for k, v in part.items() if k.startswith("outside_validity_"))
    if progress:
        print()
    return report


def result_file(model_name: str) -> str:
    """The results file of a model's sweep: ``stress.json`` (DJ2006), ``stress_<name>.json`` for the others."""
    return "stress.json" if model_name == "dj2006" else f"stress_{model_name}.json"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--points", type=int, default=1_000_000, help="model points per dtype (default 1e6)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="benchmarks/results/pareto")  # where python -m benchmarks writes it
    parser.add_argument("--model", default="dj2006", choices=tuple(MODELS))
    args = parser.parse_args(argv)
    start = time.perf_counter()
    report = sweep(args.points, args.seed, model=MODELS[args.model]())
    report["seconds"] = time.perf_counter() - start
    report.update(provenance())
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / result_file(args.model)).write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))
    return 0 if report["violations"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
