"""Calibrating shared constants by variable projection: recovery of known constants, cross-validation."""

import numpy as np
import pytest

import skinfit
from skinfit import SkinfitInputError
from skinfit.fit import CONSTANTS, calibrate_model, prior_table

from ..conftest import DJ2006

WL = np.arange(400.0, 701.0, 25.0)


@pytest.fixture(scope="module")
def population():
    """24 spectra of a model whose constants differ from DJ2006's, 12 subjects of two spectra."""
    rng = np.random.default_rng(7)
    n = 24
    params = skinfit.SkinParams(np.exp(rng.uniform(np.log(0.005), np.log(0.3), n)), rng.uniform(0.1, 0.9, n),
                                np.exp(rng.uniform(np.log(0.005), np.log(0.08), n)))
    law = DJ2006.epidermis_scattering
    truth = DJ2006.replace(epidermis_scattering=skinfit.model.ScatteringLaw(1.3 * law.mie_mm, law.mie_power, law.rayleigh_mm), blood_oxygenation=0.85)
    spectra = np.asarray(skinfit.diffuse_reflectance(params, WL, model=truth))
    return params, spectra, np.repeat(np.arange(n // 2), 2)


@pytest.fixture(scope="module")
def calibration(population):
    _, spectra, groups = population
    return calibrate_model(WL, spectra, model=DJ2006, constants=("epidermis_scattering.mie_mm", "blood_oxygenation"), groups=groups,
                           folds=2, max_steps=30, progress=False)


@pytest.mark.slow
def test_known_constants_are_recovered(population, calibration):
    params, _, _ = population
    expected_mie = 1.3 * float(DJ2006.epidermis_scattering.mie_mm)
    assert calibration.constants["epidermis_scattering.mie_mm"] == pytest.approx(expected_mie, rel=1e-4)
    assert calibration.constants["blood_oxygenation"] == pytest.approx(0.85, abs=1e-4)
    assert calibration.history[-1] < 1e-3 * calibration.history[0]
    np.testing.assert_allclose(calibration.fit.parameters["melanin"], params.melanin, rtol=1e-3)
    assert np.all(calibration.fit.status == skinfit.FitStatus.SUCCESS)
    # the calibrated model carries the population's prior, and its name
    assert calibration.model.prior is not None and calibration.model.name == "calibrated"
    assert set(prior_table(calibration.model)) == {"melanin", "melanin_blend", "haemoglobin"}
    assert all(np.isfinite(v) and v >= 0 for v in calibration.standard_errors.values())


def test_cross_validation_fits_held_out_subjects_with_fold_constants(population, calibration):
    _, _, groups = population
    cv = calibration.cross_validation
    assert cv["folds"] == 2 and set(np.unique(cv["fold"])) == {0, 1}
    for label in np.unique(groups):  # a subject's spectra stay in one fold
        assert len(set(cv["fold"][groups == label])) == 1
    assert np.all(cv["maximum_likelihood"]["rms_residual"] < 1e-4)
    assert np.all(cv["rms_residual"] < 1e-3)  # the fits with the fold's prior (MAP) are pulled a little
    assert all(fold["blood_oxygenation"] == pytest.approx(0.85, abs=1e-3) for fold in cv["fold_constants"])
    record = calibration.record()
    assert record["cross_validation"]["maximum_likelihood"]["success_fraction"] == 1.0


def test_usage_errors():
    with pytest.raises(SkinfitInputError, match="unknown constant"):
        calibrate_model(WL, np.full((2, WL.size), 0.3), model=DJ2006, constants=("thickness",))
    with pytest.raises(SkinfitInputError, match="shape"):
        calibrate_model(WL, np.full((2, 3), 0.3), model=DJ2006)
    assert "epidermis_thickness_mm" in CONSTANTS
