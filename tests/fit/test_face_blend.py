"""The melanin blend of each face (``estimate_blends``) and the standard errors it widens."""

import numpy as np
import pytest

from benchmarks.fit_image_box import colour_science_render
from skinfit import SkinModel
from skinfit.fit import BLEND_GRID, PixelStatus, estimate_blends, fit_image


def _patch(melanin, blend, shading=0.85, size=12, seed=0):
    """A face-like patch rendered by colour-science: melanin and haemoglobin varying a little over
    it, a smooth shading about ``shading``."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / (size - 1)
    c_m = melanin * (1 + 0.1 * (x - 0.5)) * np.exp(0.02 * rng.standard_normal((size, size)))
    c_h = 0.02 * (1 + 0.3 * (y - 0.5))
    k = shading * (1 + 0.04 * np.sin(3 * x + 2 * y))
    return colour_science_render(c_m, c_h, k, blend, SkinModel.default()), c_m


def test_an_albedo_capture_measures_each_faces_blend():
    """Two people of other blends side by side, as an albedo capture (shading held to its scale):
    each gets a blend of their own within 0.15 of the truth, off the bounds, with a posterior sd
    that holds the truth within 2.5 sd; fixing the population's blend instead biases the darker
    face's melanin by more. Measured on 2026-12-05: blends 0.175 / 0.925 (true 0.1 / 0.8), the scale
    1.01 against a true 0.85 (blend and scale trade off in three channels), the darker face's melanin
    +10 % (at the population's blend: scale 1.69, half the pixels not fitted, melanin +55 %)."""
    dark, dark_melanin = _patch(0.25, 0.1, seed=1)
    light, light_melanin = _patch(0.04, 0.8, seed=2)
    rgb = np.concatenate([dark, light], axis=1)
    labels = np.concatenate([np.full(dark.shape[:2], 1), np.full(light.shape[:2], 2)], axis=1).astype(np.int16)
    fit = fit_image(rgb, white_balance="none", segmentation="none", input_type="albedo", blend_regions=labels, progress=False)
    found = {b["label"]: b for b in fit.blends}
    for label, truth in ((1, 0.1), (2, 0.8)):
        assert abs(found[label]["melanin_blend"] - truth) <= 0.15, found[label]
        assert abs(found[label]["melanin_blend"] - truth) <= 2.5 * found[label]["sd"] + 0.025, found[label]
        assert BLEND_GRID[0] <= found[label]["melanin_blend"] <= BLEND_GRID[-1]
    assert np.all(fit.status[labels > 0] == PixelStatus.SUCCESS)
    assert np.all(fit.melanin_blend[labels == 1] == np.float32(found[1]["melanin_blend"]))
    assert np.all(fit.melanin_blend_sd[labels == 2] == np.float32(found[2]["sd"]))
    error = np.median(np.abs(fit.melanin[:, :12] / dark_melanin - 1))
    fixed = fit_image(rgb, white_balance="none", segmentation="none", input_type="albedo", melanin_blend=0.423, progress=False)
    fixed_error = np.median(np.abs(fixed.melanin[:, :12] / dark_melanin - 1)[fixed.status[:, :12] == PixelStatus.SUCCESS])
    assert error <= 0.15 and error < fixed_error
    assert fixed.melanin_blend_sd is None and fixed.blends == ()


def test_a_photo_of_light_skin_leaves_the_blend_to_the_prior_and_says_so():
    """With the shading free, light skin fits at every blend: the face's posterior is the
    population prior's (sd above 0.2), and the melanin standard errors carry that doubt."""
    rgb, melanin = _patch(0.03, 0.9)
    fit = fit_image(rgb, white_balance="none", segmentation="none", progress=False)
    (blend,) = fit.blends
    assert blend["sd"] > 0.2
    ok = fit.status == PixelStatus.SUCCESS
    assert ok.all()
    relative_se = fit.melanin_se[ok] / fit.melanin[ok]
    assert np.median(relative_se) > 0.05
    # the truth inside two standard errors at most pixels
    assert np.mean(np.abs(fit.melanin[ok] - melanin[ok]) <= 2 * fit.melanin_se[ok]) >= 0.9


def test_estimate_blends_checks_its_faces():
    with pytest.raises(ValueError, match="fittable"):
        estimate_blends([np.zeros((0, 3))])
