"""The renderer's blur on a texel grid (skinfit.export.profile_kernel, blur_albedo) and its inverse
(deconvolve_albedo), against the model's cumulative radial energy and round trips."""

import numpy as np
import pytest

import skinfit
from skinfit import SkinfitInputError
from skinfit.colorimetry import linear_srgb_weights
from skinfit.export import blur_albedo, cumulative_energy, deconvolve_albedo, profile_kernel
from skinfit.model import profile

LIGHT = skinfit.preset("light")


@pytest.fixture(scope="module")
def kernel_03mm():
    return profile_kernel(LIGHT, 0.3)


def test_the_kernel_holds_each_channels_light_and_spreads_red_most(kernel_03mm):
    k = kernel_03mm
    centre = k.shape[0] // 2
    np.testing.assert_allclose(k.sum(axis=(0, 1)), 1.0, rtol=1e-12)
    assert (k >= 0).all()
    np.testing.assert_allclose(k, k[::-1, ::-1], atol=1e-12)  # point-symmetric
    np.testing.assert_allclose(k, k.transpose(1, 0, 2), atol=1e-12)
    share = k[centre, centre]
    assert share[0] < share[1] < share[2] < 1


def test_the_kernel_follows_the_models_energy_within_a_radius():
    # pixels 0.02 mm: the share of the central (2m+1)^2 block lies between the model's energy
    # within the block's inscribed and circumscribed circles (the texel's entry spread is 0.01 mm)
    pixel = 0.02
    k = profile_kernel(LIGHT, pixel, radius_pixels=60)
    lam = np.arange(400.0, 701.0, 10.0)
    radii = np.geomspace(1e-4, 30.0, 600)
    rgb = linear_srgb_weights(lam) @ np.asarray(profile(LIGHT, lam, radii, entry_fresnel=True))
    energy = np.asarray(cumulative_energy(radii, rgb))
    energy /= energy[:, -1:]
    centre = k.shape[0] // 2
    for m in (5, 15, 40):
        share = k[centre - m:centre + m + 1, centre - m:centre + m + 1].sum(axis=(0, 1))
        inner = np.array([np.interp((m + 0.5) * pixel - 0.01, radii, e) for e in energy])
        outer = np.array([np.interp((m + 0.5) * pixel * np.sqrt(2) + 0.01, radii, e) for e in energy])
        within = energy[:, np.searchsorted(radii, 60.5 * pixel)]  # what the kernel keeps (it is normalised)
        assert np.all(share * within >= inner - 5e-3) and np.all(share * within <= outer + 5e-3), (m, share, inner, outer)


def test_a_uniform_albedo_is_unchanged_and_an_edge_softens(kernel_03mm):
    flat = np.full((40, 50, 3), 0.35)
    np.testing.assert_allclose(blur_albedo(flat, kernel_03mm), flat, atol=1e-12)
    edge = np.full((40, 50, 3), 0.2)
    edge[:, 25:] = 0.5
    blurred = blur_albedo(edge, kernel_03mm)
    assert np.all(blurred[20, 24] > 0.2) and np.all(blurred[20, 25] < 0.5)  # light crosses from the bright side
    gained = blurred[20, 22] - 0.2  # three texels (0.9 mm) from the edge
    assert gained[0] > gained[1] > gained[2] >= 0  # red crosses farther than green, green than blue


def test_deconvolution_undoes_the_blur(kernel_03mm):
    rng = np.random.default_rng(3)
    smooth = blur_albedo(np.clip(0.4 + 0.15 * rng.standard_normal((48, 48, 3)), 0, 1), profile_kernel(LIGHT, 0.6))
    once = blur_albedo(smooth, kernel_03mm)
    back = deconvolve_albedo(once, kernel_03mm, regularisation=1e-9)
    inner = (slice(8, -8), slice(8, -8))  # the mirrored borders are not the image's
    assert np.abs(once - smooth)[inner].max() > 1e-2
    np.testing.assert_allclose(back[inner], smooth[inner], atol=2e-3)
    # more regularisation keeps more of the blur
    kept = deconvolve_albedo(once, kernel_03mm, regularisation=1e-1)
    assert np.abs(kept - smooth)[inner].mean() > np.abs(back - smooth)[inner].mean()


def test_a_mask_keeps_the_background_out(kernel_03mm):
    image = np.full((30, 30, 3), 0.3)
    image[:, :10] = 0.0  # background
    mask = np.zeros((30, 30), bool)
    mask[:, 10:] = True
    blurred = blur_albedo(image, kernel_03mm, mask=mask)
    np.testing.assert_allclose(blurred[:, 10:], 0.3, atol=1e-12)  # the black background does not bleed in


def test_bad_input_gets_a_clear_error(kernel_03mm):
    with pytest.raises(SkinfitInputError, match="mm_per_pixel"):
        profile_kernel(LIGHT, 0.0)
    with pytest.raises(SkinfitInputError, match=r"\(h, w, 3\)"):
        blur_albedo(np.zeros((4, 4)), kernel_03mm)
    with pytest.raises(SkinfitInputError, match="kernel"):
        blur_albedo(np.zeros((4, 4, 3)), np.ones((4, 4, 3)))
    with pytest.raises(SkinfitInputError, match="regularisation"):
        deconvolve_albedo(np.zeros((4, 4, 3)), kernel_03mm, regularisation=0.0)
    with pytest.raises(SkinfitInputError, match="mask"):
        blur_albedo(np.zeros((4, 4, 3)), kernel_03mm, mask=np.zeros((3, 3), bool))
