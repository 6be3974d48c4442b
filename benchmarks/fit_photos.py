"""Image fits on real inputs with the default settings: speed, coverage, reconstruction, smoothness.

Run: python -m benchmarks.fit_photos [--scipy-n 100] [--memory-size 4096] [--out benchmarks/results]

Inputs: the demo portrait (512 x 512) and the 0.4 MP capture with nothing given (the faces are found;
statistics over the face-skin region), and, each with its mask:

- the demo photo (NASA portrait, 8-bit sRGB, warm studio light) with the shipped skin mask
  ``tests/data/eileen_collins_skin_mask.png`` (made without the skin model: ``benchmarks.demo_skin_mask``);
- a real cross-polarised face albedo capture (BioSkin test image 2, MIT) downscaled 4x, shipped in
  ``tests/data/``; and, where ``../shared/data/face-albedo/`` exists, the 0.4 MP original. Its mask is
  a head mask: it holds hair, brows, closed eyes, lips and some background as well as skin.

Per input, with ``fit_image``'s defaults (calibrated model, white balance fitted, population prior,
light regularisation): seconds per megapixel of a second call (compiled, colour table built), the
first call, the share of the mask ``SUCCESS``, CIEDE2000 over the whole mask (every pixel the fit
wrote), the share of skin pixels whose melanin is off its 3 x 3 median by a factor 2, and the skin's
median melanin and haemoglobin. Baseline in the same run: ``scipy.optimize.least_squares`` per pixel
(C_m, C_h, shading; maximum likelihood) on the same model through a jitted single-pixel colour, on
``--scipy-n`` skin pixels of each input. Peak memory: ``skinfit fit-image`` with its defaults on a
4096 x 4096 tiling of the capture, in a fresh process, and within each of its stages. A second table: where the second call's
time goes, stage by stage (``ImageFit.stage_seconds``). And the demo's first fit in fresh processes:
with skinfit's caches off, filling them, and reading them (a user's later sessions).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize

import skinfit
from benchmarks._record import provenance
from skinfit.colorimetry import COLOUR_WAVELENGTHS_NM, linear_srgb_weights, params_rgb
from skinfit.fit import PixelStatus, fit_image, speckle_fraction
from skinfit.io import read_linear_rgb, read_mask

ROOT = Path(__file__).resolve().parents[1]
INPUTS = {
    # no mask: the faces are found (skinfit.segmentation); the statistics are over the face's skin region
    "demo portrait (512x512, faces found)": (ROOT / "data/astronaut_eileen_collins.png", None),
    "albedo capture (501x798, faces found)": (ROOT.parent / "shared/data/face-albedo/face2_albedo.png", None),
    "demo photo (160x192, skin mask)": (ROOT / "tests/data/eileen_collins_face.png", ROOT / "tests/data/eileen_collins_skin_mask.png"),
    "albedo capture, 1/4 (125x199, head mask)": (ROOT / "tests/data/face2_albedo_quarter.png", ROOT / "tests/data/face2_mask_quarter.png"),
    "albedo capture (501x798, head mask)": (ROOT.parent / "shared/data/face-albedo/face2_albedo.png",
                                            ROOT.parent / "shared/data/face-albedo/face2_mask.png"),
}


def read_input(name: str):
    """(linear RGB, boolean mask) of ``INPUTS[name]``, or None where its file is not there (the shared
    data folder is not always beside the checkout)."""
    image, mask_path = INPUTS[name]
    if not image.exists():
        print(f"{name}: {image} not found, skipped")
        return None
    rgb, _ = read_linear_rgb(image)
    return rgb, None if mask_path is None else read_mask(mask_path) > 0


def measure(rgb, mask) -> dict:
    start = time.perf_counter()
    fit_image(rgb, mask=mask, progress=False)
    first = time.perf_counter() - start
    start = time.perf_counter()
    fit = fit_image(rgb, mask=mask, progress=False)
    seconds = time.perf_counter() - start
    faces = fit.faces
    if mask is None:
        mask = fit.region == 1 if fit.region is not None else np.ones(fit.status.shape, bool)
    skin = fit.status == PixelStatus.SUCCESS
    delta_e = fit.residual_dE2000[mask]
    return {
        "fit": fit,
        "pixels": int(mask.size),
        "mask_pixels": int(mask.sum()),
        "first_call_s": first,
        "s": seconds,
        "s_per_megapixel": seconds / (mask.size / 1e6),
        "mask_success_fraction": float(skin[mask].mean()),
        "statuses_in_mask": {s.name: int(np.sum(fit.status[mask] == s)) for s in PixelStatus if np.any(fit.status[mask] == s)},
        "mask_dE2000_median": float(np.median(delta_e)),
        "mask_dE2000_p95": float(np.percentile(delta_e, 95)),
        "melanin_speckle_fraction": speckle_fraction(fit.melanin, skin),
        "melanin_median": float(np.median(fit.melanin[skin])),
        "haemoglobin_median": float(np.median(fit.haemoglobin[skin])),
        "white_balance": list(fit.white_balance),
        "white_balance_sd": fit.white_balance_sd,
        "faces": faces,
        "melanin_blend": fit.summary()["melanin_blend"],
        "stage_s": {**fit.stage_seconds, "other": seconds - sum(fit.stage_seconds.values())},
    }


def scipy_baseline(rgb, fit, n, seed=0) -> dict:
    """Seconds per megapixel of per-pixel SciPy least squares on ``n`` skin pixels of the fit."""
    model = skinfit.SkinModel.default()
    weights = jnp.asarray(linear_srgb_weights(COLOUR_WAVELENGTHS_NM))
    blend = fit.summary()["melanin_blend"]
    colour = jax.jit(lambda x: x[2] * params_rgb(jnp.stack([x[0], blend, x[1]])[None], weights, model)[0])
    jacobian = jax.jit(jax.jacfwd(lambda x: x[2] * params_rgb(jnp.stack([x[0], blend, x[1]])[None], weights, model)[0]))
    skin = np.flatnonzero(fit.status.ravel() == PixelStatus.SUCCESS)
    pick = np.random.default_rng(seed).choice(skin, min(n, skin.size), replace=False)
    pixels = rgb.reshape(-1, 3)[pick] / np.asarray(fit.white_balance)
    colour(jnp.array([0.05, 0.02, 1.0])).block_until_ready()
    jacobian(jnp.array([0.05, 0.02, 1.0])).block_until_ready()
    start = time.perf_counter()
    for target in pixels:
        scipy.optimize.least_squares(
            lambda x: np.asarray(colour(jnp.asarray(x))) - target, x0=[0.05, 0.02, 1.0], jac=lambda x: np.asarray(jacobian(jnp.asarray(x))),
            bounds=([0, 0, 0], [0.5, 0.15, np.inf]), xtol=1e-10, ftol=1e-10,
        )
    return {"s_per_megapixel": (time.perf_counter() - start) / len(pixels) * 1e6, "pixels_timed": int(len(pixels))}


#: ``skinfit fit-image`` run in a fresh process as its command line does, with a thread that samples
#: the resident memory every 10 ms and the stage it is in (``ImageFit.stage_seconds``' names; "writing":
#: ``write_fit``; "between stages": the rest); prints the peak of each as JSON.
_MEMORY_BY_STAGE = """
import contextlib, json, sys, threading, time
stage, peaks, done = ["start"], {}, []
def resident_gib():
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmRSS")) / 2**20
def sample():
    while not done:
        peaks[stage[0]] = max(peaks.get(stage[0], 0.0), resident_gib())
        time.sleep(0.01)
