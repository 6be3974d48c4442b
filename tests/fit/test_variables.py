"""The fit residual's two parts (``MeasurementModel.evaluation`` and the cheap rest) against the
residual differentiated in one piece."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skinfit
from skinfit.fit import _spectra

WAVELENGTHS = np.arange(400.0, 701.0, 10.0)


@pytest.mark.parametrize("prior", [False, True])
@pytest.mark.parametrize("colour_weight", [0.0, _spectra.COLOUR_WEIGHT])
@pytest.mark.parametrize("free", [("melanin", "melanin_blend", "haemoglobin", "oil"), ("melanin", "haemoglobin", "oil")])
def test_linearised_residual_is_the_residual_and_its_jacobian(prior, colour_weight, free):
    skin = skinfit.SkinModel.default()
    fixed = None if "melanin_blend" in free else {"melanin_blend": 0.3}
    measurement = _spectra.measurement_model(skin, free, fixed, None, specular_included_deg=8.0, colour_weight=colour_weight,
                                             prior=prior)
    u = jnp.asarray([-0.9, 0.2, -1.1, 0.3][: len(free)])
    target = jnp.asarray(skinfit.diffuse_reflectance(skinfit.preset("medium"), WAVELENGTHS)) * 1.05
    w = jnp.full(WAVELENGTHS.size, 2.0)

    whole = lambda x: measurement.residual(x, target, WAVELENGTHS, w)  # noqa: E731
    expected_r, expected_j = whole(u), jax.jacfwd(whole)(u)
    evaluate = lambda x: measurement.evaluation(x, WAVELENGTHS)  # noqa: E731
    r, j = measurement.linearised_residual(evaluate(u), jax.jacfwd(evaluate)(u), target, WAVELENGTHS, w)

    # the row counts the polish sizes its carried state by
    prior_rows = measurement.prior_residual(measurement.values(u)).shape[-1] if prior else 0
    assert measurement.prior_rows == prior_rows == (len(free) if prior else 0)
    assert measurement.colour_rows == (3 if colour_weight else 0)
    rows = WAVELENGTHS.size + measurement.colour_rows + measurement.prior_rows
    assert r.shape == expected_r.shape == (rows,) and j.shape == expected_j.shape == (rows, len(free))
    np.testing.assert_allclose(r, expected_r, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(j, expected_j, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("name", ["melanin_blend", "melanin", "haemoglobin"])
def test_the_prior_pulls_back_from_its_bounds(name):
    """The prior's coordinate is finite with a nonzero gradient at and near a bound: a clip
    there (as before) zeroed the pull, and spectra that the data push to a bound stayed on it (36 %
    of the ISSA African cheeks had the blend at exactly 0)."""
    from skinfit.fit._variables import VARIABLES, prior_coordinate

    var = VARIABLES[name]
    grad = jax.grad(lambda v: prior_coordinate(name, v))
    for value in (var.low, var.low + 1e-12 * (var.high - var.low), var.low + 1e-3 * (var.high - var.low)):
        z, g = prior_coordinate(name, jnp.asarray(value)), grad(jnp.asarray(value))
        assert np.isfinite(z) and np.isfinite(g) and g > 0.0
    if var.prior == "logit":
        g = grad(jnp.asarray(var.high))
        assert np.isfinite(g) and g > 0.0
