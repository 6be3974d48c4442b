"""Frequency-domain adding against the light-skin fixture of model notes 5.4."""

import numpy as np

import skinfit
from skinfit.model import add_below, slab_response, stack_reflectance

from ..conftest import DJ2006


def _skin_responses(light, wavelengths):
    epidermis, dermis = skinfit.model.skin_layers(light, wavelengths, model=DJ2006)
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


def _combined(top, bottom):
    """The two layers as one: all four responses of the pair by the adding equations of both
    directions (written here, not taken from skinfit)."""
    r1p, t1p, r1m, t1m = top
    r2p, t2p, r2m, t2m = bottom
    bounce = 1.0 / (1.0 - r2p * r1m)
    return (r1p + t1p * r2p * t1m * bounce, t1p * t2p * bounce,
            r2m + t2m * r1m * t2p * bounce, t2m * t1m * bounce)


def test_a_three_layer_stack_equals_its_top_pair_as_one_layer():
    # adding is associative: (a over b) over c, with a-over-b's responses from both sides, is the
    # stack a, b, c that skinfit folds from the bottom; a fold from the top, or either
    # direction's responses swapped, would break it (the layers differ in index, so R+ != R-)
    a = slab_response(0.2, 8.0, 0.1, 1.4, 1.0, q=np.array([0.0, 0.7, 3.0]))
    b = slab_response(0.05, 4.0, 0.5, 1.0, 1.33, q=np.array([0.0, 0.7, 3.0]))
    c = slab_response(0.02, 2.0, np.inf, 1.0, 1.0, q=np.array([0.0, 0.7, 3.0]))
    ab = _combined([np.asarray(v) for v in a], [np.asarray(v) for v in b])
    expected = ab[0] + ab[1] * c.reflect_top * ab[3] / (1.0 - c.reflect_top * ab[2])
    np.testing.assert_allclose(stack_reflectance([a, b, c]), expected, rtol=1e-13)
    assert not np.allclose(np.asarray(a.reflect_top), np.asarray(a.reflect_bottom), rtol=1e-3)
