"""Renderer exports: energy (every exported profile integrates to its reflectance), the radius
bound, the sum-of-Gaussians and Burley fits, the per-channel medium, files and textures."""

import json

import numpy as np
import pytest

import skinfit
from skinfit import renderer_media as rm
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


def test_the_media_have_the_model_albedo_and_median_radius_in_exact_transport(presets):
    # independent of the tables' interpolation: direct adding-doubling for the colour; the
    # median radius from the profile itself (not through the medium's own numbers)
    for name, result in presets.items():
        for medium, albedo in ((result.medium, result.rgb_albedo), (result.spectral_medium, result.reflectance)):
            np.testing.assert_allclose(rm.semi_infinite_reflectance(medium.single_scattering_albedo), albedo, rtol=1e-6)
        radii = np.geomspace(1e-5, 20.0, 4000)
        rgb = linear_srgb_weights(WAVELENGTHS) @ np.asarray(skinfit.profile(skinfit.preset(name), WAVELENGTHS, radii, entry_fresnel=True))
        energy = rd.cumulative_energy(radii, rgb) / result.rgb_albedo[:, None]
        median = [np.interp(0.5, np.maximum.accumulate(e), radii) for e in energy]
        np.testing.assert_allclose(result.medium.median_radius_mm, median, rtol=5e-3)
        c = rm.medium_table().unit_median_radius(result.medium.single_scattering_albedo)
        np.testing.assert_allclose(c * result.medium.mean_free_path_mm, result.medium.median_radius_mm, rtol=1e-9)


def test_exact_media_are_brighter_matched_than_diffusion_would_make_them(presets):
    # diffusion overestimates the reflectance of absorbing media: an exact-transport match needs
    # less absorption than a diffusion match, most for the darkest channels (the 35 %)
    dark = presets["dark"].medium
    layer = [skinfit.Layer(absorption=float(dark.absorption_per_mm[i]), reduced_scattering=float(dark.reduced_scattering_per_mm[i]),
                           thickness=float("inf"), ior=1.4) for i in range(3)]
    diffusion = np.array([float(skinfit.layered_reflectance([lay])) for lay in layer])
    assert np.all(diffusion > 1.2 * presets["dark"].rgb_albedo)


def test_files_for_renderers(presets, tmp_path):
    result = presets["medium"]
    snippet = rd.write_renderer(result, "pbrt", tmp_path / "skin.pbrt").read_text()
    sigma_a = [float(v) for v in snippet.split('"rgb sigma_a" [')[1].split("]")[0].split()]
    np.testing.assert_allclose(sigma_a, result.medium.absorption_per_mm, rtol=1e-5)
    assert '"string type" "subsurface"' in snippet and '"float scale" 1000' in snippet and "boundary: smooth dielectric" in snippet
    xml = rd.write_renderer(result, "mitsuba", tmp_path / "skin.xml").read_text()
    assert 'type="homogeneous"' in xml and 'name="int_ior" value="1.4"' in xml and "phase_function: isotropic" in xml
    spectral = rd.write_renderer(result, "mitsuba-spectral", tmp_path / "spectral.xml").read_text()
    assert spectral.count(":") > 2 * WAVELENGTHS.size and "<spectrum name=\"sigma_t\"" in spectral
    blender = json.loads(rd.write_renderer(result, "blender", tmp_path / "b.json").read_text())
    assert blender["Subsurface Radius"] == pytest.approx(rd.blender_radius(result.medium.median_radius_mm, blender["Base Color"][:3]).tolist())
    assert min(blender["Subsurface Radius"]) > 0.1  # above Cycles' diffuse fallback
    assert blender["metadata"]["units"]["radius"] == "mm" and "Blender 4.2" in blender["note"]
    everything = json.loads(rd.write_renderer(result, "json", tmp_path / "all.json").read_text())
    assert everything["medium"]["conventions"]["boundary"].startswith("smooth dielectric")
    lines = [line for line in rd.write_renderer(result, "table", tmp_path / "t.csv").read_text().splitlines() if not line.startswith("#")]
    assert lines[0].startswith("radius_mm,R_400nm")
    table = np.loadtxt(lines[1:], delimiter=",")
    assert table.shape == (256, 1 + WAVELENGTHS.size + 3) and table[-1, 0] == pytest.approx(result.max_radius_mm)
    with pytest.raises(skinfit.SkinfitInputError, match="unknown renderer format"):
        rd.write_renderer(result, "maya", tmp_path / "x")


