"""Radial profiles against independent references: real-space image sums, a 2-D FFT, and energy."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skinfit
from skinfit.model import HankelQuadrature, Layer, layered_profile, profile

from .. import reference as ref
from ..conftest import DJ2006


def assert_profile_close(got, expected, rtol=1e-6, floor=1e-13):
    """Relative agreement, except in far tails below ``floor`` times the peak (float64 round-off there)."""
    got, expected = np.asarray(got), np.asarray(expected)
    peak = np.abs(expected).max(axis=-1, keepdims=True)
    excess = np.abs(got - expected) - (rtol * np.abs(expected) + floor * peak)
    assert np.all(excess <= 0), f"max relative error {np.max(np.abs(got - expected) / np.maximum(np.abs(expected), floor * peak)):.3g}"


def _energy(radii, values):
    return np.trapezoid(2 * np.pi * radii**2 * np.asarray(values), np.log(radii), axis=-1)


@pytest.mark.parametrize("name", skinfit.PRESET_NAMES)
def test_profile_integrates_to_r12(name):
    params = skinfit.preset(name)
    wl = np.arange(400.0, 701.0, 20.0)
    radii = np.geomspace(1e-5, 200.0, 4000)
    values = profile(params, wl, radii, model=DJ2006)
    r12 = skinfit.model.stack_transfer(skinfit.model.skin_layers(params, wl, model=DJ2006), 0.0)
    np.testing.assert_allclose(_energy(radii, values), r12, rtol=1e-4)
    with_fresnel = profile(params, wl, radii, entry_fresnel=True, model=DJ2006)
    np.testing.assert_allclose(_energy(radii, with_fresnel), skinfit.diffuse_reflectance(params, wl, model=DJ2006), rtol=1e-4)


@pytest.mark.parametrize("d, sigma_a, sigma_s", [(0.1, 0.05, 20.0), (0.25, 0.05, 5.0), (1.0, 0.2, 3.0), (10.0, 0.01, 2.0)])
def test_single_slab_profile_matches_real_space_image_sum(d, sigma_a, sigma_s):
    radii = np.geomspace(0.01, 10.0, 40)
    expected, _ = ref.image_sum_profiles(sigma_a, sigma_s, d, 1.4, 1.0, radii, n=3000)
    # tissue below (ior_below = 1.4) makes the bottom boundary index-matched, as in the reference
    got = np.asarray(layered_profile([Layer(sigma_a, sigma_s, d)], radii, ior_below=1.4))
    assert_profile_close(got, expected)


def test_thin_slab_needs_and_accepts_a_larger_q_range():
    radii = np.geomspace(0.002, 1.0, 30)
    expected, _ = ref.image_sum_profiles(5.0, 500.0, 0.01, 1.4, 1.0, radii, n=3000)
    got = np.asarray(
        layered_profile([Layer(5.0, 500.0, 0.01)], radii, ior_below=1.4, quadrature=HankelQuadrature(q_max=3000.0))
    )
    assert_profile_close(got, expected)


@pytest.mark.parametrize("name, wavelength", [("light", 550.0), ("light", 650.0), ("medium", 700.0)])
def test_two_layer_profile_matches_2d_fft(name, wavelength):
    layers = skinfit.model.skin_layers(skinfit.preset(name), np.array([wavelength]), model=DJ2006)
    layers = [jax.tree_util.tree_map(lambda a: a[0] if jnp.ndim(a) else a, layer) for layer in layers]
    radii_fft, values_fft = ref.fft_profile(lambda q: np.asarray(skinfit.model.stack_transfer(layers, q)))
    keep = (radii_fft > 0) & (radii_fft <= 1.0)
    got = np.asarray(layered_profile(layers, radii_fft[keep]))
    assert_profile_close(got, values_fft[keep])


def test_profiles_are_non_negative_and_finite_with_gradients():
    params = skinfit.SkinParams(melanin=jnp.array([0.001, 0.5, 1.0]), melanin_blend=jnp.array([0.0, 0.7, 1.0]), haemoglobin=jnp.array([0.001, 0.1, 1.0]))
    wl = np.arange(380.0, 1001.0, 40.0)
    radii = np.geomspace(1e-3, 30.0, 64)
    values = np.asarray(profile(params, wl, radii))
    assert values.shape == (3, wl.size, radii.size)
    assert np.all(np.isfinite(values))
    assert values.min() >= -1e-12 * values.max()
    grad = jax.grad(lambda p: profile(p, wl, radii).sum())(params)
    assert all(bool(jnp.all(jnp.isfinite(g))) for g in jax.tree_util.tree_leaves(grad))


def test_profile_jits_over_parameters_and_float32_works(light):
    radii = np.geomspace(1e-3, 10.0, 32)
    wl = np.arange(400.0, 701.0, 50.0)
    jitted = jax.jit(lambda p, lam: profile(p, lam, radii))
    assert_profile_close(jitted(light, wl), profile(light, wl, radii), rtol=1e-12, floor=1e-15)
    p32 = jax.tree_util.tree_map(lambda a: a.astype(jnp.float32), light)
    v32 = profile(p32, wl.astype(np.float32), radii)
    assert v32.dtype == jnp.float32
    v64 = np.asarray(profile(light, wl, radii))
    assert np.max(np.abs(np.asarray(v32) - v64) / v64.max(axis=-1, keepdims=True)) < 1e-5


def test_bad_radii_give_clear_errors(light):
    with pytest.raises(skinfit.SkinfitInputError, match="radii_mm"):
        profile(light, [500.0], [-1.0, 1.0])
    with pytest.raises(skinfit.SkinfitInputError, match="concrete"):
        jax.jit(lambda r: profile(light, [500.0], r))(jnp.ones(3))
