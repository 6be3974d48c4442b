"""The Monte Carlo reference: against Chandrasekhar's exact semi-infinite result, energy
conservation, and published MCML-style skin values (MODEL.md 5.5)."""

import numpy as np
import pytest

import skinfit
from skinfit.monte_carlo import monte_carlo_reflectance

from .reference import semi_infinite_isotropic_albedo

from .conftest import DJ2006


@pytest.mark.parametrize("albedo", [0.5, 0.9])
def test_matches_the_exact_semi_infinite_isotropic_albedo(albedo):
    layer = skinfit.Layer(absorption=1 - albedo, reduced_scattering=albedo, thickness=float("inf"), ior=1.0)
    mc = monte_carlo_reflectance([layer], photons=100_000, seed=1)
    exact = semi_infinite_isotropic_albedo(albedo)
    assert abs(mc.reflectance - exact) < 4 * mc.reflectance_error + 1e-4
    assert mc.transmittance == 0.0


def test_a_non_absorbing_slab_returns_every_photon_that_entered():
    layers = [skinfit.Layer(absorption=0.0, reduced_scattering=3.0, thickness=0.2, ior=1.4, anisotropy=0.8),
              skinfit.Layer(absorption=0.0, reduced_scattering=1.0, thickness=0.5, ior=1.3)]
    mc = monte_carlo_reflectance(layers, photons=20_000, seed=2)
    entry = 1 - (0.4 / 2.4) ** 2
    assert mc.reflectance + mc.transmittance == pytest.approx(entry, rel=1e-12)
    assert 0 < mc.transmittance < entry


@pytest.mark.parametrize("name, g, published", [("light", 0.0, 0.3765), ("medium", 0.0, 0.0499), ("dark", 0.9, 0.0072)])
def test_skin_stacks_agree_with_the_published_monte_carlo(name, g, published):
    epidermis, dermis = skinfit.skin_layers(skinfit.preset(name), np.array([550.0]), model=DJ2006)

    def scalar(layer, thickness):
        return skinfit.Layer(absorption=float(np.ravel(layer.absorption)[0]), reduced_scattering=float(np.ravel(layer.reduced_scattering)[0]),
                             thickness=thickness, ior=1.4, anisotropy=g)

    mc = monte_carlo_reflectance([scalar(epidermis, 0.25), scalar(dermis, float("inf"))], photons=20_000, seed=3)
    assert abs(mc.reflectance - published) < 4 * mc.reflectance_error + 0.0008  # MODEL.md 5.5: its SE <= 0.0008


def test_bad_stacks_are_clear_errors():
    semi = skinfit.Layer(absorption=0.1, reduced_scattering=1.0, thickness=float("inf"))
    with pytest.raises(skinfit.SkinfitInputError, match="semi-infinite"):
        monte_carlo_reflectance([semi, semi])
    with pytest.raises(skinfit.SkinfitInputError, match="photons"):
        monte_carlo_reflectance([semi], photons=1)
