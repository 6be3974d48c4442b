"""Image-fit benchmark: seconds per megapixel, error against full least squares, a SciPy baseline
and the peak memory of a 4096 x 4096 input.

Run: python -m benchmarks.fit_image [--size 512] [--scipy-n 200] [--memory-size 4096] [--out benchmarks/results]

The input is the issue's round-trip image: smooth maps (melanin 0.002-0.4, haemoglobin 0.002-0.08,
shading 0.5-1) rendered through the exact model and camera model. Timed after compilation (median
of --repeats runs):

- table only: the inverse-table warm start and the closed-form shading, no iteration;
- warm start + polish (the default ``fit_image``): Levenberg-Marquardt on the colour spline,
  stragglers through optimistix;
- + exact polish: 2 more Gauss-Newton steps on the exact forward model (``exact_steps=2``), which is
  the full least-squares optimum the others are measured against.

Baseline: scipy.optimize.least_squares per pixel (C_m, C_h, shading; bounds; trf) on a NumPy port
of the model and camera model, from a typical skin start, timed on a subset. Peak memory: a
4096 x 4096 EXR tiled from the rendering, fitted by ``skinfit fit-image`` in a fresh process
(maximum resident set size of the child).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.optimize

import skinfit
from benchmarks._record import provenance
from benchmarks.forward_model import chromophore_table, numpy_reflectance
from skinfit import render_maps
from skinfit.colorimetry import COLOUR_WAVELENGTHS_NM, linear_srgb_weights
from skinfit.fit import fit_pixels

#: These timings compare skinfit with NumPy/SciPy ports of Donner & Jensen 2006's diffusion model, so
#: they evaluate that model (the calibrated default is re-measured by benchmarks.fit_measured).
MODEL = skinfit.SkinModel.dj2006()


def smooth_maps(n):
    """Smooth (n, n) maps over the issue's box: melanin 0.002-0.4, haemoglobin 0.002-0.08, shading 0.5-1."""
    y, x = np.mgrid[0:n, 0:n] / (n - 1)
    melanin = 0.002 + 0.398 * (0.5 + 0.5 * np.sin(3 * x + 1) * np.cos(2 * y))
    haemoglobin = 0.002 + 0.078 * (0.5 + 0.5 * np.cos(4 * x * y + 0.5))
    return melanin, haemoglobin, 0.5 + 0.25 * (x + y)


def timed(function, repeats):
    function()  # compile
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        out = function()
        times.append(time.perf_counter() - start)
    return out, float(np.median(times))


