"""Spectral fitting: recovery of known parameters, statuses, errors and the measurement model."""

from pathlib import Path

import colour
import numpy as np
import pytest

import skinfit
from skinfit.fit import FitStatus, fit_spectra
from skinfit.io import read_nist
from skinfit.model import captured_reflectance

DJ2006 = skinfit.SkinModel.dj2006()

WL = np.arange(400.0, 701.0, 10.0)
CHROMOPHORES = ("melanin", "melanin_blend", "haemoglobin")


@pytest.fixture(scope="module")
def batch_fit():
    """Presets, two interior points, a NaN spectrum and an out-of-range one, in one call."""
    params = [skinfit.preset(n) for n in skinfit.PRESET_NAMES]
    params += [skinfit.SkinParams(0.02, 0.3, 0.04), skinfit.SkinParams(0.3, 0.9, 0.002)]
    true = np.array([[float(getattr(p, k)) for k in CHROMOPHORES] for p in params])
    spectra = np.stack([np.asarray(skinfit.diffuse_reflectance(p, WL)) for p in params])
    nan = spectra[0].copy()
    nan[3] = np.nan
    spectra = np.vstack([spectra, nan, np.full(WL.size, 3.0)])
    # the package default, maximum likelihood: a forward spectrum and its fit round-trip
    return true, spectra, fit_spectra(WL, spectra, prior=False, progress=False)


def test_noise_free_spectra_are_recovered(batch_fit):
    true, _, fit = batch_fit
    got = np.column_stack([fit.parameters[k] for k in CHROMOPHORES])[: len(true)]
    np.testing.assert_allclose(got, true, atol=1e-6)
    assert np.all(fit.status[: len(true)] == FitStatus.SUCCESS)
    assert np.all(fit.rms_residual[: len(true)] < 1e-8)
    assert np.all(fit.delta_e2000[: len(true)] < 1e-4)
    # a constant that is not fitted reports the model's value
    assert fit.parameters["blood_oxygenation"][0] == pytest.approx(float(skinfit.SkinModel.default().blood_oxygenation))
    assert fit.model == skinfit.SkinModel.default().name


def test_bad_spectra_get_a_status_and_no_nan(batch_fit):
    true, _, fit = batch_fit
    assert list(fit.status[len(true) :]) == [FitStatus.BAD_INPUT, FitStatus.BAD_INPUT]
    for values in (*fit.parameters.values(), *fit.standard_errors.values(), fit.rms_residual, fit.delta_e2000, fit.fitted):
        assert np.all(np.isfinite(values))


def test_colour_difference_is_ciede2000_of_measured_and_fitted_colour():
    # measured NIST forearm spectra: the model leaves a colour difference of a few units
    nist = read_nist(Path(__file__).parents[2] / "data" / "nist_skin_reflectance_250-1000nm.csv")
    spectra = np.stack([np.interp(WL, nist.wavelengths_nm, s) for s in nist.average[:6]])
    fit = fit_spectra(WL, spectra, model=DJ2006, progress=False)
    weights = skinfit.colorimetry.xyz_weights(WL)
    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    lab = [colour.XYZ_to_Lab(np.clip(s, 0.0, None) @ weights.T, white) for s in (spectra, fit.fitted)]
    expected = colour.delta_E(lab[0], lab[1], method="CIE 2000")
    assert np.all(expected > 0.5)
    np.testing.assert_allclose(fit.delta_e2000, expected, rtol=1e-9)


def test_standard_errors_match_the_scatter_of_noisy_refits():
    rng = np.random.default_rng(3)
    params = skinfit.SkinParams(0.05, 0.6, 0.03)
    clean = np.asarray(skinfit.diffuse_reflectance(params, WL))
    noisy = clean * (1 + 0.005 * rng.standard_normal((60, WL.size)))
    fit = fit_spectra(WL, noisy, progress=False)
    assert np.all(fit.status == FitStatus.SUCCESS)
    for name in CHROMOPHORES:
        scatter = np.std(fit.parameters[name])
        predicted = np.median(fit.standard_errors[name])
        assert 0.6 < predicted / scatter < 1.6, (name, predicted, scatter)


@pytest.mark.slow
def test_extended_measurement_model_is_recovered():
    """Offset, calibration and a finite port, fitted together with the chromophores."""
    params = skinfit.SkinParams(0.03, 0.5, 0.02)
    port = 2.5
    spectrum = 1.05 * (np.asarray(captured_reflectance(params, WL, port)) + 0.03)
    fit = fit_spectra(
        WL, spectrum, free=(*CHROMOPHORES, "specular_offset", "calibration_scale"), port_radius_mm=port, prior=False, progress=False
    )
    assert fit.status == FitStatus.SUCCESS
    expected = {"melanin": 0.03, "melanin_blend": 0.5, "haemoglobin": 0.02, "specular_offset": 0.03, "calibration_scale": 1.05}
    for name, value in expected.items():
        assert fit.parameters[name] == pytest.approx(value, abs=1e-5), name


