import colour
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import skinfit
from skinfit import colorimetry as col


@pytest.mark.parametrize("illuminant", ["D65", "D50", "A", "E"])
def test_perfect_white_is_y_one_and_rgb_one(illuminant):
    wl = np.arange(400.0, 701.0, 10.0)
    white = np.ones(wl.size)
    assert float(col.spectrum_to_xyz(white, wl, illuminant=illuminant)[1]) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(col.spectrum_to_linear_srgb(white, wl, illuminant=illuminant), 1.0, atol=1e-12)


@pytest.mark.filterwarnings("ignore:.*shape could not be honoured")  # colour-science's own resampling note
@pytest.mark.parametrize("step", [1.0, 5.0, 10.0])
def test_xyz_agrees_with_colour_science(light, step):
    wl = np.arange(380.0, 781.0, step)
    reflectance = np.asarray(skinfit.diffuse_reflectance(light, wl))
    expected = colour.sd_to_XYZ(colour.SpectralDistribution(dict(zip(wl, reflectance))), illuminant=colour.SDS_ILLUMINANTS["D65"]) / 100
    np.testing.assert_allclose(col.spectrum_to_xyz(reflectance, wl), expected, atol=2e-4)


def test_srgb_matches_colour_science_and_round_trips():
    xyz = np.array([[0.3, 0.25, 0.2], [0.05, 0.04, 0.03], [0.9, 0.95, 1.0]])
    ours = np.asarray(col.srgb_encode(col.xyz_to_linear_srgb(xyz)))
    theirs = colour.XYZ_to_sRGB(xyz)
    np.testing.assert_allclose(ours, theirs, atol=2e-4)
    x = jnp.linspace(0.0, 1.0, 101)
    np.testing.assert_allclose(col.srgb_decode(col.srgb_encode(x)), x, atol=1e-12)


def test_encoding_gradients_are_finite_at_zero():
    for f in (col.srgb_encode, col.srgb_decode):
        g = jax.vmap(jax.grad(f))(jnp.array([0.0, 1e-9, 0.003, 0.5, 1.0]))
        assert bool(jnp.all(jnp.isfinite(g)))


def test_colour_is_differentiable_through_the_model(light):
    wl = np.arange(400.0, 701.0, 10.0)
    g = jax.grad(lambda p: col.spectrum_to_srgb(skinfit.diffuse_reflectance(p, wl), wl)[0])(light)
    assert float(g.melanin) < 0


def test_bad_colour_input_gives_clear_errors():
    with pytest.raises(skinfit.SkinfitInputError, match="increasing"):
        col.xyz_weights([500.0, 400.0])
    with pytest.raises(skinfit.SkinfitInputError, match="illuminant"):
        col.xyz_weights([400.0, 500.0], illuminant="moonlight")
    with pytest.raises(skinfit.SkinfitInputError, match="last axis"):
        col.spectrum_to_xyz(np.ones(4), [400.0, 500.0])


def test_lab_of_linear_srgb_matches_colour_science():
    rgb = np.random.default_rng(1).random((200, 3)) ** 3  # dark colours too, below the Lab knee
    space = colour.RGB_COLOURSPACES["sRGB"]
    expected = colour.XYZ_to_Lab(colour.RGB_to_XYZ(rgb, space, apply_cctf_decoding=False), space.whitepoint)
    np.testing.assert_allclose(col.linear_srgb_to_lab(rgb), expected, atol=1e-10)


def test_lab_of_xyz_matches_colour_science():
    xyz = np.random.default_rng(4).random((200, 3)) ** 3  # dark colours too, below the Lab knee
    for illuminant in ("D65", "A"):
        white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"][illuminant]
        np.testing.assert_allclose(col.xyz_to_lab(xyz, illuminant=illuminant), colour.XYZ_to_Lab(xyz, white), atol=1e-10)
    with pytest.raises(skinfit.SkinfitInputError, match="white point"):
        col.xyz_to_lab(xyz, illuminant="moonlight")


def test_delta_e2000_matches_colour_science():
    rng = np.random.default_rng(2)
    lab_1 = rng.uniform([0, -60, -60], [100, 60, 60], (5000, 3))
    # near pairs (the fits' residuals), far pairs, and the hue-wrap and achromatic branches
    lab_2 = np.concatenate([lab_1[:2000] + rng.normal(0, 0.5, (2000, 3)), rng.uniform([0, -60, -60], [100, 60, 60], (3000, 3))])
    lab_1[:50, 1:] = 0.0
    lab_2[50:100, 1] = -np.abs(lab_2[50:100, 1])
    lab_1[50:100, 1] = -np.abs(lab_1[50:100, 1])
    expected = colour.delta_E(lab_1, lab_2, method="CIE 2000")
    np.testing.assert_allclose(col.delta_e2000(lab_1, lab_2), expected, rtol=1e-9, atol=1e-9)
