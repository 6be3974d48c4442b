"""The Monte Carlo reference: against Chandrasekhar's exact semi-infinite result, energy
conservation, the model notes' own MCML-style simulation of skin stacks (model notes 5.5, a different code
from this one), and the closed-form single-scattering energy within a radius."""

import numpy as np
import pytest
import scipy.integrate

import skinfit
from skinfit.model import monte_carlo_reflectance

from ..conftest import DJ2006
from ..reference import semi_infinite_isotropic_albedo


@pytest.mark.parametrize("albedo", [0.5, 0.9])
def test_matches_the_exact_semi_infinite_isotropic_albedo(albedo):
    layer = skinfit.model.Layer(absorption=1 - albedo, reduced_scattering=albedo, thickness=float("inf"), ior=1.0)
    mc = monte_carlo_reflectance([layer], photons=100_000, seed=1)
    exact = semi_infinite_isotropic_albedo(albedo)
    assert abs(mc.reflectance - exact) < 4 * mc.reflectance_error + 1e-4
    assert mc.transmittance == 0.0


def test_a_non_absorbing_slab_returns_every_photon_that_entered():
    layers = [skinfit.model.Layer(absorption=0.0, reduced_scattering=3.0, thickness=0.2, ior=1.4, anisotropy=0.8),
              skinfit.model.Layer(absorption=0.0, reduced_scattering=1.0, thickness=0.5, ior=1.3)]
    mc = monte_carlo_reflectance(layers, photons=20_000, seed=2)
    entry = 1 - (0.4 / 2.4) ** 2
    assert mc.reflectance + mc.transmittance == pytest.approx(entry, rel=1e-12)
    assert 0 < mc.transmittance < entry


@pytest.mark.parametrize("name, g, notes_value", [("light", 0.0, 0.3765), ("medium", 0.0, 0.0499), ("dark", 0.9, 0.0072)])
def test_skin_stacks_agree_with_the_model_notes_monte_carlo(name, g, notes_value):
    epidermis, dermis = skinfit.model.skin_layers(skinfit.preset(name), np.array([550.0]), model=DJ2006)

    def scalar(layer, thickness):
        return skinfit.model.Layer(absorption=float(np.ravel(layer.absorption)[0]), reduced_scattering=float(np.ravel(layer.reduced_scattering)[0]),
                             thickness=thickness, ior=1.4, anisotropy=g)

    mc = monte_carlo_reflectance([scalar(epidermis, 0.25), scalar(dermis, float("inf"))], photons=20_000, seed=3)
    assert abs(mc.reflectance - notes_value) < 4 * mc.reflectance_error + 0.0008  # model notes 5.5: its SE <= 0.0008


def test_bad_stacks_are_clear_errors():
    semi = skinfit.model.Layer(absorption=0.1, reduced_scattering=1.0, thickness=float("inf"))
    with pytest.raises(skinfit.SkinfitInputError, match="semi-infinite"):
        monte_carlo_reflectance([semi, semi])
    with pytest.raises(skinfit.SkinfitInputError, match="photons"):
        monte_carlo_reflectance([semi], photons=1)


def _single_scattering_within(albedo, radius):
    """Energy within ``radius`` of once-scattered light in an index-matched isotropic medium with
    sigma_t = 1: scattered at depth z (density e^-z), escaping along mu (density 1/2) with
    e^(-z / mu), at radius z tan(theta); the depth integral in closed form leaves
    a/2 int_0^1 mu / (1 + mu) (1 - exp(-r sqrt((1 + mu) / (1 - mu)))) dmu."""
    def integrand(mu):
        return mu / (1 + mu) * -np.expm1(-radius * np.sqrt((1 + mu) / (1 - mu))) if mu < 1 else 0.5

    return 0.5 * albedo * scipy.integrate.quad(integrand, 0.0, 1.0, limit=200)[0]


def test_the_radial_tally_follows_single_scattering_in_a_dark_medium():
    # at albedo 0.002 light is scattered once (multiple scattering adds ~0.4 % of it)
    layer = skinfit.model.Layer(absorption=0.998, reduced_scattering=0.002, thickness=float("inf"), ior=1.0)
    radii = np.array([0.1, 0.5, 2.0])
    mc = monte_carlo_reflectance([layer], photons=400_000, seed=4, radii_mm=radii)
    single = np.array([_single_scattering_within(0.002, r) for r in radii])
    assert np.all(np.diff(mc.reflectance_within) > 0) and mc.reflectance_within[-1] <= mc.reflectance
    assert np.all(np.abs(mc.reflectance_within - single) < 4 * mc.reflectance_within_error + 0.006 * single)
    # a radius beyond every exit gives the whole reflectance
    far = monte_carlo_reflectance([layer], photons=10_000, seed=4, radii_mm=[1e6])
    assert far.reflectance_within[0] == pytest.approx(far.reflectance, rel=1e-12)