@pytest.mark.parametrize(
    "kwargs, word",
    [
        (dict(free=("melanin", "sparkle")), "unknown fit variable"),
        (dict(free=("melanin", "haemoglobin")), "melanin_blend is not free"),
        (dict(free=CHROMOPHORES, fixed={"blood_oxygenation": 2.0}), "outside"),
        (dict(weights=np.ones(3)), "weights"),
        (dict(port_radius_mm=-1.0), "port_radius_mm"),
    ],
)
def test_usage_errors(kwargs, word):
    with pytest.raises(skinfit.SkinfitInputError, match=word):
        fit_spectra(WL, np.full(WL.size, 0.3), progress=False, **kwargs)


def test_wavelengths_outside_the_tables_are_a_clear_error():
    with pytest.raises(skinfit.SkinfitInputError, match="wavelengths_nm"):
        fit_spectra(np.arange(200.0, 701.0, 10.0), np.full(51, 0.3), progress=False)


@pytest.mark.parametrize("model", [DJ2006, skinfit.SkinModel.default()], ids=["dj2006", "calibrated"])
def test_round_trip_over_the_parameter_box(model):
    """1,000 random parameter sets (C_m 0.001-0.5, beta_m 0-1, C_h 0.001-0.1), 400-700 nm every 10 nm."""
    rng = np.random.default_rng(0)
    n = 1000
    true = np.column_stack([rng.uniform(0.001, 0.5, n), rng.uniform(0.0, 1.0, n), rng.uniform(0.001, 0.1, n)])
    spectra = np.asarray(skinfit.diffuse_reflectance(skinfit.SkinParams(*true.T), WL, model=model))
    fit = fit_spectra(WL, spectra, model=model, prior=False, progress=False)
    got = np.column_stack([fit.parameters[k] for k in CHROMOPHORES])
    assert np.all(fit.status == FitStatus.SUCCESS)
    assert np.max(np.abs(got - true)) <= 1e-6


def test_unrolled_normal_solve_matches_lapack_and_survives_a_dead_direction():
    from skinfit.fit import solve_normal

    rng = np.random.default_rng(5)
    for n in range(1, 9):
        jac = rng.normal(size=(31, n))
        b = rng.normal(size=n)
        np.testing.assert_allclose(np.asarray(solve_normal(jac.T @ jac, b)), np.linalg.solve(jac.T @ jac, b), rtol=1e-9)
    jac[:, 2] = 0.0  # a variable the data do not see (a zero Jacobian column on a bound)
    step = np.asarray(solve_normal(jac.T @ jac, jac.T @ rng.normal(size=31)))
    assert np.all(np.isfinite(step)) and step[2] == 0.0


def test_oil_is_fitted_where_the_measurement_includes_the_specular_part():
    wl = np.arange(400.0, 701.0, 10.0)
    rng = np.random.default_rng(0)
    n = 24
    truth = dict(melanin=10 ** rng.uniform(-3, np.log10(0.4), n), melanin_blend=rng.uniform(0, 1, n),
                 haemoglobin=10 ** rng.uniform(-3, -1, n), oil=rng.uniform(0, 1, n))
    theta = np.radians(8.0)
    specular, subsurface = skinfit.model.surface_energy(skinfit.SkinParams(**truth), wl, np.array([np.sin(theta), 0.0, np.cos(theta)]))
    measured = np.asarray(specular)[:, None] + np.asarray(subsurface)  # an SCI measurement at 8 degrees
    fit = skinfit.fit_spectra(wl, measured, free=("melanin", "melanin_blend", "haemoglobin", "oil"),
                              specular_included_deg=8.0, prior=False, progress=False)
    assert np.all(fit.status == skinfit.FitStatus.SUCCESS)
    for name, values in truth.items():
        np.testing.assert_allclose(fit.parameters[name], values, atol=1e-8)


def test_oil_without_a_specular_measurement_is_a_clear_error():
    with pytest.raises(skinfit.SkinfitInputError, match="specular_included_deg"):
        skinfit.fit_spectra(np.arange(400.0, 701.0, 10.0), np.full(31, 0.3), free=("melanin", "oil"), fixed={"melanin_blend": 0.7, "haemoglobin": 0.01})


# -- method="transport-direct" ---------------------------------------------------------------------------
WL_COARSE = np.arange(400.0, 701.0, 30.0)


