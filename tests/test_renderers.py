"""Renderer exports: energy (every exported profile integrates to its reflectance), the radius
bound, the sum-of-Gaussians and Burley fits, the per-channel medium, files and textures."""

import json

import numpy as np
import pytest

import skinfit
from skinfit import renderers as rd
from skinfit.colorimetry import linear_srgb_weights

WAVELENGTHS = np.arange(400.0, 701.0, 10.0)


@pytest.fixture(scope="module")
def presets():
    return {name: rd.renderer_profiles(skinfit.preset(name), WAVELENGTHS, label=name) for name in skinfit.PRESET_NAMES}


def test_every_exported_profile_integrates_to_its_reflectance(presets):
    for result in presets.values():
        spectral = rd.cumulative_energy(result.radii_mm, result.spectral)[:, -1]
        np.testing.assert_allclose(spectral, result.reflectance, rtol=1e-4)
        rgb = rd.cumulative_energy(result.radii_mm, result.rgb)[:, -1]
        np.testing.assert_allclose(rgb, result.rgb_albedo, rtol=1e-4)
        for i, channel in enumerate(rd.CHANNELS):
            assert sum(result.gaussians[channel]["weights"]) == pytest.approx(result.rgb_albedo[i], rel=1e-4)
            assert result.burley[channel]["albedo"] == pytest.approx(result.rgb_albedo[i], rel=1e-12)
        # the normalisation is small: the table holds 99.7 % of the energy before it
        assert np.all(np.abs(np.asarray(result.metadata["rgb_scale"]) - 1) < 5e-3)


def test_the_largest_radius_holds_the_stated_energy(presets):
    # independent of the table: the energy-kernel quadrature of captured_reflectance
    for name, result in presets.items():
        captured = np.asarray(skinfit.captured_reflectance(skinfit.preset(name), WAVELENGTHS, result.max_radius_mm))
        fraction = linear_srgb_weights(WAVELENGTHS) @ captured / result.rgb_albedo
        assert np.all(fraction >= 0.997 - 1e-3)
        assert np.min(np.abs(fraction - 0.997)) < 1e-3  # the limiting channel sits on the bound


def test_sum_of_gaussians_within_one_percent_where_the_profile_is_non_negative(presets):
    # linear-sRGB profiles dip below zero at large r where the sRGB primaries weigh a long red tail
    # negatively; a non-negative sum of Gaussians cannot follow that part, so the bound grows by it
    for name, result in presets.items():
        radii = np.geomspace(1e-5, 2 * result.max_radius_mm, 3000)
        rgb = linear_srgb_weights(WAVELENGTHS) @ np.asarray(skinfit.profile(skinfit.preset(name), WAVELENGTHS, radii, entry_fresnel=True))
        negative = (rd._energy_measure(radii) * np.maximum(-rgb, 0)).sum(axis=1) / result.rgb_albedo
        for i, channel in enumerate(rd.CHANNELS):
            assert result.gaussians[channel]["energy_error"] <= max(0.01, 1.1 * negative[i]), (name, channel)
            fitted = rd.gaussian_sum(radii, result.gaussians[channel]["variances_mm2"], result.gaussians[channel]["weights"])
            assert np.all(np.isfinite(fitted))
    assert all(presets["light"].gaussians[c]["energy_error"] <= 0.01 for c in rd.CHANNELS)


def test_the_medium_reproduces_albedo_and_median_radius(presets):
    for result in presets.values():
        medium = result.medium
        for i in range(3):
            layer = skinfit.Layer(absorption=medium["absorption_per_mm"][i], reduced_scattering=medium["reduced_scattering_per_mm"][i],
                                  thickness=float("inf"), ior=1.4)
            assert float(skinfit.layered_reflectance([layer])) == pytest.approx(result.rgb_albedo[i], rel=1e-4)
            radius = medium["median_radius_mm"][i]
            inside = float(rd._unit_medium_energy(medium["reduced_albedo"][i], 1.4, radius / medium["mean_free_path_mm"][i]))
            assert inside == pytest.approx(0.5 * result.rgb_albedo[i], rel=1e-3)


def test_files_for_renderers(presets, tmp_path):
    result = presets["medium"]
    snippet = rd.write_renderer(result, "pbrt", tmp_path / "skin.pbrt").read_text()
    sigma_a = [float(v) for v in snippet.split('"rgb sigma_a" [')[1].split("]")[0].split()]
    np.testing.assert_allclose(sigma_a, result.medium["absorption_per_mm"], rtol=1e-5)
    assert '"string type" "subsurface"' in snippet and '"float scale" 1000' in snippet
    blender = json.loads(rd.write_renderer(result, "blender", tmp_path / "b.json").read_text())
    assert blender["Subsurface Radius"] == result.medium["mean_free_path_mm"] and blender["metadata"]["units"]["radius"] == "mm"
    lines = [line for line in rd.write_renderer(result, "table", tmp_path / "t.csv").read_text().splitlines() if not line.startswith("#")]
    assert lines[0].startswith("radius_mm,R_400nm")
    table = np.loadtxt(lines[1:], delimiter=",")
    assert table.shape == (256, 1 + WAVELENGTHS.size + 3) and table[-1, 0] == pytest.approx(result.max_radius_mm)
    with pytest.raises(skinfit.SkinfitInputError, match="unknown renderer format"):
        rd.write_renderer(result, "mitsuba", tmp_path / "x")


def test_textures_from_maps_match_the_per_pixel_medium():
    melanin = np.array([[0.01, 0.05], [0.2, 0.4]])
    haemoglobin = np.array([[0.005, 0.02], [0.05, 0.08]])
    textures = rd.renderer_textures({"melanin": melanin, "haemoglobin": haemoglobin, "melanin_blend": 0.7}, grid=8)
    albedo, median = rd.median_radius(skinfit.SkinParams(melanin[1, 0], 0.7, haemoglobin[1, 0]))
    mfp = rd.homogeneous_medium(albedo, median)["mean_free_path_mm"]
    # the grid corners are exact; elsewhere bilinear in log concentration
    np.testing.assert_allclose([textures[f"mfp.{c}"][1, 0] for c in "RGB"], mfp, rtol=2e-2)
    np.testing.assert_allclose([textures[f"albedo.{c}"][1, 0] for c in "RGB"], albedo, rtol=1e-5)
