"""Transport against diffusion: cost per spectrum, and the NIST fits with both methods side by side.

Run: python -m benchmarks.transport_fit [--n 100] [--out benchmarks/results]

1. Cost: the 31-wavelength (400-700 nm) reflectance of 64 random parameter sets with each method,
   timed after compilation (median of three), and a transport fit's Jacobian.
2. Fits: the NIST subject averages (400-700 nm every 10 nm), DJ2006 constants, chromophores free,
   fitted with method="diffusion" and method="transport" (first call, compilation included: what a
   user waits). Writes transport_fit.json (summary), transport_fit_nist.csv (every subject, both
   methods) and transport_fit_nist.png (fitted parameters and residuals side by side).
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


def cost(batch: int = 64) -> dict:
    rng = np.random.default_rng(1)
    params = skinfit.SkinParams(*(jnp.asarray(a) for a in (rng.uniform(0.001, 0.5, batch), rng.uniform(0, 1, batch), rng.uniform(0.001, 0.1, batch))))
    lam = jnp.asarray(WAVELENGTHS)
    seconds = {
        method: median_seconds(jax.jit(lambda p, m=method: skinfit.diffuse_reflectance(p, lam, method=m, model=MODEL)), params) / batch
        for method in ("diffusion", "transport")
    }

    def spectrum(x):
        return skinfit.diffuse_reflectance(skinfit.SkinParams(x[0], x[1], x[2]), lam, method="transport", model=MODEL)

    x = jnp.stack([params.melanin, params.melanin_blend, params.haemoglobin], axis=-1)[:8]
    jacobian = median_seconds(jax.jit(jax.vmap(jax.jacfwd(spectrum))), x) / len(x)
    return {
        "diffusion_s_per_spectrum": seconds["diffusion"],
        "transport_s_per_spectrum": seconds["transport"],
        "transport_over_diffusion": seconds["transport"] / seconds["diffusion"],
        "transport_jacobian_s_per_spectrum": jacobian,
    }


def nist_fits(n: int) -> tuple[dict, list[dict]]:
    nist = read_nist(NIST)
    spectra = np.stack([np.interp(WAVELENGTHS, nist.wavelengths_nm, s) for s in nist.average[:n]])
    fits, seconds = {}, {}
    for method in ("diffusion", "transport"):
        start = time.perf_counter()
        fits[method] = skinfit.fit_spectra(WAVELENGTHS, spectra, method=method, model=MODEL, progress=False)
        seconds[method] = time.perf_counter() - start
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
    _plot(fits, spectra)
    return summary, rows


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
    parser.add_argument("--out", default="benchmarks/results")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    result = {**provenance(), "device": jax.devices()[0].device_kind, "cost": cost(args.batch)}
    print(json.dumps(result["cost"], indent=1), flush=True)
    result["nist"], rows = nist_fits(args.n)
    import matplotlib.pyplot as plt

    plt.savefig(out / "transport_fit_nist.png", dpi=110)
    (out / "transport_fit.json").write_text(json.dumps(result, indent=1) + "\n")
    header = list(rows[0])
    lines = [",".join(header)] + [",".join(f"{r[k]:.6g}" if isinstance(r[k], float) else str(r[k]) for k in header) for r in rows]
    (out / "transport_fit_nist.csv").write_text("\n".join(lines) + "\n")
    print(json.dumps(result["nist"], indent=1))
    return 0


if __name__ == "__main__":
    main()