@pytest.mark.slow
def test_transport_fit_recovers_transport_spectra_where_diffusion_cannot():
    """Spectra made by exact transport (one with no eumelanin, on the blend's bound) are recovered by
    the transport fit; the diffusion fit of the same spectra misses them (its parameters are
    biased: transport is darker)."""
    true = np.array([[0.02, 0.3, 0.04], [0.15, 0.0, 0.01]])
    spectra = np.asarray(skinfit.diffuse_reflectance(skinfit.SkinParams(*true.T), WL_COARSE, model=DJ2006, method="transport-direct"))
    fit = fit_spectra(WL_COARSE, spectra, model=DJ2006, method="transport-direct", progress=False)
    got = np.column_stack([fit.parameters[k] for k in CHROMOPHORES])
    assert np.all(fit.status == FitStatus.SUCCESS)
    np.testing.assert_allclose(got, true, atol=1e-6)
    assert np.all(fit.rms_residual < 1e-8)
    np.testing.assert_allclose(fit.fitted, spectra, atol=1e-8)
    diffusion = fit_spectra(WL_COARSE, spectra, model=DJ2006, progress=False)
    assert np.all(diffusion.rms_residual > 100 * fit.rms_residual + 1e-4)


@pytest.mark.slow
def test_transport_fit_converges_on_a_measured_spectrum_far_from_the_model():
    """A NIST spectrum (RMS residual ~0.05, far above its noise): the bounded quasi-Newton polish
    still reaches the optimum (a Gauss-Newton step from the fit, with the variables a bound holds
    kept on it, moves no variable by 1e-6 of its range), and lowers the residual below diffusion's.

    (Stationarity as a fraction of the cost is no test here: a variable the data pin down keeps a
    gradient of 1e-4 of the cost per range 6e-9 of its range from the optimum.)"""
    import jax
    import jax.numpy as jnp

    from skinfit.fit import VARIABLES, measurement_model

    nist = read_nist(Path(__file__).parents[2] / "data" / "nist_skin_reflectance_250-1000nm.csv")
    spectrum = np.interp(WL_COARSE, nist.wavelengths_nm, nist.average[2])
    # a purely spectral fit (no colour term), so that the step below is of the cost it minimised
    fit = fit_spectra(WL_COARSE, spectrum, model=DJ2006, method="transport-direct", colour_weight=0.0, progress=False)
    diffusion = fit_spectra(WL_COARSE, spectrum, model=DJ2006, colour_weight=0.0, progress=False)
    assert fit.status == FitStatus.SUCCESS and diffusion.status == FitStatus.SUCCESS
    assert fit.rms_residual < diffusion.rms_residual
    model = measurement_model(skinfit.model.model_with_options(DJ2006, method="transport-direct"), CHROMOPHORES, None, None,
                              colour_weight=0.0)
    theta = jnp.array([fit.parameters[k] for k in CHROMOPHORES])
    residual = lambda th: model.spectrum_of_free(th, jnp.asarray(WL_COARSE)) - spectrum  # noqa: E731
    r, jacobian = np.asarray(residual(theta)), np.asarray(jax.jacfwd(residual)(theta))
    low = np.array([VARIABLES[k].low for k in CHROMOPHORES])
    span = np.array([VARIABLES[k].high for k in CHROMOPHORES]) - low
    gradient = jacobian.T @ r
    offset = (np.asarray(theta) - low) / span
    held = ((offset <= 1e-9) & (gradient > 0)) | ((offset >= 1.0 - 1e-9) & (gradient < 0))
    step = -np.linalg.lstsq(jacobian[:, ~held], r, rcond=None)[0]
    assert np.max(np.abs(step) / span[~held]) <= 1e-6
    assert np.sum(r**2) - np.sum((r + jacobian[:, ~held] @ step) ** 2) <= 1e-10 * np.sum(r**2)


def test_transport_with_a_port_is_energy_corrected():
    """With a finite port the transport model captures diffusion's fraction of transport's total."""
    import jax.numpy as jnp

    from skinfit.fit import measurement_model

    params = skinfit.SkinParams(0.05, 0.5, 0.02)
    model = measurement_model(skinfit.model.model_with_options(DJ2006, method="transport-direct"), CHROMOPHORES, None, 2.0)
    got = np.asarray(model.spectrum_of_free(jnp.array([0.05, 0.5, 0.02]), jnp.asarray(WL_COARSE)))
    fraction = (np.asarray(captured_reflectance(params, WL_COARSE, 2.0, model=DJ2006))
                / np.asarray(skinfit.diffuse_reflectance(params, WL_COARSE, model=DJ2006)))
    expected = np.asarray(skinfit.diffuse_reflectance(params, WL_COARSE, model=DJ2006, method="transport-direct")) * fraction
    np.testing.assert_allclose(got, expected, rtol=1e-6)


@pytest.mark.parametrize(
    "kwargs, word",
    [(dict(method="monte-carlo"), "method"), (dict(method="transport", anisotropy=1.0), "anisotropy")],
)
def test_transport_usage_errors(kwargs, word):
    with pytest.raises(skinfit.SkinfitInputError, match=word):
        fit_spectra(WL, np.full(WL.size, 0.3), progress=False, **kwargs)