def test_the_blender_base_colour_inverts_the_measured_cycles_curve():
    drift = rd.blender_drift("RANDOM_WALK")
    base, rendered = np.array(drift["base_colour"]), np.array(drift["rendered_albedo"])
    np.testing.assert_allclose(rd.blender_base_colour(rendered[5:-5:7]), base[5:-5:7], rtol=1e-9)  # the nodes themselves
    between = np.sqrt(rendered[10:-10:9] * rendered[11:-9:9])
    recovered = rd.blender_base_colour(between)
    assert np.all((recovered > base[10:-10:9]) & (recovered < base[11:-9:9]))
    assert np.all(rd.blender_base_colour(between) > between)  # Cycles renders darker than its base colour
    with pytest.raises(skinfit.SkinfitInputError, match="measured Blender"):
        rd.blender_base_colour([0.99])


def test_textures_from_maps_match_the_per_pixel_medium(tmp_path):
    melanin = np.array([[0.01, 0.05], [0.2, 0.4]])
    haemoglobin = np.array([[0.005, 0.02], [0.05, 0.08]])
    textures = rd.renderer_textures({"melanin": melanin, "haemoglobin": haemoglobin, "melanin_blend": 0.7}, grid=8)
    albedo, median = rd.median_radius(skinfit.SkinParams(melanin[1, 0], 0.7, haemoglobin[1, 0]))
    medium = rm.transport_medium(albedo, median)
    # the grid corners are exact; elsewhere bilinear in log concentration
    np.testing.assert_allclose([textures[f"mfp.{c}"][1, 0] for c in "RGB"], medium.mean_free_path_mm, rtol=2e-2)
    np.testing.assert_allclose([textures[f"albedo.{c}"][1, 0] for c in "RGB"], albedo, rtol=1e-5)
    np.testing.assert_allclose([textures[f"ss_albedo.{c}"][1, 0] for c in "RGB"], medium.single_scattering_albedo, rtol=1e-5)
    np.testing.assert_allclose([textures[f"base_colour.{c}"][1, 0] for c in "RGB"], rd.blender_base_colour(albedo), rtol=1e-5)
    xml = rd.write_mitsuba_textures(textures, tmp_path)
    assert (tmp_path / "sigma_t.vol").stat().st_size == 48 + 4 * 2 * 2 * 3 and 'type="heterogeneous"' in xml.read_text()


def test_a_spectral_mitsuba_medium_covers_what_mitsuba_samples(presets):
    # Mitsuba reads an irregular spectrum as zero outside its wavelengths: a transparent medium
    from skinfit import mitsuba as sm

    result = presets["light"]
    medium = sm.mitsuba_spectral_medium(result.wavelengths_nm, result.spectral_medium)
    wavelengths = [w for w, _ in medium["sigma_t"]["value"]]
    assert wavelengths[0] == 360.0 and wavelengths[-1] == 830.0
    assert medium["sigma_t"]["value"][0][1] == pytest.approx(medium["sigma_t"]["value"][1][1])
    with pytest.raises(skinfit.SkinfitInputError, match="one medium per wavelength"):
        sm.mitsuba_spectral_medium(result.wavelengths_nm[:-1], result.spectral_medium)
    with pytest.raises(skinfit.SkinfitInputError, match="3 channels"):
        sm.mitsuba_medium(result.spectral_medium)
