"""Media matched with exact transport: the colour curve against direct adding-doubling, the median
radius against fresh Monte Carlo, and whole media against both (independent of the tables)."""

import numpy as np
import pytest

import skinfit
from skinfit import export
from skinfit.model import monte_carlo_reflectance


@pytest.fixture(scope="module")
def table():
    return export.medium_table()


def test_the_colour_inversion_matches_direct_adding_doubling_between_the_nodes(table):
    # midpoints in logit(a) between the curve's nodes, where a spline errs most
    mid = 0.5 * (table.albedo_logit[:-1] + table.albedo_logit[1:])[::7]
    albedo = 1.0 / (1.0 + np.exp(-mid))
    albedo = albedo[albedo < 1.0 - table.median_absorption[0]]
    reflectance = export.semi_infinite_reflectance(albedo)
    recovered = table.single_scattering_albedo(reflectance)
    np.testing.assert_allclose(export.semi_infinite_reflectance(recovered), reflectance, rtol=1e-7)  # measured 1e-9


def test_the_direct_curve_agrees_with_monte_carlo():
    # the adding-doubling behind the table, checked by the independent Monte Carlo (n 1.4, g 0)
    for albedo in (0.5, 0.97):
        mc = monte_carlo_reflectance([export.unit_medium_layer(albedo)], photons=40_000, seed=5)
        assert abs(float(export.semi_infinite_reflectance(albedo)) - mc.reflectance) < 4 * mc.reflectance_error


def test_the_median_radius_matches_fresh_monte_carlo_off_the_nodes(table):
    one_minus = np.sqrt(table.median_absorption[12] * table.median_absorption[13])  # between nodes, a ~ 0.93
    c, se = export.median_of_unit_medium(1.0 - one_minus, photons=60_000, seed=77)
    node_se = max(table.median_error[12], table.median_error[13])
    assert abs(float(table.unit_median_radius(1.0 - one_minus)) / c - 1.0) < 4 * np.hypot(se, node_se) + 2e-3


def test_a_medium_has_the_target_albedo_and_median_radius_in_exact_transport():
    albedo, median = np.array([0.45, 0.12, 0.03]), np.array([0.4, 0.1, 0.03])
    medium = export.transport_medium(albedo, median)
    np.testing.assert_allclose(export.semi_infinite_reflectance(medium.single_scattering_albedo), albedo, rtol=1e-7)
    for i in range(3):
        layer = skinfit.model.Layer(absorption=float(medium.absorption_per_mm[i]), reduced_scattering=float(medium.reduced_scattering_per_mm[i]),
                              thickness=float("inf"), ior=1.4, anisotropy=0.0)
        radii = np.array([median[i]])
        mc = monte_carlo_reflectance([layer], photons=40_000, seed=10 + i, radii_mm=radii)
        half = mc.reflectance_within[0] / mc.reflectance
        assert abs(half - 0.5) < 4 * mc.reflectance_within_error[0] / mc.reflectance + 0.01, i
    np.testing.assert_allclose(medium.mean_free_path_mm * medium.extinction_per_mm, 1.0)
    np.testing.assert_allclose(medium.absorption_per_mm + medium.scattering_per_mm, medium.extinction_per_mm)


def test_an_anisotropic_renderer_gets_its_own_scattering(table):
    # the colour depends on g: the same albedo needs a different single-scattering albedo at g 0.8
    forward = export.RendererConventions(anisotropy=0.8)
    a0 = table.single_scattering_albedo(0.3)
    curve = export.semi_infinite_reflectance(np.array([a0, 0.999]), forward)
    assert curve[0] < 0.3 < curve[1]


def test_albedos_no_medium_renders_and_bad_conventions_are_clear_errors(table):
    low, high = table.reflectance_range
    assert 1e-4 > low and 0.85 < high < 1 - export.DEFAULT_CONVENTIONS.specular
    with pytest.raises(skinfit.SkinfitInputError, match="outside what a homogeneous medium"):
        export.transport_medium(np.array([0.5, 0.95, 0.2]), np.array([0.1, 0.1, 0.1]))
    with pytest.raises(skinfit.SkinfitInputError, match="median radii"):
        export.transport_medium(np.array([0.5]), np.array([0.0]))
    with pytest.raises(skinfit.SkinfitInputError, match="ior"):
        export.RendererConventions(ior=0.9)