def errors(maps, reference, ok):
    return {
        name: {"median": float(np.median(np.abs(maps[name] - reference[name])[ok])), "p99": float(np.percentile(np.abs(maps[name] - reference[name])[ok], 99))}
        for name in ("melanin", "haemoglobin")
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--size", type=int, default=512)
    parser.add_argument("--scipy-n", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--memory-size", type=int, default=4096, help="0 skips the peak-memory run")
    parser.add_argument("--out", default="benchmarks/results")
    args = parser.parse_args(argv)
    melanin, haemoglobin, shading = smooth_maps(args.size)
    rgb = render_maps(melanin, haemoglobin, shading, model=MODEL)
    pixels = rgb.reshape(-1, 3)
    megapixels = len(pixels) / 1e6
    truth = {"melanin": melanin.ravel(), "haemoglobin": haemoglobin.ravel()}

    start = time.perf_counter()
    fit_pixels(pixels, progress=False, model=MODEL)
    first = time.perf_counter() - start
    runs = {
        "table_only": dict(steps=0, max_straggler_rounds=0, lm_max_steps=0),
        "warm_start_and_polish": {},
        "with_exact_polish": dict(exact_steps=2),
    }
    results = {}
    for name, options in runs.items():
        maps, seconds = timed(lambda: fit_pixels(pixels, progress=False, model=MODEL, **options), args.repeats)
        results[name] = {"maps": maps, "s_per_megapixel": seconds / megapixels}
    exact = results["with_exact_polish"]["maps"]
    ok = exact["status"] == 0
    summary = {}
    for name, r in results.items():
        summary[name] = {
            "s_per_megapixel": r["s_per_megapixel"],
            "success_fraction": float(np.mean(r["maps"]["status"] == 0)),
            "error_vs_full_least_squares": errors(r["maps"], exact, ok),
            "error_vs_truth": errors(r["maps"], truth, ok),
        }

    # SciPy baseline: per pixel, (C_m, C_h, shading), NumPy model
    table = chromophore_table(COLOUR_WAVELENGTHS_NM)
    weights = linear_srgb_weights(COLOUR_WAVELENGTHS_NM)
    rng = np.random.default_rng(3)
    subset = rng.choice(len(pixels), min(args.scipy_n, len(pixels)), replace=False)
    start = time.perf_counter()
    scipy_error = []
    for i in subset:
        res = scipy.optimize.least_squares(
            lambda x: x[2] * (weights @ numpy_reflectance(x[0], 0.7, x[1], table)) - pixels[i],
            x0=[0.05, 0.02, 1.0], bounds=([0, 0, 0], [0.5, 0.15, np.inf]), xtol=1e-12, ftol=1e-12, gtol=1e-12,
        )
        scipy_error.append(abs(res.x[0] - truth["melanin"][i]))
    scipy_s_per_megapixel = (time.perf_counter() - start) / len(subset) * 1e6
    scipy_error = np.array(scipy_error)

    memory = None
    if args.memory_size:
        memory = peak_memory(rgb, args.memory_size)

    result = {
        **provenance(),
        "image": f"{args.size}x{args.size} smooth maps (issue round trip)",
        "first_call_s_incl_table_and_compile": first,
        **summary,
        "scipy_least_squares": {
            "s_per_megapixel": scipy_s_per_megapixel,
            "pixels_timed": len(subset),
            "melanin_error_median": float(np.median(scipy_error)),
            "melanin_within_1e-4": float(np.mean(scipy_error <= 1e-4)),
        },
        "speedup_vs_scipy": {name: scipy_s_per_megapixel / s["s_per_megapixel"] for name, s in summary.items()},
        "peak_memory": memory,
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "fit_image.json").write_text(json.dumps(result, indent=2))
    (out / "fit_image.md").write_text(markdown(result) + "\n")
    print(json.dumps(result, indent=2))


def markdown(result: dict) -> str:
    """The docs table (docs/fitting-images.md, kept equal to fit_image.md by tests/test_readme.py)."""
    def errors(path, name):
        e = result[path]["error_vs_full_least_squares"][name]
        return "(the reference)" if path == "with_exact_polish" else f"{e['median']:.1e} / {e['p99']:.1e}"

    rows = [("table only (warm start, no iteration)", "table_only"), ("warm start + polish (`fit_pixels`, no priors)", "warm_start_and_polish"),
            ("+ exact polish (`--exact-steps 2`)", "with_exact_polish")]
    lines = [f"Measured {result['date']} on {result['machine']} (commit {result['git_commit'][:10]}), {result['image']}.", "",
             "| path | s per megapixel | pixels SUCCESS | melanin error | haemoglobin error |", "|---|---|---|---|---|"]
    for label, path in rows:
        s = result[path]
        success = "(not iterated)" if path == "table_only" else f"{100 * s['success_fraction']:.1f} %"
        lines.append(f"| {label} | {s['s_per_megapixel']:.3g} | {success} | {errors(path, 'melanin')} | {errors(path, 'haemoglobin')} |")
    lines.append(f"| `scipy.optimize.least_squares` per pixel, NumPy model | {result['scipy_least_squares']['s_per_megapixel']:,.0f} | | | |")
    return "\n".join(lines)


def peak_memory(rgb, size):
    """Peak resident memory (GiB) and time of ``skinfit fit-image`` on a size x size EXR tiled
    from ``rgb``, in a fresh process."""
    from skinfit.io import write_exr

    reps = -(-size // rgb.shape[0])
    big = np.tile(rgb, (reps, reps, 1))[:size, :size]
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "big.exr"
        write_exr(path, {c: big[..., i].astype(np.float32) for i, c in enumerate("RGB")})
        del big
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        start = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "skinfit", "fit-image", str(path), "--out", str(Path(folder) / "out"), "--quiet"],
            capture_output=True, text=True,
        )
        seconds = time.perf_counter() - start
        peak_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    if done.returncode != 0:
        return {"error": done.stderr[-500:]}
    return {
        "pixels": size * size,
        "peak_rss_gib": peak_kib / 2**20,
        "peak_rss_note": "maximum resident set of the child process (includes the JAX runtime and the image)" if peak_kib > before else "",
        "wall_s_incl_start_and_compile": seconds,
        "summary_line": done.stdout.strip().splitlines()[-1],
    }


if __name__ == "__main__":
    main()
