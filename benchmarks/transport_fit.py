"""Transport against diffusion: cost per spectrum, and the NIST fits with each method side by side.

Run: python -m benchmarks.transport_fit [--n 100] [--direct] [--out benchmarks/results]

1. Cost: the 31-wavelength (400-700 nm) reflectance of 64 random parameter sets with
   method="diffusion", "transport" (the tabulated adding-doubling) and "transport-direct" (the direct
   solve), timed after compilation (median of three), with each one's first call (compilation
   included), and the Jacobian a transport fit needs, by the table and directly.
2. The colour table that image fits use, built from the tabulated transport (first call: what an
   image fit waits for), beside diffusion's.
3. Fits: the NIST subject averages (400-700 nm every 10 nm), DJ2006 constants, chromophores free,
   fitted with method="diffusion" and method="transport" (and, with ``--direct``, method=
   "transport-direct": about 20 minutes on a 2-core CPU), first call (compilation included: what a
   user waits) and a second call (compiled). Writes transport_fit.json (summary),
   transport_fit_nist.csv (every subject, every method) and transport_fit_nist.png (fitted
   parameters and residuals side by side).
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
from benchmarks._timing import median_seconds
from skinfit.io import read_nist

KEYS = ("melanin", "melanin_blend", "haemoglobin")
WAVELENGTHS = np.arange(400.0, 701.0, 10.0)
NIST = Path(__file__).resolve().parents[1] / "data" / "nist_skin_reflectance_250-1000nm.csv"
#: This benchmark records DJ2006's constants through diffusion and through direct adding-doubling.
MODEL = skinfit.SkinModel.dj2006()


METHODS = ("diffusion", "transport", "transport-direct")


def _first_call(function, *args) -> float:
    start = time.perf_counter()
    jax.block_until_ready(function(*args))
    return time.perf_counter() - start


def cost(batch: int = 64) -> dict:
    rng = np.random.default_rng(1)
    params = skinfit.SkinParams(*(jnp.asarray(a) for a in (rng.uniform(0.001, 0.5, batch), rng.uniform(0, 1, batch), rng.uniform(0.001, 0.1, batch))))
    lam = jnp.asarray(WAVELENGTHS)
    out = {}
    for method in METHODS:
        function = jax.jit(lambda p, m=method: skinfit.diffuse_reflectance(p, lam, method=m, model=MODEL))
        key = method.replace("-", "_")
        out[f"{key}_first_call_s"] = _first_call(function, params)
        out[f"{key}_s_per_spectrum"] = median_seconds(function, params) / batch

    x = jnp.stack([params.melanin, params.melanin_blend, params.haemoglobin], axis=-1)[:8]
    for method in ("transport", "transport-direct"):
        def spectrum(x, m=method):
            return skinfit.diffuse_reflectance(skinfit.SkinParams(x[0], x[1], x[2]), lam, method=m, model=MODEL)

        out[f"{method.replace('-', '_')}_jacobian_s_per_spectrum"] = median_seconds(jax.jit(jax.vmap(jax.jacfwd(spectrum))), x) / len(x)
    out["transport_over_diffusion"] = out["transport_s_per_spectrum"] / out["diffusion_s_per_spectrum"]
    out["transport_direct_over_diffusion"] = out["transport_direct_s_per_spectrum"] / out["diffusion_s_per_spectrum"]
    out["transport_direct_over_transport"] = out["transport_direct_s_per_spectrum"] / out["transport_s_per_spectrum"]
    return out


def colour_tables() -> dict:
    """The image fits' colour table (blend 0.7, default nodes) built from each method: first call."""
    from skinfit.colorimetry import colour_table

    out = {}
    for method in ("diffusion", "transport"):
        start = time.perf_counter()
        table = colour_table(0.7, method=method, model=MODEL)
        jax.block_until_ready(jax.tree_util.tree_leaves(table))
        out[f"{method}_build_s"] = time.perf_counter() - start
    return out


