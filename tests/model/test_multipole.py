"""The closed-form infinite multipole against independent references and its limits."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from skinfit.model import (
    boundary_coefficient,
    dipole_profile,
    dipole_transfer,
    fresnel_diffuse_reflectance,
    slab_response,
)

from .. import reference as ref

# (thickness mm, sigma_a mm^-1, sigma_s' mm^-1): slabs from 0.01 to 10 mm, each with l < d.
SLABS = [
    (0.01, 5.0, 500.0),
    (0.1, 0.01, 10.0),  # thin and weakly absorbing: the image series converges slowly (model notes 5.3)
    (0.25, 0.05, 5.0),  # the epidermis-like case of model notes 5.3
    (1.0, 0.2, 3.0),
    (10.0, 0.01, 2.0),
]
ETA_TOP, ETA_BOTTOM = 1.4, 1.0


def test_boundary_constants():
    assert float(fresnel_diffuse_reflectance(1.4)) == pytest.approx(0.52949, abs=1e-5)
    assert float(boundary_coefficient(1.4)) == pytest.approx(3.2507, abs=1e-4)
    assert float(boundary_coefficient(1.0)) == pytest.approx(1.0032, abs=1e-4)
    assert float(fresnel_diffuse_reflectance(1 / 1.4)) == pytest.approx(0.0780, abs=1e-4)


@pytest.mark.parametrize("d, sigma_a, sigma_s", SLABS)
def test_closed_form_equals_image_series_in_q(d, sigma_a, sigma_s):
    q = np.array([0.0, 0.3, 1.0, 5.0, 20.0, 100.0]) / max(d, 0.1)
    expected_r, expected_t = ref.image_sum_transfer(sigma_a, sigma_s, d, ETA_TOP, ETA_BOTTOM, q, n=20000)
    got = slab_response(sigma_a, sigma_s, d, ETA_TOP, ETA_BOTTOM, q)
    np.testing.assert_allclose(got.reflect_top, expected_r, rtol=1e-6)
    np.testing.assert_allclose(got.transmit_top, expected_t, rtol=1e-6, atol=1e-300)


@pytest.mark.parametrize("d, sigma_a, sigma_s", SLABS)
def test_closed_form_equals_forward_hankel_of_real_space_image_sum(d, sigma_a, sigma_s):
    g = ref.slab_geometry(sigma_a, sigma_s, d, ETA_TOP, ETA_BOTTOM)
    r_max = 45.0 / g["sigma_tr"]
    q = np.array([0.0, 0.5, 2.0, 8.0]) / max(d, 0.25)
    # images out to |z| where e^{-sigma_tr |z|} < 1e-17: beyond that they change no transform value
    n_images = int(np.ceil(40.0 / (2 * (d + g["zb0"] + g["zbd"]) * g["sigma_tr"]))) + 2
    refl = ref.forward_hankel(lambda r: ref.image_sum_profiles(sigma_a, sigma_s, d, ETA_TOP, ETA_BOTTOM, r, n_images)[0], q, r_max)
    trans = ref.forward_hankel(lambda r: ref.image_sum_profiles(sigma_a, sigma_s, d, ETA_TOP, ETA_BOTTOM, r, n_images)[1], q, r_max)
    got = slab_response(sigma_a, sigma_s, d, ETA_TOP, ETA_BOTTOM, q)
    np.testing.assert_allclose(got.reflect_top, refl, rtol=1e-6)
    np.testing.assert_allclose(got.transmit_top, trans, rtol=1e-6)


def test_eleven_dipole_image_sum_error_as_in_model():
    """pbrt-v2-skin's 11 dipole pairs: 1.5e-3 (R) and 5e-4 (T) relative error (model notes 5.3 table)."""
    q = np.array([0.0, 1.0, 5.0, 20.0, 100.0])
    exact = slab_response(0.05, 5.0, 0.25, ETA_TOP, ETA_BOTTOM, q)
    r11, t11 = ref.image_sum_transfer(0.05, 5.0, 0.25, ETA_TOP, ETA_BOTTOM, q, n=5)
    err_r = np.max(np.abs(r11 / exact.reflect_top - 1))
    err_t = np.max(np.abs(t11 / exact.transmit_top - 1))
    assert err_r == pytest.approx(1.5e-3, rel=0.1)
    assert err_t == pytest.approx(5e-4, rel=0.15)


@pytest.mark.parametrize("sigma_a, expected", [(0.01, 0.614095), (0.1, 0.297672), (0.5, 0.124234)])
def test_semi_infinite_limit_is_jensen_2001(sigma_a, expected):
    """model notes 5.2: alpha' = 0.990 / 0.909 / 0.667, that is sigma_a = 0.01 / 0.1 / 0.5 with sigma_s' = 1."""
    sigma_s = 1.0
    albedo = sigma_s / (sigma_a + sigma_s)
    got = float(slab_response(sigma_a, sigma_s, np.inf, ETA_TOP, 1.0).reflect_top)
    a = float(boundary_coefficient(ETA_TOP))
    jensen = 0.5 * albedo * (1 + np.exp(-4 / 3 * a * np.sqrt(3 * (1 - albedo)))) * np.exp(-np.sqrt(3 * (1 - albedo)))
    assert got == pytest.approx(jensen, rel=1e-12)
    assert got == pytest.approx(expected, abs=2e-6)