threading.Thread(target=sample, daemon=True).start()
import skinfit.cli._batch as batch
import skinfit.fit._images as images
from skinfit.cli._main import main
timed = images._Stages.__call__
@contextlib.contextmanager
def named(self, name):
    stage[0] = name
    try:
        with timed(self, name):
            yield
    finally:
        stage[0] = "between stages"
images._Stages.__call__ = named
write_fit = batch.write_fit
def writing(*args, **kwargs):
    stage[0] = "writing"
    return write_fit(*args, **kwargs)
batch.write_fit = writing
stage[0] = "between stages"
code = main(["fit-image", *sys.argv[1:], "--quiet"])
done.append(True)
with open("/proc/self/status") as status:
    peak = next(int(line.split()[1]) for line in status if line.startswith("VmHWM")) / 2**20
print(json.dumps({"peak": peak, "by_stage": peaks}))
sys.exit(code)
"""


def peak_memory(rgb, size) -> dict:
    """Peak resident memory (GiB) and wall time of ``skinfit fit-image`` (defaults) on a size x size
    EXR tiled from ``rgb``, in fresh processes that share skinfit's caches in an empty folder: the
    first compiles and fills them (a first session), the second reads them (a user's later ones);
    for each, the peak within each stage."""
    from skinfit.io import write_exr

    reps = -(-size // min(rgb.shape[:2]))
    big = np.tile(rgb, (reps, reps, 1))[:size, :size]
    runs = {}
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "big.exr"
        write_exr(path, {c: big[..., i].astype(np.float32) for i, c in enumerate("RGB")})
        del big
        env = dict(os.environ, SKINFIT_CACHE_DIR=str(Path(folder) / "cache"), SKINFIT_COMPILATION_CACHE="1", SKINFIT_DISK_CACHE="1")
        for run in ("caches_filling", "caches_warm"):
            start = time.perf_counter()
            done = subprocess.run([sys.executable, "-c", _MEMORY_BY_STAGE, str(path), "--out", str(Path(folder) / run)],
                                  capture_output=True, text=True, env=env)
            seconds = time.perf_counter() - start
            if done.returncode != 0:
                return {"error": done.stderr[-500:]}
            lines = done.stdout.strip().splitlines()
            measured = json.loads(lines[-1])
            runs[run] = {"peak_rss_gib": measured["peak"], "wall_s_incl_start": seconds, "s_per_megapixel_incl_start": seconds / (size * size / 1e6),
                         "summary_line": lines[-2], "peak_rss_gib_by_stage": measured["by_stage"]}
    return {"pixels": size * size, **runs}


#: The demo's fit in a fresh process, timed inside it (import and reading excluded).
_FRESH = """
import json, sys, time
from skinfit.fit import fit_image
from skinfit.io import read_linear_rgb
rgb, _ = read_linear_rgb(sys.argv[1])
start = time.perf_counter()
fit_image(rgb, progress=False)
print(json.dumps({"first_fit_s": time.perf_counter() - start}))
"""


def fresh_process(image: Path, runs: int = 3) -> dict:
    """The first ``fit_image`` (defaults) of ``image`` in fresh processes that share skinfit's caches
    (compiled programs, colour tables) in an empty folder: the first run fills them, the later ones
    read them (what a user's second session gets). Seconds each, and of the same with the caches off."""
    def run(env):
        done = subprocess.run([sys.executable, "-c", _FRESH, str(image)], env=env, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(done.stderr[-1000:])
        return json.loads(done.stdout.strip().splitlines()[-1])["first_fit_s"]

    with tempfile.TemporaryDirectory() as folder:
        env = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR",)}
        cached = dict(env, SKINFIT_CACHE_DIR=folder, SKINFIT_COMPILATION_CACHE="1", SKINFIT_DISK_CACHE="1")
        seconds = [run(cached) for _ in range(runs)]
        uncached = run(dict(env, SKINFIT_COMPILATION_CACHE="0", SKINFIT_DISK_CACHE="0"))
    return {"image": image.name, "caches_filling_s": seconds[0], "caches_warm_s": seconds[1:], "caches_off_s": uncached}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scipy-n", type=int, default=100)
    parser.add_argument("--memory-size", type=int, default=4096, help="0 skips the peak-memory run")
    parser.add_argument("--large-memory-size", type=int, default=0,
                        help="with --memory-only: a larger tiling (6928: 48 MP) measured alone and added to the saved results")
    parser.add_argument("--memory-only", action="store_true", help="only the --large-memory-size run, into the saved results")
    parser.add_argument("--out", default="benchmarks/results")
    args = parser.parse_args(argv)
    out = Path(args.out)
    if args.memory_only:
        record = json.loads((out / "fit_photos.json").read_text())
        capture, _ = read_linear_rgb(INPUTS["albedo capture, 1/4 (125x199, head mask)"][0])
        large = {**provenance(), **peak_memory(capture, args.large_memory_size)}
        print(f"{args.large_memory_size}^2: {large}")
        record["peak_memory_large"] = large
        (out / "fit_photos.json").write_text(json.dumps(record, indent=2))
        (out / "fit_photos.md").write_text(markdown(record) + "\n")
        return
    results = {}
    for name in INPUTS:
        loaded = read_input(name)
        if loaded is None:
            continue
        rgb, mask = loaded
        result = measure(rgb, mask)
        result["scipy_least_squares"] = scipy_baseline(rgb, result.pop("fit"), args.scipy_n)
        result["speedup_vs_scipy"] = result["scipy_least_squares"]["s_per_megapixel"] / result["s_per_megapixel"]
        results[name] = result
        print(f"{name}: {result['s_per_megapixel']:.2f} s/MP ({result['speedup_vs_scipy']:.0f}x SciPy), "
              f"mask SUCCESS {100 * result['mask_success_fraction']:.1f} %, CIEDE2000 median {result['mask_dE2000_median']:.3f} "
              f"p95 {result['mask_dE2000_p95']:.2f}, speckle {100 * result['melanin_speckle_fraction']:.2f} %, "
              f"C_m {result['melanin_median']:.3f}, C_h {result['haemoglobin_median']:.4f}", flush=True)
    fresh = fresh_process(INPUTS["demo portrait (512x512, faces found)"][0])
    print(f"first fit in a fresh process: {fresh}", flush=True)
    memory = None
    if args.memory_size:
        capture, _ = read_linear_rgb(INPUTS["albedo capture, 1/4 (125x199, head mask)"][0])
        memory = peak_memory(capture, args.memory_size)
        print(f"{args.memory_size}^2: {memory}")
    record = {
        **provenance(),
        "model": skinfit.SkinModel.default().name,
        "inputs": results,
        "peak_memory_default_settings": memory,
        "fresh_process": fresh,
    }
    if (out / "fit_photos.json").exists():  # a larger tiling measured alone stays until measured again
        previous = json.loads((out / "fit_photos.json").read_text()).get("peak_memory_large")
        if previous:
            record["peak_memory_large"] = previous
    out.mkdir(parents=True, exist_ok=True)
    (out / "fit_photos.json").write_text(json.dumps(record, indent=2))
    (out / "fit_photos.md").write_text(markdown(record) + "\n")


def markdown(record) -> str:
    """The table of real inputs in docs/fitting-images.md (kept equal to it by tests/test_readme.py)."""
    lines = [
        f"Real inputs, default settings ({record['model']}; `python -m benchmarks.fit_photos`, {record['date']}, "
        f"{record['machine']}); CIEDE2000 over every mask pixel; speckle: skin pixels whose melanin is off its 3×3 median by 2×:",
        "",
        "| input | mask SUCCESS | CIEDE2000 median / p95 | speckle | C_m / C_h median | gains | s/MP (first call) | × SciPy |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in record["inputs"].items():
        gains = ", ".join(f"{g:.2f}" for g in r["white_balance"])
        lines.append(
            f"| {name} | {100 * r['mask_success_fraction']:.1f} % | {r['mask_dE2000_median']:.3f} / {r['mask_dE2000_p95']:.2f} | "
            f"{100 * r['melanin_speckle_fraction']:.2f} % | {r['melanin_median']:.3f} / {r['haemoglobin_median']:.4f} | {gains} | "
            f"{r['s_per_megapixel']:.1f} ({r['first_call_s']:.0f} s) | {r['speedup_vs_scipy']:.0f} |"
        )
    stages = [k for r in record["inputs"].values() for k in r.get("stage_s", {})]
    stages = list(dict.fromkeys(stages))
    if stages:
        lines += ["", "Where the time goes (the same compiled calls; seconds per stage, `ImageFit.stage_seconds`; "
                      "\"other\": reading arrays, masks, band bookkeeping):", "",
                  "| input | " + " | ".join(stages) + " | total |", "|---|" + "---|" * (len(stages) + 1)]
        for name, r in record["inputs"].items():
            cells = [f"{r['stage_s'].get(k, 0.0):.2f}" for k in stages]
            lines.append(f"| {name} | " + " | ".join(cells) + f" | {r['s']:.2f} |")
    fresh = record.get("fresh_process")
    if fresh:
        warm = ", ".join(f"{t:.1f}" for t in fresh["caches_warm_s"])
        lines += ["", f"First fit of the demo portrait in a fresh process (import and reading excluded): {fresh['caches_off_s']:.1f} s "
                      f"with skinfit's caches off, {fresh['caches_filling_s']:.1f} s filling them (compiled programs, colour tables), "
                      f"{warm} s reading them."]
    for memory in (record.get("peak_memory_default_settings"), record.get("peak_memory_large")):
        if not memory or "caches_warm" not in memory:
            continue
        side = int(round(memory["pixels"] ** 0.5))
        when = f" (measured alone, {memory['date']}, commit {memory['git_commit'][:7]})" if "date" in memory else ""
        lines += ["", f"{side}×{side} ({memory['pixels'] / 1e6:.0f} MP, the capture tiled) through `skinfit fit-image` with the defaults "
                      f"in a fresh process{when}:"]
        for run, label in (("caches_filling", "a first session (compiling, filling the caches)"), ("caches_warm", "a later one (caches warm)")):
            r = memory[run]
            lines.append(f"{label}: peak resident {r['peak_rss_gib']:.2f} GiB, {r['wall_s_incl_start']:.0f} s including start "
                         f"({r['s_per_megapixel_incl_start']:.1f} s/MP); within each stage (GiB): "
                         + ", ".join(f"{k} {v:.2f}" for k, v in r["peak_rss_gib_by_stage"].items()) + ".")
        lines[-2] = "- " + lines[-2]
        lines[-1] = "- " + lines[-1]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
