"""Every public function that evaluates the model, under every JAX transformation, in any order.

Run in a fresh process (``tests/test_transformations.py`` starts one per first transformation):

    python -m tests.transformation_matrix FIRST [--dtype float64|float32] [--model-file PATH]

FIRST is the transformation of the process's very first model call (every case, default model):
the call that fills skinfit's caches (the default model, colour weights, Hankel kernels, plans,
transport tables). Then every case runs under every transformation, for the default model (passed
as None and as ``SkinModel.default()``), ``SkinModel.dj2006()`` and a model read from a file (both
built inside the transformed function), in float64 and float32, all under ``jax.checking_leaks``.
Each transformed result is checked against the eager forward-mode Jacobian: values, vmap rows,
grad, jacfwd, jacrev, jvp and the transpose of the linearisation. Prints one JSON line: the
number of checks and the failures (case, transformation, model, dtype, what went wrong).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
import traceback

import jax
import jax.numpy as jnp
import numpy as np

import skinfit
from skinfit import colorimetry
from skinfit import model as skin_model

#: Three parameters every case maps to its outputs: melanin, melanin blend, haemoglobin.
POINT = np.array([0.08, 0.6, 0.03])
BATCH = np.array([[0.08, 0.6, 0.03], [0.01, 0.9, 0.004]])
WAVELENGTHS_NM = np.arange(420.0, 701.0, 40.0)
RADII_MM = np.geomspace(0.01, 5.0, 6)


def _params(x):
    return skinfit.SkinParams(melanin=x[0], melanin_blend=x[1], haemoglobin=x[2])


def _lam(x):
    return WAVELENGTHS_NM.astype(x.dtype)  # NumPy: wavelengths and radii are concrete (closed over)


def _reflectance(x, model):
    return skinfit.diffuse_reflectance(_params(x), _lam(x), model=model)


def _profile(x, model):
    return skinfit.profile(_params(x), _lam(x)[:3], RADII_MM.astype(x.dtype), model=model).ravel()


def _srgb(x, model):
    return skinfit.spectrum_to_srgb(_reflectance(x, model), _lam(x))


def _lab_difference(x, model):
    lab = colorimetry.xyz_to_lab(colorimetry.spectrum_to_xyz(_reflectance(x, model), _lam(x)))
    return jnp.atleast_1d(colorimetry.delta_e2000(lab, jnp.asarray([60.0, 15.0, 18.0], x.dtype)))


def _plan_rgb(x, model):
    request = skinfit.Request(wavelengths_nm=tuple(WAVELENGTHS_NM[:2]), rgb=True)
    result = skinfit.plan(request, model=model).evaluate(_params(x), model=model)
    return jnp.concatenate([result.reflectance, result.rgb])


def _surface(x, model):
    wi = (np.array([0.3, 0.0, 0.954]) / np.linalg.norm([0.3, 0.0, 0.954])).astype(x.dtype)
    wo = (np.array([-0.2, 0.1, 0.975]) / np.linalg.norm([-0.2, 0.1, 0.975])).astype(x.dtype)
    return skin_model.reflectance_factor(_params(x), _lam(x)[:3], wi, wo, model=model)


def _colour_of_params(x, model):
    weights = jnp.asarray(colorimetry.linear_srgb_weights(colorimetry.COLOUR_WAVELENGTHS_NM, "D65"), x.dtype)
    return colorimetry.params_rgb(x[None, :], weights, skin_model.resolve_model(model))[0]


def _layers(x, model):  # a user's own stack: the model object plays no part
    stack = [skinfit.Layer(absorption=0.2 + 5.0 * x[0], reduced_scattering=3.0 + x[1], thickness=0.1 + x[2]),
             skinfit.Layer(absorption=0.05 + x[2], reduced_scattering=2.0, thickness=jnp.inf)]
    return jnp.atleast_1d(skinfit.layered_reflectance(stack))


def _preset_scaled(x, model):  # presets built inside the trace
    light = skinfit.preset("light")
    params = skinfit.SkinParams(light.melanin * (1.0 + x[0]), light.melanin_blend * x[1], light.haemoglobin + x[2])
    return skinfit.diffuse_reflectance(params, _lam(x), model=model)


CASES = {
    "diffuse_reflectance": _reflectance,
    "profile": _profile,
    "spectrum_to_srgb": _srgb,
    "xyz_to_lab+delta_e2000": _lab_difference,
    "plan.evaluate": _plan_rgb,
    "reflectance_factor": _surface,
    "params_rgb": _colour_of_params,
    "layered_reflectance": _layers,
    "preset": _preset_scaled,
}


def _model_builders(model_file):
    """How each case gets its model, called inside the transformed function."""
    return {
        "default-none": lambda: None,
        "default": skinfit.SkinModel.default,
        "dj2006": skinfit.SkinModel.dj2006,
        "file": lambda: skinfit.SkinModel.from_file(model_file),
    }


def transformations(f, x, batch):
    """name -> a thunk running ``f`` under that transformation at ``x`` (or ``batch`` for vmap)."""
    tangent = jnp.asarray([0.3, -0.2, 0.5], x.dtype)

    def transpose():
        y, linear = jax.linearize(f, x)
        return jax.linear_transpose(linear, x)(jnp.ones_like(y))[0]

    return {
        "jit": lambda: jax.jit(f)(x),
        "vmap": lambda: jax.vmap(f)(batch),
        "grad": lambda: jax.grad(lambda p: jnp.sum(f(p)))(x),
        "jacfwd": lambda: jax.jacfwd(f)(x),
        "jacrev": lambda: jax.jacrev(f)(x),
        "jvp": lambda: jax.jvp(f, (x,), (tangent,))[1],
        "linear_transpose": transpose,
        "jit(vmap(grad))": lambda: jax.jit(jax.vmap(jax.grad(lambda p: jnp.sum(f(p)))))(batch),
    }


TRANSFORMATIONS = tuple(transformations(lambda p: p, jnp.zeros(3), jnp.zeros((2, 3))))


def expected(name, value, jacobian, rows, row_jacobians):
    """What transformation ``name`` must return, from eager evaluations."""
    tangent = np.asarray([0.3, -0.2, 0.5])
    return {
        "jit": value,
        "vmap": rows,
        "grad": jacobian.sum(axis=0),
        "jacfwd": jacobian,
        "jacrev": jacobian,
        "jvp": jacobian @ tangent,
        "linear_transpose": jacobian.sum(axis=0),
        "jit(vmap(grad))": row_jacobians.sum(axis=1),
    }[name]


_REFERENCES: dict = {}


def _reference(case, model_name, model_file):
    """Float64 values and forward-mode Jacobians at ``POINT`` and at each row of ``BATCH``,
    compiled once per case and model (the eager op-by-op version takes minutes)."""
    key = (case, model_name)
    if key not in _REFERENCES:
        build = _model_builders(model_file)[model_name]
        f = lambda p: CASES[case](p, build())  # noqa: E731
        both = jax.jit(lambda p: (f(p), jax.jacfwd(f)(p)))
        value, jacobian = (np.asarray(a) for a in both(jnp.asarray(POINT)))
        rows, row_jacobians = (np.stack(a) for a in zip(*[[np.asarray(a) for a in both(jnp.asarray(b))] for b in BATCH]))
        _REFERENCES[key] = value, jacobian, rows, row_jacobians
    return _REFERENCES[key]


def _check(case, transformation, model_name, dtype, model_file):
    build = _model_builders(model_file)[model_name]
    f = lambda p: CASES[case](p, build())  # noqa: E731 - the model is built inside every trace
    got = np.asarray(transformations(f, jnp.asarray(POINT, dtype), jnp.asarray(BATCH, dtype))[transformation](), dtype=float)
    want = expected(transformation, *_reference(case, model_name, model_file))
    if got.shape != want.shape:
        return f"shape {got.shape}, expected {want.shape}"
    if not np.all(np.isfinite(got)):
        return "NaN or Inf"
    # float32: the model in single precision (relative 1e-3 of the output's scale); float64: round-off
    rtol, atol_scale = (2e-3, 2e-3) if dtype == jnp.float32 else (1e-7, 1e-9)
    scale = max(float(np.max(np.abs(want))), 1e-12)
    if not np.allclose(got, want, rtol=rtol, atol=atol_scale * scale):
        return f"max difference {float(np.max(np.abs(got - want))):.3g} (scale {scale:.3g})"
    return None


def run(first: str, first_dtype, model_file: str, *, full: bool = True, check_leaks: str = "all") -> dict:
    """The matrix in one process (see the module docstring). ``full=False``: after the first calls,
    every case under every transformation with the default model in the other dtype, and under the
    first one with the other models. ``check_leaks``: "all" or "first" (only the first calls: JAX's
    leak checker turns its compilation caches off, which makes the rest ~10x slower)."""
    checks, failures = 0, []

    def attempt(case, transformation, model_name, dtype, leaks=check_leaks == "all"):
        nonlocal checks
        checks += 1
        start = time.perf_counter()
        try:
            with jax.checking_leaks() if leaks else contextlib.nullcontext():
                problem = _check(case, transformation, model_name, dtype, model_file)
        except Exception as err:  # noqa: BLE001 - every failure is reported, not only the first
            problem = f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''} | " + \
                traceback.format_exc().strip().splitlines()[-1][:200]
        if problem:
            failures.append({"case": case, "transformation": transformation, "model": model_name,
                             "dtype": jnp.dtype(dtype).name, "problem": problem})
        print(f"{time.perf_counter() - start:6.2f} s  {case} / {transformation} / {model_name} / {jnp.dtype(dtype).name}: "
              f"{problem or 'ok'}", file=sys.stderr, flush=True)

    # the process's first model calls: every case under ``first``, the default model left to skinfit
    for case in CASES:
        attempt(case, first, "default-none", first_dtype, leaks=True)
    # then everything else, in the same process
    other_dtype = jnp.float32 if first_dtype == jnp.float64 else jnp.float64
    for dtype in (first_dtype, other_dtype):
        for model_name in _model_builders(model_file):
            for case in CASES:
                for transformation in TRANSFORMATIONS:
                    if (transformation, model_name, dtype) == (first, "default-none", first_dtype):
                        continue
                    in_quick = (model_name == "default-none" and dtype == other_dtype) or (
                        transformation == first and model_name != "default-none" and dtype == first_dtype)
                    if full or in_quick:
                        attempt(case, transformation, model_name, dtype)
    return {"first": first, "first_dtype": jnp.dtype(first_dtype).name, "checks": checks, "failures": failures}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("first", choices=TRANSFORMATIONS)
    parser.add_argument("--dtype", default="float64", choices=("float64", "float32"))
    parser.add_argument("--model-file", required=True, help="a model JSON file (SkinModel.save)")
    parser.add_argument("--quick", action="store_true", help="the quick tier's part of the matrix (see run)")
    parser.add_argument("--check-leaks", default="all", choices=("all", "first"))
    args = parser.parse_args(argv)
    print(json.dumps(run(args.first, jnp.dtype(args.dtype).type, args.model_file, full=not args.quick, check_leaks=args.check_leaks)))


if __name__ == "__main__":
    main()