def test_thick_slab_tends_to_semi_infinite_and_transmits_nothing():
    thick = slab_response(0.1, 3.0, 1e3, ETA_TOP, 1.0, np.array([0.0, 1.0]))
    semi = slab_response(0.1, 3.0, np.inf, ETA_TOP, 1.0, np.array([0.0, 1.0]))
    np.testing.assert_allclose(thick.reflect_top, semi.reflect_top, rtol=1e-14)
    assert np.all(np.asarray(thick.transmit_top) < 1e-300 + 1e-200)


@pytest.mark.parametrize("d", [1e-4, 0.01, 0.25, 10.0])
def test_non_absorbing_slab_conserves_energy(d):
    """sigma_a = 0, q = 0: k = 0 exactly, and R + T = 1 (all light leaves through a face)."""
    resp = slab_response(0.0, 20.0, d, ETA_TOP, ETA_BOTTOM, 0.0)
    assert float(resp.reflect_top + resp.transmit_top) == pytest.approx(1.0, abs=1e-12)
    assert float(resp.reflect_bottom + resp.transmit_bottom) == pytest.approx(1.0, abs=1e-12)
    assert float(slab_response(0.0, 20.0, np.inf, ETA_TOP, 1.0).reflect_top) == pytest.approx(1.0, abs=1e-12)


def test_limits_are_continuous():
    # absorption -> 0 and q -> 0 approach the exact k = 0 value
    at_zero = slab_response(0.0, 5.0, 0.25, ETA_TOP, ETA_BOTTOM, 0.0)
    near = slab_response(1e-12, 5.0, 0.25, ETA_TOP, ETA_BOTTOM, 1e-9)
    for a, b in zip(at_zero, near):
        assert float(a) == pytest.approx(float(b), abs=1e-8)
    # very thin slabs: finite, R + T <= 1, and converging as d -> 0
    d = np.geomspace(1e-9, 1e-2, 50)
    resp = slab_response(0.5, 10.0, d, ETA_TOP, ETA_BOTTOM, 0.0)
    total = np.asarray(resp.reflect_top + resp.transmit_top)
    assert np.all(np.isfinite(total)) and np.all(total <= 1.0)
    assert abs(float(resp.reflect_top[0] - resp.reflect_top[1])) < 1e-6


def test_light_from_below_swaps_the_boundaries():
    q = np.array([0.0, 2.0, 10.0])
    up = slab_response(0.1, 5.0, 0.3, ETA_TOP, ETA_BOTTOM, q)
    flipped = slab_response(0.1, 5.0, 0.3, ETA_BOTTOM, ETA_TOP, q)
    np.testing.assert_allclose(up.reflect_bottom, flipped.reflect_top, rtol=1e-14)
    np.testing.assert_allclose(up.transmit_bottom, flipped.transmit_top, rtol=1e-14)


def test_no_overflow_at_extremes():
    q = np.array([0.0, 1e-8, 1.0, 1e2, 1e4])[:, None]
    sigma_a = np.array([0.0, 1e-6, 0.1, 100.0, 1e4])
    for d in (1e-4, 0.25, 10.0, np.inf):
        resp = slab_response(sigma_a, 10.0, d, ETA_TOP, ETA_BOTTOM, q)
        for value in resp:
            assert np.all(np.isfinite(np.asarray(value)))
            assert np.all(np.asarray(value) >= 0) and np.all(np.asarray(value) <= 1)


def test_gradients_are_finite_including_semi_infinite_and_zero_absorption():
    def total(params):
        sigma_a, sigma_s, q = params
        out = 0.0
        for d in (1e-4, 0.25, jnp.inf):
            out += sum(jnp.sum(v) for v in slab_response(sigma_a, sigma_s, d, ETA_TOP, ETA_BOTTOM, q))
        return out

    for point in [(0.0, 5.0, 0.0), (0.1, 5.0, 0.0), (1e3, 1.0, 1e4)]:
        grads = jax.grad(total)(tuple(jnp.asarray(v) for v in point))
        assert all(np.isfinite(float(g)) for g in grads), point


def test_dipole_pair_is_a_transform_pair():
    q = np.array([0.0, 1.0, 4.0])
    expected = ref.forward_hankel(lambda r: np.asarray(dipole_profile(0.1, 5.0, ETA_TOP, r)), q, r_max=200.0)
    np.testing.assert_allclose(dipole_transfer(0.1, 5.0, ETA_TOP, q), expected, rtol=1e-7)
