"""Frequency-domain adding against the light-skin fixture of MODEL.md 5.4."""

import numpy as np

import skinfit
from skinfit.adding import add_below, stack_reflectance
from skinfit.multipole import slab_response

from .conftest import DJ2006


def _skin_responses(light, wavelengths):
    epidermis, dermis = skinfit.skin_layers(light, wavelengths, model=DJ2006)
    top = slab_response(epidermis.absorption, epidermis.reduced_scattering, epidermis.thickness, 1.4, 1.0)
    bottom = slab_response(dermis.absorption, dermis.reduced_scattering, dermis.thickness, 1.0, 1.0)
    return top, bottom


def test_layer_responses_match_fixture(light, light_fixture):
    top, bottom = _skin_responses(light, light_fixture["wavelengths_nm"])
    np.testing.assert_allclose(top.reflect_top, light_fixture["R1_top"], atol=6e-5)
    np.testing.assert_allclose(top.reflect_bottom, light_fixture["R1_bottom"], atol=6e-5)
    np.testing.assert_allclose(top.transmit_top, light_fixture["T1_top"], atol=6e-5)
    np.testing.assert_allclose(top.transmit_bottom, light_fixture["T1_bottom"], atol=6e-5)
    np.testing.assert_allclose(bottom.reflect_top, light_fixture["R2"], atol=6e-5)


def test_directional_and_symmetric_adding_match_fixture(light, light_fixture):
    top, bottom = _skin_responses(light, light_fixture["wavelengths_nm"])
    np.testing.assert_allclose(add_below(top, bottom.reflect_top), light_fixture["R12_directional"], atol=6e-5)
    np.testing.assert_allclose(add_below(top, bottom.reflect_top, "symmetric"), light_fixture["R12_symmetric"], atol=6e-5)


def test_adding_sums_the_geometric_series_of_interreflections(light):
    top, bottom = _skin_responses(light, np.array([500.0]))
    r1p, t1p, r1m, t1m = (np.asarray(v) for v in top)
    r2 = np.asarray(bottom.reflect_top)
    series = r1p + sum(t1p * r2 * (r1m * r2) ** n * t1m for n in range(200))
    np.testing.assert_allclose(add_below(top, bottom.reflect_top), series, rtol=1e-13)


def test_three_layer_stack_folds_from_the_bottom():
    a = slab_response(0.2, 8.0, 0.1, 1.4, 1.0)
    b = slab_response(0.05, 4.0, 0.5, 1.0, 1.0)
    c = slab_response(0.02, 2.0, np.inf, 1.0, 1.0)
    expected = add_below(a, add_below(b, c.reflect_top))
    np.testing.assert_allclose(stack_reflectance([a, b, c]), expected, rtol=1e-15)