def nist_fits(n: int, methods=("diffusion", "transport")) -> tuple[dict, list[dict]]:
    nist = read_nist(NIST)
    spectra = np.stack([np.interp(WAVELENGTHS, nist.wavelengths_nm, s) for s in nist.average[:n]])
    fits, seconds, again = {}, {}, {}
    for method in methods:
        start = time.perf_counter()
        fits[method] = skinfit.fit_spectra(WAVELENGTHS, spectra, method=method, model=MODEL, progress=False)
        seconds[method] = time.perf_counter() - start
        if method != "transport-direct":  # compiled now: what the next batch of this shape costs
            start = time.perf_counter()
            skinfit.fit_spectra(WAVELENGTHS, spectra, method=method, model=MODEL, progress=False)
            again[method] = time.perf_counter() - start
    rows = []
    for i, subject in enumerate(nist.subjects[:n]):
        row = {"subject": subject}
        for method, fit in fits.items():
            for key in KEYS:
                row[f"{method}_{key}"] = float(fit.parameters[key][i])
            row[f"{method}_rms"] = float(fit.rms_residual[i])
            row[f"{method}_dE2000"] = float(fit.delta_e2000[i])
            row[f"{method}_status"] = skinfit.FitStatus(int(fit.status[i])).name
            row[f"{method}_iterations"] = int(fit.iterations[i])
        rows.append(row)
    summary = {"spectra": n}
    for method, fit in fits.items():
        summary[method] = {
            "seconds_first_call": seconds[method],
            "seconds_compiled": again.get(method),
            "max_steps": int(np.sum(fit.status == skinfit.FitStatus.MAX_STEPS)),
            "success": int(np.sum(fit.status == skinfit.FitStatus.SUCCESS)),
            "rms_median": float(np.median(fit.rms_residual)),
            "rms_max": float(np.max(fit.rms_residual)),
            "dE2000_median": float(np.median(fit.delta_e2000)),
            "dE2000_max": float(np.max(fit.delta_e2000)),
            "iterations_median": float(np.median(fit.iterations)),
            **{f"{key}_median": float(np.median(fit.parameters[key])) for key in KEYS},
            **{f"{key}_range": [float(np.min(fit.parameters[key])), float(np.max(fit.parameters[key]))] for key in KEYS},
        }
    d, t = fits["diffusion"], fits["transport"]
    summary["transport_over_diffusion_median"] = {
        key: float(np.median(t.parameters[key] / np.maximum(d.parameters[key], 1e-12))) for key in ("melanin", "haemoglobin")
    }
    summary["rms_transport_below_diffusion"] = int(np.sum(t.rms_residual < d.rms_residual))
    if "transport-direct" in fits:  # the table's fits against the direct solve's
        direct = fits["transport-direct"]
        summary["transport_vs_direct"] = {
            f"{key}_max_relative_difference": float(np.max(np.abs(t.parameters[key] / np.maximum(direct.parameters[key], 1e-12) - 1)))
            for key in ("melanin", "haemoglobin")
        }
        summary["transport_vs_direct"]["rms_max_difference"] = float(np.max(np.abs(t.rms_residual - direct.rms_residual)))
    _plot(fits, spectra)
    return summary, rows


LABELS = {"diffusion": "diffusion", "transport": "transport (table)", "transport-direct": "transport (direct solve)"}


