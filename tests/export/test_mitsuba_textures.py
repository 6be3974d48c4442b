"""Per-texel media rendered back in Mitsuba 3 (skinfit.export.render_textures): a uniform grid
renders its albedo, and the maps' row 0 comes out at the top (slow tier: Monte Carlo renders)."""

import numpy as np
import pytest

pytest.importorskip("mitsuba")

import skinfit  # noqa: E402
from skinfit import SkinfitInputError  # noqa: E402
from skinfit.export import render_textures, renderer_textures, textures_depth_mm  # noqa: E402

pytestmark = pytest.mark.slow


def _textures(melanin):
    shape = melanin.shape
    return renderer_textures({"melanin": melanin, "haemoglobin": np.full(shape, 0.01), "melanin_blend": np.full(shape, 0.7)})


def test_a_uniform_grid_renders_its_albedo_and_rows_keep_their_order():
    melanin = np.full((6, 6), 0.05)
    melanin[:2] = 0.3  # the maps' top rows darker
    textures = _textures(melanin)
    albedo = np.stack([textures[f"albedo.{c}"] for c in "RGB"], axis=-1)
    image = render_textures(textures, 4.0, spp=512, seed=1)
    assert image.shape == (6, 6, 3) and np.isfinite(image).all()
    # light from the bright rows crosses into the dark ones over millimetres (red most): compare the
    # far rows with their own albedo only where the blur has faded (green, 4 mm texels)
    bottom, top = image[4:].reshape(-1, 3).mean(axis=0), image[:1].reshape(-1, 3).mean(axis=0)
    assert top[1] < bottom[1] and top[2] < bottom[2]
    np.testing.assert_allclose(bottom[1:], albedo[5, 0, 1:], rtol=0.08)


def test_a_uniform_patch_renders_within_noise_of_its_albedo():
    textures = _textures(np.full((4, 4), 0.08))
    albedo = np.array([textures[f"albedo.{c}"][0, 0] for c in "RGB"])
    image = render_textures(textures, 20.0, spp=1024, seed=2)  # 80 mm square: the edges are far in every channel
    centre = image[1:3, 1:3].reshape(-1, 3)
    error = centre.std(axis=0, ddof=1) / np.sqrt(len(centre))
    assert np.all(np.abs(centre.mean(axis=0) - albedo) <= 4 * error + 0.01 * albedo), (centre.mean(axis=0), albedo, error)
    assert textures_depth_mm(textures) > 5.0


def test_bad_input_gets_a_clear_error():
    with pytest.raises(SkinfitInputError, match="mm_per_pixel"):
        render_textures(_textures(np.full((2, 2), 0.1)), 0.0)
    with pytest.raises(SkinfitInputError, match="sigma_t"):
        render_textures({"albedo.R": np.zeros((2, 2))}, 1.0)


def test_the_layered_texture_scene_loads_with_each_texels_coefficients(tmp_path):
    # rendering the per-texel grids to an albedo within 1 % is out of reach on CPU: Mitsuba's
    # heterogeneous medium (delta tracking) costs about 30x the homogeneous one per path and its red
    # error is about 10x larger at the same samples (docs/renderers.md); what loads is checked here
    from skinfit.export import layered_textures, mitsuba_layered_texture_shapes
    from skinfit.export._mitsuba import _mitsuba, _slab_scene, rgb_film

    melanin = np.full((2, 3), 0.05)
    melanin[0] = 0.2  # the maps' top row
    textures = layered_textures({"melanin": melanin, "haemoglobin": np.full((2, 3), 0.01)}, grid=2)
    mi = _mitsuba("scalar_rgb")
    shapes = mitsuba_layered_texture_shapes(mi, textures, tmp_path, mm_per_pixel=1.0)
    params = mi.traverse(mi.load_dict(_slab_scene(mi, None, rgb_film(2), spp=1, seed=0, view_mm=1.0, extra=shapes)))
    for layer in ("epidermis", "dermis"):
        a, s = getattr(textures, f"{layer}_absorption_per_mm"), getattr(textures, f"{layer}_scattering_per_mm")
        sigma_t = np.asarray(params[f"{layer}.sigma_t.data"])[0] * params[f"{layer}.scale"]
        np.testing.assert_allclose(sigma_t, (a + s)[::-1], rtol=1e-5)  # row 0 of the maps at +y, the grids' last row
        np.testing.assert_allclose(np.asarray(params[f"{layer}.albedo.data"])[0], (s / (a + s))[::-1], rtol=1e-6)
    assert params["epidermis.phase_function.g"] == pytest.approx(textures.anisotropy)  # (Mitsuba lists a shared phase once)
    top, bottom = np.asarray(params["epidermis.sigma_t.data"])[0, -1], np.asarray(params["epidermis.sigma_t.data"])[0, 0]
    assert np.all(top[:, 2] > bottom[:, 2])  # the darker row absorbs more blue in the epidermis
