"""The surface (oil) lobe: its albedo against brute-force integration, energy conservation,
the oil-free limit, Fresnel closed forms, NaN-free values and gradients, clear errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skinfit
from skinfit.model import _surface as surface

WAVELENGTHS = np.array([450.0, 550.0, 650.0])
UP = np.array([0.0, 0.0, 1.0])


def direction(theta, phi=0.0):
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def brute_force_albedo(wi, roughness, n_mu=1200):
    """Midpoint rule over the outgoing hemisphere in (cos theta_o, phi): independent of the
    half-vector quadrature the module uses."""
    mu = (np.arange(n_mu) + 0.5) / n_mu
    phi = 2 * np.pi * (np.arange(2 * n_mu) + 0.5) / (2 * n_mu)
    m, p = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - m**2)
    wo = np.stack([s * np.cos(p), s * np.sin(p), m], axis=-1)
    f = np.asarray(surface._unit_lobe(jnp.asarray(np.broadcast_to(wi, wo.shape)), jnp.asarray(wo), roughness, 1.4))
    return np.sum(f * m) / n_mu * (np.pi / n_mu)


@pytest.mark.parametrize("roughness", [0.2, 0.35, 0.6])
@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0, 75.0])
def test_lobe_albedo_matches_brute_force_integration(roughness, theta_deg):
    wi = direction(np.radians(theta_deg))
    got = float(surface.lobe_albedo(wi, roughness))
    assert got == pytest.approx(brute_force_albedo(wi, roughness), rel=2e-3)


def test_fresnel_closed_forms():
    assert float(surface.fresnel_dielectric(1.0, 1.4)) == pytest.approx((0.4 / 2.4) ** 2, rel=1e-12)
    assert float(surface.fresnel_dielectric(0.0, 1.4)) == pytest.approx(1.0)
    brewster = np.arctan(1.4)  # p-polarised reflectance vanishes: the average is half the s part
    cos_i, cos_t = np.cos(brewster), np.cos(np.arcsin(np.sin(brewster) / 1.4))
    r_s = ((cos_i - 1.4 * cos_t) / (cos_i + 1.4 * cos_t)) ** 2
    assert float(surface.fresnel_dielectric(cos_i, 1.4)) == pytest.approx(r_s / 2, rel=1e-10)


@pytest.mark.parametrize("oil", [0.0, 0.3, 1.0])
@pytest.mark.parametrize("roughness", [0.1, 0.35, 1.0])
def test_specular_plus_subsurface_never_exceeds_one(oil, roughness):
    params = skinfit.SkinParams(np.array([0.0, 0.005, 0.5]), 0.7, np.array([0.0, 0.005, 0.1]), oil=oil)
    thetas = np.radians(np.linspace(0.0, 89.9, 40))
    for theta in thetas:
        specular, subsurface = skinfit.model.surface_energy(params, np.arange(400.0, 1001.0, 50.0), direction(theta), roughness=roughness)
        total = np.asarray(specular)[..., None] + np.asarray(subsurface)
        assert np.all(total <= 1.0) and np.all(total >= 0.0)


def test_reflectance_factor_integrates_to_the_energy_split():
    # int beta(wi, wo) cos(theta_o) dwo / pi must equal specular + subsurface albedo
    params = skinfit.SkinParams(0.05, 0.7, 0.02, oil=0.6)
    wi = direction(np.radians(40.0))
    n = 200
    mu = (np.arange(n) + 0.5) / n
    phi = 2 * np.pi * (np.arange(2 * n) + 0.5) / (2 * n)
    m, p = np.meshgrid(mu, phi, indexing="ij")
    wo = np.stack([np.sqrt(1 - m**2) * np.cos(p), np.sqrt(1 - m**2) * np.sin(p), m], axis=-1).reshape(-1, 3)
    beta = np.asarray(skinfit.model.reflectance_factor(params, WAVELENGTHS, wi, wo))
    integral = np.sum(beta * m.reshape(-1, 1), axis=0) / n * (np.pi / n) / np.pi
    specular, subsurface = skinfit.model.surface_energy(params, WAVELENGTHS, wi)
    np.testing.assert_allclose(integral, float(specular) + np.asarray(subsurface), rtol=5e-3)


def test_without_oil_the_patch_is_lambertian_with_the_subsurface_reflectance():
    params = skinfit.SkinParams(0.05, 0.7, 0.02, oil=0.0)
    r12 = np.asarray(skinfit.diffuse_reflectance(params, WAVELENGTHS)) / (1 - (0.4 / 2.4) ** 2)
    for wi, wo in [(UP, UP), (direction(1.0), direction(0.3, 2.0)), (direction(1.4), direction(1.4, np.pi))]:
        np.testing.assert_allclose(skinfit.model.reflectance_factor(params, WAVELENGTHS, wi, wo), r12, rtol=1e-12)
    assert np.all(np.asarray(skinfit.model.brdf(params, WAVELENGTHS, UP, UP)) == 0.0)


def test_the_lobe_peaks_in_the_mirror_direction_and_scales_with_oil():
    params = skinfit.SkinParams(0.05, 0.7, 0.02, oil=np.array([0.25, 0.5]))
    wi = direction(0.5)
    mirror = direction(0.5, np.pi)
    off = direction(0.5, np.pi / 2)  # same polar angle, out of the plane of incidence
    at_mirror = np.asarray(skinfit.model.brdf(params, WAVELENGTHS, wi, mirror))
    assert np.all(at_mirror[..., 0] > np.asarray(skinfit.model.brdf(params, WAVELENGTHS, wi, off))[..., 0])
    assert at_mirror[1, 0] == pytest.approx(2 * at_mirror[0, 0])
    expected = surface.fresnel_dielectric(np.cos(0.5), 1.4) / (4 * np.pi * 0.35**2 * np.cos(0.5) ** 2)  # D(0) G=1 F / (4 cos^2)
    assert at_mirror[0, 0] == pytest.approx(0.25 * float(expected), rel=1e-10)


def test_no_nan_in_values_or_gradients_at_awkward_directions():
    def total(oil, roughness, wi, wo):
        params = skinfit.SkinParams(0.1, 0.7, 0.02, oil=oil)
        return jnp.sum(skinfit.model.reflectance_factor(params, WAVELENGTHS, wi, wo, roughness=roughness))

    grad = jax.jit(jax.grad(total, argnums=(0, 1, 2, 3)))
    cases = [
        (UP, UP), (direction(np.pi / 2), UP), (UP, direction(np.pi / 2)), (direction(1.2), -direction(1.2)),
        (np.array([0.0, 0.0, -1.0]), UP), (direction(1.5707), direction(1.5707, np.pi)), (direction(0.3), direction(0.3, np.pi)),
    ]
    for wi, wo in cases:
        value = total(0.5, 0.35, wi, wo)
        assert np.isfinite(float(value))
        assert all(np.all(np.isfinite(np.asarray(g))) for g in grad(0.5, 0.35, wi, wo))
    below = skinfit.model.reflectance_factor(skinfit.SkinParams(0.1, 0.7, 0.02, oil=1.0), WAVELENGTHS, UP, np.array([0.0, 0.6, -0.8]))
    assert np.all(np.asarray(below) == 0.0)


def test_vmap_over_directions_in_float32_matches_float64_one_by_one():
    directions = np.stack([direction(t) for t in np.linspace(0, 1.4, 5)])
    one_by_one = np.stack([np.asarray(skinfit.model.reflectance_factor(skinfit.SkinParams(0.1, 0.7, 0.02, oil=0.3), WAVELENGTHS, w, w))
                           for w in directions])
    params = skinfit.SkinParams(jnp.float32(0.1), jnp.float32(0.7), jnp.float32(0.02), oil=jnp.float32(0.3))
    lam = jnp.asarray(WAVELENGTHS, jnp.float32)
    f = jax.vmap(lambda w: skinfit.model.reflectance_factor(params, lam, w, w))
    out = f(jnp.asarray(directions, jnp.float32))
    assert out.shape == (5, 3) and out.dtype == jnp.float32
    # measured 1.1e-6 (2026-12-02): float32 round-off; a batching or dtype bug would be far larger
    np.testing.assert_allclose(np.asarray(out), one_by_one, rtol=1e-5)


def test_bad_directions_are_clear_errors():
    params = skinfit.preset("light")
    with pytest.raises(skinfit.SkinfitInputError, match="unit vectors"):
        skinfit.model.brdf(params, WAVELENGTHS, np.array([0.0, 0.0, 2.0]), UP)
    with pytest.raises(skinfit.SkinfitInputError, match=r"shape \(\.\.\., 3\)"):
        skinfit.model.reflectance_factor(params, WAVELENGTHS, np.array([0.0, 1.0]), UP)
    with pytest.raises(skinfit.SkinfitInputError, match="roughness"):
        skinfit.model.brdf(params, WAVELENGTHS, UP, UP, roughness=-1.0)


def test_reflectance_factor_takes_the_scattering_scale():
    """Without oil the patch returns R12(0), the diffuse reflectance with the entry Fresnel undone."""
    params = skinfit.SkinParams(0.05, 0.6, 0.02, oil=0.0)
    wl = np.array([450.0, 550.0, 650.0])
    normal = np.array([0.0, 0.0, 1.0])
    model = skinfit.SkinModel.dj2006()
    f0 = ((1.4 - 1.0) / (1.4 + 1.0)) ** 2
    for scale in (1.0, 2.0):
        got = skinfit.model.reflectance_factor(params, wl, normal, normal, model=model, scattering_scale=scale)
        expected = skinfit.diffuse_reflectance(params, wl, model=model, scattering_scale=scale) / (1.0 - f0)
        np.testing.assert_allclose(got, expected, rtol=1e-10)
