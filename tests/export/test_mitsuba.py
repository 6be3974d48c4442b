"""The exports rendered in Mitsuba 3 (an independent path tracer, a test dependency): the RGB media
of the presets and of 20 random parameter sets reproduce the model's linear-sRGB albedo, the
spectral medium its reflectance per wavelength, and the radial check agrees with skinfit's own
Monte Carlo of the same medium."""

import mitsuba as mi  # noqa: E402 - a test dependency: missing, the file fails (never skips)
import numpy as np
import pytest

import skinfit
from skinfit import export
from skinfit.colorimetry import delta_e2000, linear_srgb_to_lab
from skinfit.model import monte_carlo_reflectance

pytestmark = pytest.mark.slow


def _material(result):
    return export.mitsuba_material(export.mitsuba_medium(result.medium), result.medium.conventions.ior)


def _assert_renders_the_albedo(result, spp, label):
    rendered, error = export.render_albedo(_material(result), spp=spp)
    ratio = rendered / result.rgb_albedo
    tolerance = np.maximum(0.01, 3 * error / result.rgb_albedo)  # 1 %, or the render's own Monte Carlo error
    assert np.all(np.abs(ratio - 1) <= tolerance), (label, ratio, error / result.rgb_albedo)
    de = float(delta_e2000(linear_srgb_to_lab(rendered), linear_srgb_to_lab(result.rgb_albedo)))
    assert de <= 0.3, (label, de)
    return ratio


@pytest.mark.parametrize("name", skinfit.PRESET_NAMES)
def test_the_presets_render_with_the_model_albedo(name):
    _assert_renders_the_albedo(export.renderer_profiles(skinfit.preset(name)), 32768, name)


def test_random_parameter_sets_render_with_the_model_albedo():
    rng = np.random.default_rng(19)
    for k in range(20):
        params = skinfit.SkinParams(np.exp(rng.uniform(np.log(0.002), np.log(0.5))), rng.uniform(0.0, 1.0),
                                    np.exp(rng.uniform(np.log(0.002), np.log(0.2))))
        _assert_renders_the_albedo(export.renderer_profiles(params), 8192, (k, params))


def test_the_spectral_export_renders_the_model_reflectance_per_wavelength():
    wavelengths = np.arange(360.0, 831.0, 10.0)
    result = export.renderer_profiles(skinfit.preset("medium"), wavelengths)
    material = export.mitsuba_material(export.mitsuba_spectral_medium(wavelengths, result.spectral_medium), 1.4)
    checked = np.array([420.0, 480.0, 540.0, 580.0, 620.0, 680.0])
    rendered, error = export.render_spectral_albedo(material, checked, spp=16384)
    target = np.interp(checked, wavelengths, result.reflectance)
    tolerance = np.maximum(0.01, 3 * error / target)
    assert np.all(np.abs(rendered / target - 1) <= tolerance), (rendered / target, error / target)


def test_the_xml_fragment_loads_as_the_same_medium():
    result = export.renderer_profiles(skinfit.preset("dark"))
    xml = export.mitsuba_export(result)
    mi.set_variant("scalar_rgb")
    scene = mi.load_string(f'<scene version="3.0.0">{xml}<shape type="sphere"><ref id="skin_boundary"/><ref name="interior" id="skin"/></shape></scene>')
    params = mi.traverse(scene)
    np.testing.assert_allclose(np.ravel(params["skin.albedo.value.value"]), result.medium.single_scattering_albedo, rtol=1e-6)
    extinction = np.ravel(params["skin.sigma_t.value.value"]) * params["skin.scale"]
    np.testing.assert_allclose(extinction, result.medium.extinction_per_mm, rtol=1e-6)
    assert params["skin_boundary.eta"] == pytest.approx(1.4)


def test_volume_textures_load_in_mitsuba_and_a_uniform_one_renders_as_the_homogeneous_medium(tmp_path):
    result = export.renderer_profiles(skinfit.preset("medium"))
    m = result.medium
    values = np.random.default_rng(0).uniform(0.1, 1.0, (5, 7, 3))
    path = export.write_mitsuba_volume(tmp_path / "grid.vol", values)
    mi.set_variant("scalar_rgb")
    np.testing.assert_allclose(np.asarray(mi.VolumeGrid(str(path))), values[None].astype(np.float32))
    peak = float(np.max(m.extinction_per_mm))
    sigma = export.write_mitsuba_volume(tmp_path / "sigma_t.vol", np.broadcast_to(m.extinction_per_mm / peak, (4, 4, 3)))
    albedo = export.write_mitsuba_volume(tmp_path / "albedo.vol", np.broadcast_to(m.single_scattering_albedo, (4, 4, 3)))
    slab = mi.ScalarTransform4f().translate([-export.SLAB_WIDTH_MM / 2, -export.SLAB_WIDTH_MM / 2, -export.SLAB_DEPTH_MM])
    medium = export.mitsuba_heterogeneous_medium(sigma, albedo, peak, to_world=slab @ mi.ScalarTransform4f().scale([export.SLAB_WIDTH_MM, export.SLAB_WIDTH_MM, export.SLAB_DEPTH_MM]))
    rendered, error = export.render_albedo(export.mitsuba_material(medium, 1.4), spp=1024)  # delta tracking: ~20x the homogeneous cost
    assert np.all(np.abs(rendered / result.rgb_albedo - 1) <= np.maximum(0.015, 3 * error / result.rgb_albedo))


def test_the_radial_render_agrees_with_the_radially_resolved_monte_carlo():
    # two independent exact-transport codes on one medium (Mitsuba by reciprocity through a
    # screen, skinfit's Monte Carlo by tallying exits): the energy within 1 and 4 mean free paths
    medium = {"type": "homogeneous", "albedo": {"type": "rgb", "value": [0.99, 0.9, 0.5]},
              "sigma_t": {"type": "rgb", "value": [1.0, 1.0, 1.0]}, "scale": 2.0, "phase": {"type": "isotropic"}}
    radii = np.array([0.5, 2.0])
    rendered, error = export.render_energy_within(export.mitsuba_material(medium, 1.4), radii, spp=4096)
    for i, albedo in enumerate((0.99, 0.9, 0.5)):
        layer = skinfit.model.Layer(absorption=2.0 * (1 - albedo), reduced_scattering=2.0 * albedo, thickness=float("inf"), ior=1.4)
        mc = monte_carlo_reflectance([layer], photons=60_000, seed=i, radii_mm=radii)
        assert np.all(np.abs(rendered[:, i] - mc.reflectance_within) < 4 * np.hypot(error[:, i], mc.reflectance_within_error)
                      + 0.01 * mc.reflectance_within), (albedo, rendered[:, i], mc.reflectance_within)
