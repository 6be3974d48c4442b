"""The two-layer export: the model's own coefficients per wavelength, RGB stacks matched by
adding-doubling to the model's transport albedo, the XML written for Mitsuba (rendered in the slow
tier, tests/export/test_mitsuba_layered.py)."""

import xml.etree.ElementTree as ElementTree

import numpy as np
import pytest

import skinfit
from skinfit import export
from skinfit._validate import SkinfitInputError
from skinfit.model import SKIN_ANISOTROPY, stack_reflectance_transport

WAVELENGTHS_NM = np.array([420.0, 550.0, 680.0])


def test_spectral_layers_are_the_models_coefficients_and_its_transport_reflectance():
    params = skinfit.preset("medium")
    layered = export.layered_medium(params, WAVELENGTHS_NM, spectral=True)
    epidermis, dermis = skinfit.SkinModel.default().layers(params, WAVELENGTHS_NM)
    g = SKIN_ANISOTROPY
    np.testing.assert_allclose(layered.epidermis_absorption_per_mm, np.asarray(epidermis.absorption), rtol=1e-12)
    np.testing.assert_allclose(layered.dermis_scattering_per_mm * (1 - g), np.asarray(dermis.reduced_scattering), rtol=1e-12)
    assert layered.epidermis_thickness_mm == pytest.approx(float(np.asarray(epidermis.thickness).reshape(-1)[0]))
    reference = np.asarray(skinfit.diffuse_reflectance(params, WAVELENGTHS_NM, method="transport-direct"))
    np.testing.assert_allclose(layered.albedo, reference, rtol=2e-3)  # the shipped table against the direct solve


@pytest.mark.parametrize("name", skinfit.PRESET_NAMES)
def test_each_rgb_channels_stack_reflects_the_channels_albedo(name):
    layered = export.layered_medium(skinfit.preset(name))
    for c in range(3):
        epidermis, dermis = layered.layers(c)
        stack = stack_reflectance_transport(
            np.array([float(epidermis.absorption), float(dermis.absorption)]),
            np.array([float(epidermis.reduced_scattering), float(dermis.reduced_scattering)]),
            np.array([layered.epidermis_thickness_mm, 1.0]), np.full(2, layered.anisotropy), ior=1.4, ior_above=1.0,
            semi_infinite=True, streams=32)
        assert float(stack) == pytest.approx(layered.albedo[c], rel=1e-6)
    # one factor on the log-mean absorption: near one where the log-mean is a fair summary
    assert np.all((layered.absorption_factor > 0.6) & (layered.absorption_factor < 1.5)), layered.absorption_factor
    # redder channels absorb less in both layers
    assert np.all(np.diff(layered.dermis_absorption_per_mm) > 0)


def test_layered_xml_names_its_media_and_boundaries_and_states_its_assumptions():
    layered = export.layered_medium(skinfit.preset("light"))
    xml = export.mitsuba_layered_xml(layered, mm_per_scene_unit=1000.0)
    root = ElementTree.fromstring(f"<scene>{xml}</scene>")
    ids = {element.get("id"): element.get("type") for element in root}
    assert ids == {"skin_surface": "dielectric", "skin_interface": "null", "epidermis": "homogeneous", "dermis": "homogeneous"}
    scale = float(root.find("medium[@id='dermis']/float[@name='scale']").get("value"))
    sigma_t = layered.dermis_absorption_per_mm + layered.dermis_scattering_per_mm
    assert scale == pytest.approx(1000.0 * sigma_t.max(), rel=1e-6)  # per scene unit: metres
    for assumption in ("Henyey-Greenstein g 0.8", "0.06 mm thick", "index-matched", "F0 = 0.0278"):
        assert assumption in xml


def test_oil_makes_the_surface_a_blend_with_the_rough_lobe():
    layered = export.layered_medium(skinfit.SkinParams(0.05, 0.7, 0.02, oil=0.3))
    surface = export.mitsuba_layered_surface(layered)
    assert surface["type"] == "blendbsdf" and surface["weight"] == pytest.approx(0.3)
    assert surface["bsdf_1"]["type"] == "roughdielectric" and surface["bsdf_1"]["distribution"] == "beckmann"
    root = ElementTree.fromstring(f"<scene>{export.mitsuba_layered_xml(layered)}</scene>")
    assert root.find("bsdf[@id='skin_surface']").get("type") == "blendbsdf"


def test_bad_layered_input_gets_a_clear_error():
    with pytest.raises(SkinfitInputError, match="one parameter set"):
        export.layered_medium(skinfit.SkinParams(np.array([0.1, 0.2]), 0.7, 0.01))
    with pytest.raises(SkinfitInputError, match="increasing"):
        export.layered_medium(skinfit.preset("light"), [550.0, 500.0])
    with pytest.raises(SkinfitInputError, match="oil 0"):
        export.render_layered_albedo(export.layered_medium(skinfit.SkinParams(0.05, 0.7, 0.02, oil=0.3)))
