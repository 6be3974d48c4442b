"""Per-texel two-layer media (skinfit.export.layered_textures): each texel's stack is
layered_medium's where the table holds it, reflects the model's albedo by adding-doubling between
the table's nodes, and goes out as Mitsuba grids and XML (rendered in the slow tier)."""

import xml.etree.ElementTree as ElementTree

import numpy as np
import pytest

import skinfit
from skinfit import export
from skinfit._validate import SkinfitInputError
from skinfit.model import stack_reflectance_transport

FIELDS = ("epidermis_absorption_per_mm", "epidermis_scattering_per_mm", "dermis_absorption_per_mm", "dermis_scattering_per_mm")


@pytest.fixture(scope="module")
def two_tone():
    """3 x 4 maps: a darker top row, a redder first column; melanin and haemoglobin at two values each."""
    melanin = np.full((3, 4), 0.05)
    melanin[0] = 0.2
    haemoglobin = np.full((3, 4), 0.01)
    haemoglobin[:, 0] = 0.03
    maps = {"melanin": melanin, "haemoglobin": haemoglobin, "melanin_blend": np.full((3, 4), 0.6)}
    return maps, export.layered_textures(maps, grid=2)


def test_texels_at_the_tables_nodes_are_the_stacks_of_their_parameters(two_tone):
    maps, textures = two_tone
    assert textures.shape == (3, 4)
    for i, j in [(0, 0), (0, 2), (2, 0), (1, 3)]:
        stack = export.layered_medium(skinfit.SkinParams(maps["melanin"][i, j], 0.6, maps["haemoglobin"][i, j]))
        for name in FIELDS:
            np.testing.assert_allclose(getattr(textures, name)[i, j], getattr(stack, name), rtol=1e-9)
        np.testing.assert_allclose(textures.albedo[i, j], stack.albedo, rtol=2e-3)  # the model's albedo (its table)
    assert textures.epidermis_thickness_mm == pytest.approx(stack.epidermis_thickness_mm)


def _stack_albedo(textures, i, j, c):
    g = textures.anisotropy
    a = np.array([textures.epidermis_absorption_per_mm[i, j, c], textures.dermis_absorption_per_mm[i, j, c]])
    s = np.array([textures.epidermis_scattering_per_mm[i, j, c], textures.dermis_scattering_per_mm[i, j, c]]) * (1 - g)
    return float(stack_reflectance_transport(a, s, np.array([textures.epidermis_thickness_mm, 1.0]), np.full(2, g), ior=textures.ior,
                                             ior_above=1.0, semi_infinite=True, streams=32))


def test_between_nodes_the_interpolated_stack_reflects_the_texels_albedo():
    rng = np.random.default_rng(4)
    melanin = np.exp(rng.uniform(np.log(0.02), np.log(0.3), (4, 4)))
    haemoglobin = np.exp(rng.uniform(np.log(0.005), np.log(0.05), (4, 4)))
    textures = export.layered_textures({"melanin": melanin, "haemoglobin": haemoglobin}, grid=4)
    errors = [_stack_albedo(textures, i, j, c) / textures.albedo[i, j, c] - 1 for i, j in [(0, 1), (2, 3), (3, 0)] for c in range(3)]
    assert np.max(np.abs(errors)) < 0.03, errors  # a 4 x 4 table over a 15x melanin and 10x haemoglobin range


def test_the_xml_places_both_layers_grids_and_says_what_it_assumes(two_tone, tmp_path):
    _, textures = two_tone
    path = export.write_mitsuba_layered_textures(textures, tmp_path, mm_per_pixel=0.5)
    text = path.read_text()
    root = ElementTree.fromstring(f"<scene version='3.0.0'>{text}</scene>")
    media = {m.get("id"): m for m in root.iter("medium")}
    assert set(media) == {"epidermis", "dermis"} and all(m.get("type") == "heterogeneous" for m in media.values())
    assert {b.get("id") for b in root.iter("bsdf")} == {"skin_surface", "skin_interface"}
    for name in ("epidermis", "dermis"):
        for grid in ("sigma_t", "albedo"):
            assert (tmp_path / f"{name}_{grid}.vol").stat().st_size == 48 + 4 * 3 * 4 * 3  # header + h w 3 float32
    scale = media["epidermis"].find("volume/transform/scale")
    assert float(scale.get("x")) == pytest.approx(2.0) and float(scale.get("z")) == pytest.approx(textures.epidermis_thickness_mm)
    assert "0.5 mm each" in text and "world space" in text and "rr_depth 5000" in text


def test_oil_makes_the_surface_a_blend(tmp_path):
    maps = {"melanin": np.full((2, 2), 0.05), "haemoglobin": np.full((2, 2), 0.01), "oil": np.full((2, 2), 0.3)}
    textures = export.layered_textures(maps, grid=2)
    assert textures.oil == pytest.approx(0.3)
    text = export.write_mitsuba_layered_textures(textures, tmp_path, mm_per_pixel=1.0).read_text()
    assert '<bsdf type="blendbsdf" id="skin_surface"><float name="weight" value="0.3"/>' in text and "roughdielectric" in text


def test_bad_input_gets_a_clear_error(two_tone, tmp_path):
    _, textures = two_tone
    with pytest.raises(SkinfitInputError, match="melanin and haemoglobin"):
        export.layered_textures({"melanin": np.ones((2, 2))})
    with pytest.raises(SkinfitInputError, match="no fitted texel"):
        export.layered_textures({"melanin": np.zeros((2, 2)), "haemoglobin": np.zeros((2, 2))})
    with pytest.raises(SkinfitInputError, match="grid"):
        export.layered_textures({"melanin": np.ones((2, 2)), "haemoglobin": np.ones((2, 2))}, grid=1)
    with pytest.raises(SkinfitInputError, match="mm_per_pixel"):
        export.write_mitsuba_layered_textures(textures, tmp_path, mm_per_pixel=0)