def summary_markdown(result: dict) -> str:
    """The NIST table of docs/transport.md, from the saved record (a test keeps the two equal)."""
    nist, cost, tables = result["nist"], result["cost"], result["colour_table"]
    methods = [m for m in METHODS if m in nist]
    lines = [f"Measured {result['date']} on {result['machine']} (`python -m benchmarks.transport_fit"
             f"{' --direct' if 'transport-direct' in nist else ''}`), {result['model']} constants, {nist['spectra']} NIST subject "
             "averages, 400-700 nm every 10 nm, chromophores free, g = 0.8:", "",
             "| | " + " | ".join(LABELS[m] for m in methods) + " |", "|---|" + "---|" * len(methods)]

    def row(label, cell):
        lines.append(f"| {label} | " + " | ".join(cell(nist[m], m) for m in methods) + " |")

    row("SUCCESS / MAX_STEPS", lambda r, m: f"{r['success']} / {r['max_steps']}")
    row("RMS residual, median / worst", lambda r, m: f"{r['rms_median']:.4f} / {r['rms_max']:.4f}")
    row("CIEDE2000, median / worst", lambda r, m: f"{r['dE2000_median']:.2f} / {r['dE2000_max']:.2f}")
    for key, name in (("melanin", "melanin C_m"), ("haemoglobin", "haemoglobin C_h")):
        row(f"{name}, median (range)", lambda r, m, k=key: f"{r[k + '_median']:.4f} ({r[k + '_range'][0]:.4f}-{r[k + '_range'][1]:.4f})")
    row("melanin blend β_m, median", lambda r, m: f"{r['melanin_blend_median']:.3f}")
    row("the 100 fits, first call (compilation included)", lambda r, m: f"{r['seconds_first_call']:,.1f} s")
    row("the 100 fits again (compiled)", lambda r, m: "-" if r["seconds_compiled"] is None else f"{r['seconds_compiled']:.2f} s")
    row("reflectance, µs per 31-wavelength spectrum (batch of 64, compiled)",
        lambda r, m: f"{1e6 * cost[m.replace('-', '_') + '_s_per_spectrum']:,.1f}")
    lines += ["", f"Image fits' colour table (129 x 129 nodes, first call): diffusion {tables['diffusion_build_s']:.1f} s, "
                  f"transport (table) {tables['transport_build_s']:.1f} s."]
    if "transport_vs_direct" in nist:
        d = nist["transport_vs_direct"]
        lines += ["", f"The table's fits against the direct solve's: melanin within {d['melanin_max_relative_difference']:.1e}, "
                      f"haemoglobin within {d['haemoglobin_max_relative_difference']:.1e} (relative), RMS residual within "
                      f"{d['rms_max_difference']:.1e}."]
    return "\n".join(lines) + "\n"


def _plot(fits, spectra):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d, t = fits["diffusion"], fits["transport"]
    figure, axes = plt.subplots(1, 4, figsize=(17, 4))
    for ax, key in zip(axes[:2], ("melanin", "haemoglobin")):
        ax.scatter(d.parameters[key], t.parameters[key], s=10)
        top = max(d.parameters[key].max(), t.parameters[key].max())
        ax.plot([0, top], [0, top], "k:", lw=1)
        ax.set(xlabel=f"{key} (diffusion fit)", ylabel=f"{key} (transport fit)")
    axes[2].scatter(d.rms_residual, t.rms_residual, s=10)
    top = max(d.rms_residual.max(), t.rms_residual.max())
    axes[2].plot([0, top], [0, top], "k:", lw=1)
    axes[2].set(xlabel="RMS residual (diffusion)", ylabel="RMS residual (transport)")
    i = int(np.argmax(d.rms_residual))
    axes[3].plot(WAVELENGTHS, spectra[i], "k.", label="NIST")
    axes[3].plot(WAVELENGTHS, d.fitted[i], label="diffusion fit")
    axes[3].plot(WAVELENGTHS, t.fitted[i], label="transport fit")
    axes[3].set(xlabel="wavelength (nm)", ylabel="reflectance", title="worst diffusion fit")
    axes[3].legend()
    figure.tight_layout()
    return figure


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=100, help="NIST subjects to fit")
    parser.add_argument("--batch", type=int, default=64, help="spectra per timed batch")
    parser.add_argument("--direct", action="store_true", help="also fit with the direct solve (about 20 min on a 2-core CPU)")
    parser.add_argument("--out", default="benchmarks/results")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    result = {**provenance(), "device": jax.devices()[0].device_kind, "model": MODEL.name, "cost": cost(args.batch)}
    print(json.dumps(result["cost"], indent=1), flush=True)
    result["colour_table"] = colour_tables()
    print(json.dumps(result["colour_table"], indent=1), flush=True)
    result["nist"], rows = nist_fits(args.n, METHODS if args.direct else METHODS[:2])
    import matplotlib.pyplot as plt

    plt.savefig(out / "transport_fit_nist.png", dpi=110)
    (out / "transport_fit.json").write_text(json.dumps(result, indent=1) + "\n")
    (out / "transport_fit.md").write_text(summary_markdown(result))
    header = list(rows[0])
    lines = [",".join(header)] + [",".join(f"{r[k]:.6g}" if isinstance(r[k], float) else str(r[k]) for k in header) for r in rows]
    (out / "transport_fit_nist.csv").write_text("\n".join(lines) + "\n")
    print(json.dumps(result["nist"], indent=1))
    return 0


if __name__ == "__main__":
    main()
