"""Forward-model benchmark: accuracy against independent references and time after compilation.

Run: python -m benchmarks.forward_model [--out benchmarks/results]
Prints a table and writes forward_model.json. Baselines are measured in the same run:
* profiles: the 2-D FFT recipe (NumPy, N = 2048, dx = 0.02 mm; pbrt-v2-skin's approach) per wavelength;
* reflectance: a NumPy port of the same closed form (what users write today), one spectrum at a time.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

import skinfit
from benchmarks._record import provenance
from skinfit.model import profile
from tests import reference as ref

#: These timings compare skinfit with NumPy/SciPy ports of Donner & Jensen 2006's diffusion model, so
#: they evaluate that model (the calibrated default is re-measured by benchmarks.fit_measured).
MODEL = skinfit.SkinModel.dj2006()


def timed(fn, repeat=5):
    fn()  # compile / warm up
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - start)
    return best


def chromophore_table(wl):
    """Chromophore spectra at ``wl`` as NumPy arrays, computed once for the NumPy baseline."""
    from skinfit import model as ch

    names = ("baseline", "eumelanin", "pheomelanin", "oxyhaemoglobin", "deoxyhaemoglobin")
    table = {n: np.asarray(getattr(ch, f"{n}_absorption")(wl)) for n in names}
    table["scattering"] = np.asarray(ch.epidermis_reduced_scattering(wl))
    return table


def numpy_reflectance(c_m, beta_m, c_h, t):
    """Straight NumPy port of the closed-form model (the baseline); parameters scalars or (n, 1) arrays."""
    base = t["baseline"]
    mel = beta_m * t["eumelanin"] + (1 - beta_m) * t["pheomelanin"]
    blood = 0.75 * t["oxyhaemoglobin"] + 0.25 * t["deoxyhaemoglobin"]
    sa1, sa2 = c_m * mel + (1 - c_m) * base, c_h * blood + (1 - c_h) * base
    ss1 = t["scattering"]
    ss2 = 0.5 * ss1

    def a(eta):
        f = -1.44 / eta**2 + 0.71 / eta + 0.668 + 0.0636 * eta
        return (1 + f) / (1 - f)

    def slab(sa, ss, d, a_top, a_bot):
        st = sa + ss
        alb, dd, l, k = ss / st, 1 / (3 * st), np.minimum(1 / st, d), np.sqrt(3 * sa * st)
        z0, zd = 2 * a_top * dd, 2 * a_bot * dd
        span = d + z0 + zd
        ratio = lambda x: np.expm1(-2 * k * x) / np.expm1(-2 * k * span)  # noqa: E731
        r = 0.5 * alb * np.exp(-k * l) * (1 + np.exp(-2 * k * z0)) * ratio(d + zd - l)
        t = 0.5 * alb * np.exp(-k * (d - l)) * (1 + np.exp(-2 * k * zd)) * ratio(l + z0)
        return r, t

    r1p, t1p = slab(sa1, ss1, 0.25, a(1.4), a(1.0))
    r1m, t1m = slab(sa1, ss1, 0.25, a(1.0), a(1.4))
    st2 = sa2 + ss2
    alb2, d2, l2, k2 = ss2 / st2, 1 / (3 * st2), 1 / st2, np.sqrt(3 * sa2 * st2)
    r2 = 0.5 * alb2 * (np.exp(-k2 * l2) + np.exp(-k2 * (l2 + 4 * a(1.0) * d2)))
    return (1 - 1 / 36) * (r1p + t1p * r2 * t1m / (1 - r2 * r1m))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="benchmarks/results")
    args = parser.parse_args(argv)
    results = provenance()

    # 1. Accuracy of the closed form against image sums (model notes 5.3 slab cases + skin epidermis)
    q = np.array([0.0, 1.0, 5.0, 20.0, 100.0])
    rows = []
    for d, sa, ss in [(0.25, 0.05, 5.0), (0.1, 0.01, 10.0), (0.01, 5.0, 500.0), (10.0, 0.01, 2.0)]:
        exact = skinfit.model.slab_response(sa, ss, d, 1.4, 1.0, q)
        row = {"slab": f"d={d} mm, sa={sa}, ss'={ss}"}
        for n in (0, 5, 50, 2000):
            r, t = ref.image_sum_transfer(sa, ss, d, 1.4, 1.0, q, n=n)
            for key, got, want in (("R", r, exact.reflect_top), ("T", t, exact.transmit_top)):
                want = np.asarray(want)
                ok = want > 1e-290  # transmission through 10 mm at q = 100 underflows to 0 in both
                row[f"err_{key}_{2 * n + 1}_dipoles"] = float(np.max(np.abs(got[ok] / want[ok] - 1)))
        rows.append(row)
    results["closed_form_vs_image_sum"] = rows

    # 2. Profile table: 61 wavelengths x 256 radii, time after compilation, vs the 2-D FFT baseline
    light = skinfit.preset("light")
    wl = np.arange(400.0, 701.0, 5.0)
    radii = np.geomspace(1e-3, 20.0, 256)
    fn = jax.jit(lambda p: profile(p, wl, radii, model=MODEL))
    start = time.perf_counter()
    jax.block_until_ready(fn(light))
    compile_s = time.perf_counter() - start
    table_s = timed(lambda: fn(light))
    layers = skinfit.model.skin_layers(light, wl, model=MODEL)
    transfer = jax.jit(lambda qq: skinfit.model.stack_transfer([jax.tree_util.tree_map(lambda a: a[..., None, None], layer) for layer in layers], qq))
    freq = 2 * np.pi * np.fft.fftfreq(2048, 0.02)
    qgrid = np.sqrt(freq[:, None] ** 2 + freq[None, :] ** 2)
    transfer(qgrid)

    def fft_baseline():
        grid = np.asarray(transfer(qgrid))  # (61, 2048, 2048)
        return [np.real(np.fft.ifft2(g)) for g in grid]

    start = time.perf_counter()
    fft_baseline()
    fft_s = time.perf_counter() - start
    fine = np.geomspace(1e-5, 200.0, 4000)
    energy = np.trapezoid(2 * np.pi * fine**2 * np.asarray(profile(light, wl, fine, model=MODEL)), np.log(fine), axis=-1)
    r12 = np.asarray(skinfit.model.stack_transfer(layers, 0.0))
    results["profile_table"] = {"shape": [61, 256], "compile_s": compile_s, "time_s": table_s,
                                "fft_baseline_s": fft_s, "speedup_vs_fft": fft_s / table_s,
                                "max_energy_error": float(np.max(np.abs(energy / r12 - 1)))}

    # 3. Reflectance spectra: batch of 10,000 x 61 wavelengths vs a NumPy loop
    rng = np.random.default_rng(1)
    n = 10_000
    batch = skinfit.SkinParams(melanin=rng.uniform(0.001, 0.5, n), melanin_blend=rng.uniform(0, 1, n), haemoglobin=rng.uniform(0.001, 0.1, n))
    refl = jax.jit(lambda p: skinfit.diffuse_reflectance(p, wl, model=MODEL))
    jax_s = timed(lambda: refl(batch))
    table = chromophore_table(wl)
    c_m, beta_m, c_h = (np.asarray(v) for v in (batch.melanin, batch.melanin_blend, batch.haemoglobin))
    start = time.perf_counter()
    numpy_loop = np.stack([numpy_reflectance(c_m[i], beta_m[i], c_h[i], table) for i in range(n)])
    numpy_loop_s = time.perf_counter() - start
    numpy_vec_s = timed(lambda: numpy_reflectance(c_m[:, None], beta_m[:, None], c_h[:, None], table))
    results["reflectance_batch"] = {
        "spectra": n, "wavelengths": wl.size, "jax_s": jax_s, "jax_us_per_spectrum": 1e6 * jax_s / n,
        "numpy_loop_s": numpy_loop_s, "speedup_vs_numpy_loop": numpy_loop_s / jax_s,
        "numpy_vectorised_s": numpy_vec_s, "speedup_vs_numpy_vectorised": numpy_vec_s / jax_s,
        "max_abs_diff_vs_numpy": float(np.max(np.abs(np.asarray(refl(batch)) - numpy_loop))),
    }

    # 4. Sweep for NaN/Inf in values and gradients
    m = 200_000
    x = rng.uniform(0, 1, (m, 4))
    thick = 10 ** rng.uniform(-4, 1, m)
    lam = rng.uniform(250, 1000, m)

    def one(xi, t, l):
        p = skinfit.SkinParams(melanin=xi[0], melanin_blend=xi[1], haemoglobin=xi[2])
        return skinfit.diffuse_reflectance(p, l[None], model=MODEL, blood_oxygenation=xi[3], epidermis_thickness_mm=t)[0]

    values = jax.jit(jax.vmap(one))(x, thick, lam)
    grads = jax.jit(jax.vmap(jax.grad(one)))(x, thick, lam)
    results["sweep"] = {"points": m, "nan_or_inf_values": int(np.sum(~np.isfinite(np.asarray(values)))),
                        "nan_or_inf_gradients": int(np.sum(~np.isfinite(np.asarray(grads)))),
                        "min": float(np.min(values)), "max": float(np.max(values))}

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "forward_model.json").write_text(json.dumps(results, indent=2))
    table = markdown(results)
    (out / "forward_model.md").write_text(table)
    print(table)


def markdown(res):
    """The forward-model table (docs/performance.md)."""
    epi, thin = res["closed_form_vs_image_sum"][0], res["closed_form_vs_image_sum"][1]
    pt, rb, sw = res["profile_table"], res["reflectance_batch"], res["sweep"]
    rows = [
        f"Measured {res['date']} on {res['machine']}.",
        "",
        "| what | result |",
        "|---|---|",
        f"| 11-dipole image sum (pbrt-v2-skin) vs closed form, epidermis-like slab (d 0.25, σa 0.05, σs' 5) | R {epi['err_R_11_dipoles']:.1e}, T {epi['err_T_11_dipoles']:.1e} relative |",
        f"| same, thin weakly absorbing slab (d 0.1, σa 0.01, σs' 10) | R {thin['err_R_11_dipoles']:.1e}, T {thin['err_T_11_dipoles']:.1e} relative |",
        f"| single dipole (damlaren's epidermis) vs closed form, epidermis-like slab | R {epi['err_R_1_dipoles']:.2f}, T {epi['err_T_1_dipoles']:.2f} relative |",
        f"| 4001-dipole image sum vs closed form, worst of 4 slabs (0.01-10 mm) | {max(r['err_R_4001_dipoles'] for r in res['closed_form_vs_image_sum']):.1e} |",
        f"| profile energy ∫2πrR dr vs R12(0), light skin, 61 wavelengths | {pt['max_energy_error']:.1e} relative |",
        f"| profile table 61 wavelengths x 256 radii, after compilation | {1e3 * pt['time_s']:.1f} ms (compile {pt['compile_s']:.2f} s); 2-D FFT recipe (N 2048) {pt['fft_baseline_s']:.1f} s, {pt['speedup_vs_fft']:.0f}x slower |",
        f"| reflectance, {rb['spectra']:,} spectra x {rb['wavelengths']} wavelengths | {1e3 * rb['jax_s']:.1f} ms ({rb['jax_us_per_spectrum']:.1f} µs/spectrum); NumPy loop {rb['speedup_vs_numpy_loop']:.0f}x slower, vectorised NumPy {rb['speedup_vs_numpy_vectorised']:.1f}x slower; max difference {rb['max_abs_diff_vs_numpy']:.0e} |",
        f"| NaN/Inf sweep: {sw['points']:,} random points (all fractions 0-1, epidermis 1e-4-10 mm, 250-1000 nm) | {sw['nan_or_inf_values']} in values, {sw['nan_or_inf_gradients']} in gradients; reflectance in [{sw['min']:.4f}, {sw['max']:.4f}] |",
    ]
    return "\n".join(rows) + "\n"


if __name__ == "__main__":
    main()
