"""Numerical stress: the fast version of ``benchmarks.stress`` and property-based tests of the same
properties (values, derivatives, monotonicity in the diffusion model's validity domain)."""

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import skinfit
from benchmarks import stress

unit = st.floats(0.0, 1.0)


@pytest.mark.slow
@pytest.mark.parametrize("model_name", tuple(stress.MODELS))
def test_fast_sweep_has_no_violations(model_name):
    model = stress.MODELS[model_name]()
    report = stress.sweep(points=65536, profile_sets=32, solvers=False, progress=False, model=model)
    for dtype in ("float64", "float32"):
        assert report[dtype]["points"] >= 65536
        assert report[dtype]["points_in_validity"] > 0.3 * report[dtype]["points"]
    if isinstance(model.method, skinfit.Transport):  # exact transport: monotone at every optical thickness
        assert report["float64"]["points_in_validity"] == report["float64"]["points"]
    assert report["float64"]["fd_points"] > 0
    assert report["violations"] == 0, report


@pytest.mark.slow
def test_solvers_return_a_status_never_nan():
    counts = stress.check_solvers(np.random.default_rng(1), n_spectra=27, n_pixels=1024)
    assert counts["solver_nan_inf"] == 0 and counts["solver_bad_status"] == 0, counts


@settings(max_examples=150, deadline=None)
@given(
    melanin=unit, blend=unit, haemoglobin=unit, oxygenation=unit,
    log_thickness=st.floats(-4.0, 1.0), wavelength=st.floats(250.0, 1000.0),
    dtype=st.sampled_from([jnp.float64, jnp.float32]),
)
def test_reflectance_properties_at_any_point(melanin, blend, haemoglobin, oxygenation, log_thickness, wavelength, dtype):
    fields = {
        "melanin": np.array([melanin]), "melanin_blend": np.array([blend]), "haemoglobin": np.array([haemoglobin]),
        "blood_oxygenation": np.array([oxygenation]), "epidermis_thickness_mm": np.array([10.0**log_thickness]),
    }
    lam = np.array([wavelength])
    value, derivatives = stress.values_and_derivatives({k: jnp.asarray(v, dtype) for k, v in fields.items()}, jnp.asarray(lam, dtype))
    value = float(value[0, 0])
    assert np.isfinite(value) and 0.0 <= value <= 1.0
    assert all(np.isfinite(float(d[0, 0])) for d in derivatives.values())
    if stress.epidermis_optical_thickness(fields, lam)[0, 0] >= 1.0:
        noise = 64 * np.finfo(np.dtype(dtype)).eps * abs(value)
        assert float(derivatives["melanin"][0, 0]) <= noise
        assert float(derivatives["haemoglobin"][0, 0]) <= noise


def test_thin_epidermis_is_outside_the_diffusion_validity_domain():
    # The reason the physical properties are asserted only where sigma_t' d >= 1: an epidermis
    # thinner than a transport mean free path reflects more as it absorbs more in diffusion theory.
    # If this starts failing, the model changed and the stress docs must follow.
    fields = {"melanin": np.array([0.0]), "melanin_blend": np.array([0.7]), "haemoglobin": np.array([0.5]),
              "blood_oxygenation": np.array([0.75]), "epidermis_thickness_mm": np.array([1e-3])}
    lam = np.array([900.0])
    assert stress.epidermis_optical_thickness(fields, lam)[0, 0] < 1.0
    _, derivatives = stress.values_and_derivatives({k: jnp.asarray(v) for k, v in fields.items()}, jnp.asarray(lam))
    assert float(derivatives["melanin"][0, 0]) > 0.0
