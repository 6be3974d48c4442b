"""The layered export rendered in Mitsuba 3: its albedo is the model's transport reflectance, its
radial energy skinfit's Monte Carlo of the same two-layer stack (benchmarks/layered_renders.py runs
the presets and 20 random sets)."""

import mitsuba as mi  # noqa: F401 - a test dependency: missing, the file fails (never skips)
import numpy as np
import pytest

import skinfit
from skinfit import export

pytestmark = pytest.mark.slow

RADII_MM = (0.1, 0.5, 1.0, 2.0)


def test_the_light_presets_stack_renders_its_albedo_and_the_monte_carlos_radial_energy():
    layered = export.layered_medium(skinfit.preset("light"))
    rendered, error = export.render_layered_albedo(layered, spp=2048)
    tolerance = np.maximum(0.01, 3 * error / layered.albedo)
    assert np.all(np.abs(rendered / layered.albedo - 1) <= tolerance), (rendered / layered.albedo, error)
    within, within_error = export.render_layered_energy_within(layered, RADII_MM, spp=2048)
    mc, mc_error = layered.monte_carlo_energy_within(RADII_MM, photons=60_000)
    points = 100 * np.abs(within - mc) / layered.albedo
    allowed = np.maximum(2.0, 300 * np.hypot(within_error, mc_error) / layered.albedo)
    assert np.all(points <= allowed), (points, allowed)


def test_a_spectral_stack_renders_the_models_reflectance_per_wavelength():
    layered = export.layered_medium(skinfit.preset("light"), np.array([450.0, 560.0, 650.0]), spectral=True)
    rendered, error = export.render_layered_albedo(layered, spp=2048)
    tolerance = np.maximum(0.01, 3 * error / layered.albedo)
    assert np.all(np.abs(rendered / layered.albedo - 1) <= tolerance), (rendered / layered.albedo, error)


def test_the_written_xml_loads_in_mitsuba(tmp_path):
    mi.set_variant("scalar_rgb")
    xml = export.mitsuba_layered_xml(export.layered_medium(skinfit.preset("dark")))
    scene = mi.load_string(f'<scene version="3.0.0">{xml}<shape type="rectangle"><ref id="skin_surface"/>'
                           '<ref name="interior" id="epidermis"/></shape></scene>')
    assert len(scene.shapes()) == 1
