import subprocess
import sys

import numpy as np
import pytest

from skinfit.cli import main

from ..conftest import LIGHT_FIXTURE

F0 = ((1.4 - 1) / (1.4 + 1)) ** 2


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "skinfit", *args], capture_output=True, text=True, timeout=300)


def test_spectrum_prints_the_light_fixture(capsys):
    assert main(["spectrum", "--preset", "light", "--wavelengths", "450:650:100", "--model", "dj2006"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0] == "wavelength_nm,reflectance"
    data = np.loadtxt(lines[1:], delimiter=",")
    np.testing.assert_array_equal(data[:, 0], [450, 550, 650])
    np.testing.assert_allclose(data[:, 1], (1 - F0) * LIGHT_FIXTURE["R12_directional"], atol=6e-5)


def test_spectrum_explicit_parameters_and_symmetric_adding(capsys):
    assert main(["spectrum", "--melanin", "0.005", "--melanin-blend", "0.7", "--haemoglobin", "0.005", "--wavelengths", "550", "--adding", "symmetric",
                 "--model", "dj2006"]) == 0
    value = float(capsys.readouterr().out.strip().splitlines()[1].split(",")[1])
    assert value == pytest.approx((1 - F0) * 0.4558, abs=6e-5)


@pytest.mark.parametrize(
    "args, word",
    [
        (["spectrum", "--melanin", "0.1"], "missing"),
        (["spectrum", "--preset", "light", "--wavelengths", "100:700:10"], "wavelengths_nm"),
        (["spectrum", "--preset", "light", "--wavelengths", "abc"], "--wavelengths"),
        (["spectrum", "--preset", "pale"], "invalid choice"),
        (["profiles", "--preset", "light", "--radii", "1:0:5", "--out", "x.csv"], "--radii"),
        (["spectrum", "--melanin", "7", "--melanin-blend", "0.5", "--haemoglobin", "0.01"], "melanin"),
    ],
)
def test_usage_errors_are_one_line_with_exit_code_2(args, word):
    result = run_cli(*args)
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert word in result.stderr and "Traceback" not in result.stderr


def test_profiles_command_writes_the_table_of_its_arguments_in_each_format(tmp_path):
    import skinfit
    from skinfit.export import profile_table, read_exr_table

    expected = profile_table(skinfit.preset("dark"), np.array([450.0, 550.0, 650.0]), np.geomspace(0.01, 5.0, 16))
    for suffix in (".csv", ".npz", ".exr"):
        out = tmp_path / f"t{suffix}"
        assert main(["profiles", "--preset", "dark", "--wavelengths", "450:650:100", "--radii", "0.01:5:16", "--out", str(out)]) == 0
        if suffix == ".exr":
            back = read_exr_table(out)
            np.testing.assert_allclose(back.spectral, expected.spectral, rtol=1e-6)  # float32 in the file
            np.testing.assert_allclose(back.radii_mm, expected.radii_mm, rtol=1e-6)
        elif suffix == ".npz":
            np.testing.assert_allclose(np.load(out)["spectral"], expected.spectral, rtol=1e-12)
        else:
            rows = [line for line in out.read_text().splitlines() if not line.startswith("#")][1:]
            data = np.loadtxt(rows, delimiter=",")
            np.testing.assert_allclose(data[:, 1:-3].T, expected.spectral, rtol=1e-9)


def test_every_command_has_help():
    for command in ("spectrum", "profiles", "fit-spectra", "fit-image", "render-maps", "demo", "presets"):
        result = run_cli(command, "--help")
        assert result.returncode == 0 and "usage" in result.stdout


def test_presets_writes_tables_and_plots(tmp_path, capsys):
    assert main(["presets", "--out", str(tmp_path / "presets")]) == 0
    out = capsys.readouterr().out
    assert "light" in out and "dark" in out
    for name in ("reflectance.csv", "profiles_light.csv", "presets.png", "profiles.png"):
        assert (tmp_path / "presets" / name).stat().st_size > 0


def test_demo_fits_the_bundled_photo(tmp_path, capsys):
    """The demo on the 512 x 512 portrait, nothing prepared: one face found, >= 90 % of its skin
    SUCCESS and nothing else fitted, CIEDE2000 over the skin median <= 0.2 and 95th percentile <= 1,
    under 2 % speckle; the rule-made skin mask of the face's crop (tests/data) >= 90 % fitted."""
    from pathlib import Path

    from skinfit.fit import speckle_fraction
    from skinfit.io import read_exr_channels, read_mask

    assert main(["demo", "--out", str(tmp_path / "demo"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "1 face found" in out
    for name in ("maps.exr", "maps.png", "regions.png", "reconstructed.png", "dE2000.png", "blush.png", "skin_mask.png"):
        assert (tmp_path / "demo" / name).stat().st_size > 0
    channels, attributes = read_exr_channels(tmp_path / "demo" / "maps.exr")
    face_skin = channels["region"] == 1
    skin = channels["status"] == 0
    assert skin[face_skin].mean() >= 0.9 and not skin[~face_skin].any()
    delta_e = channels["residual_dE2000"][face_skin]
    assert np.median(delta_e) <= 0.2 and np.percentile(delta_e, 95) <= 1.0
    assert speckle_fraction(channels["melanin"], skin) < 0.02
    assert 0.01 <= np.median(channels["melanin"][skin]) <= 0.10 and 0.002 <= np.median(channels["haemoglobin"][skin]) <= 0.05
    assert np.all(np.isfinite(channels["melanin_se"])) and np.all(channels["melanin_se"][skin] > 0)
    assert len(attributes["skinfit:white_balance"].split()) == 3 and len(attributes["skinfit:white_balance_sd"].split()) == 3
    crop_mask = read_mask(Path(__file__).parents[1] / "data" / "eileen_collins_skin_mask.png") > 0  # rows 16-207, columns 144-303
    assert skin[16:208, 144:304][crop_mask].mean() >= 0.9


def test_fit_spectra_csv_round_trip(tmp_path, capsys):
    import skinfit

    wl = np.arange(400.0, 701.0, 5.0)
    true = np.array([[0.005, 0.7, 0.005], [0.15, 0.7, 0.01], [0.5, 0.7, 0.05], [0.02, 0.3, 0.04], [0.3, 0.9, 0.002], [0.08, 0.5, 0.02], [0.01, 0.1, 0.06]])
    spectra = np.asarray(skinfit.diffuse_reflectance(skinfit.SkinParams(*true.T), wl))
    path = tmp_path / "spectra.csv"
    names = [f"s{i}" for i in range(len(true))]
    lines = ["wavelength_nm," + ",".join(names)] + [f"{w:g}," + ",".join(f"{v:.12g}" for v in spectra[:, j]) for j, w in enumerate(wl)]
    path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "params.csv"
    # the default model, maximum likelihood: a forward spectrum and its fit round-trip
    assert main(["fit-spectra", str(path), "--out", str(out), "--quiet", "--no-prior", "--plot", str(tmp_path / "fits.png")]) == 0
    rows = [line.split(",") for line in out.read_text().splitlines()]
    header, body = rows[0], rows[1:]
    assert [r[0] for r in body] == names
    got = np.array([[float(r[header.index(k)]) for k in ("melanin", "melanin_blend", "haemoglobin")] for r in body])
    np.testing.assert_allclose(got, true, atol=1e-6)
    assert all(r[header.index("status")] == "SUCCESS" for r in body)
    assert {r[header.index("model")] for r in body} == {skinfit.SkinModel.default().name}
    assert (tmp_path / "fits.png").stat().st_size > 0
    assert "RMS residual" in capsys.readouterr().out


def test_fit_spectra_rejects_wavelengths_outside_the_data(tmp_path):
    path = tmp_path / "spectra.csv"
    path.write_text("wavelength_nm,a\n450,0.3\n500,0.35\n600,0.4\n")
    result = run_cli("fit-spectra", str(path), "--out", str(tmp_path / "p.csv"), "--wavelengths", "400:700:10")
    assert result.returncode == 2 and "outside the data" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_plan_prints_what_is_computed_and_what_is_skipped(capsys):
    assert main(["plan", "--wavelengths", "400:700:10"]) == 0
    text = capsys.readouterr().out
    assert "spectral reflectance at 31 wavelengths" in text and "profiles: not requested" in text
    # DJ2006's dark skin returns its light within 2 mm; the calibrated model's (a 60 um epidermis, so far
    # less melanin on the long lateral paths) returns 2 % from beyond, and needs the profiles there
    assert main(["plan", "--rgb", "--profiles", "--pixel-footprint-mm", "4", "--preset", "dark", "--model", "dj2006"]) == 0
    text = capsys.readouterr().out
    assert "RGB (D65) from" in text and "profiles: not needed" in text
    assert main(["plan", "--rgb", "--profiles", "--pixel-footprint-mm", "4", "--preset", "dark"]) == 0
    assert "of the energy lies beyond 2 mm" in capsys.readouterr().out
    assert main(["plan", "--rgb", "--profiles", "--pixel-footprint-mm", "10", "--preset", "dark"]) == 0
    assert "profiles: not needed" in capsys.readouterr().out
    assert main(["plan"]) == 2


def test_profiles_for_renderers_and_textures(tmp_path, capsys):
    out = tmp_path / "skin.pbrt"
    assert main(["profiles", "--preset", "light", "--wavelengths", "400:700:20", "--format", "pbrt", "--out", str(out)]) == 0
    assert '"string type" "subsurface"' in out.read_text()
    assert "sum-of-Gaussians energy error" in capsys.readouterr().out
    from skinfit.io import read_exr_channels, write_exr

    maps = tmp_path / "maps.exr"
    write_exr(maps, {"melanin": np.full((4, 5), 0.05, np.float32), "haemoglobin": np.full((4, 5), 0.02, np.float32),
                     "melanin_blend": np.full((4, 5), 0.7, np.float32)})
    assert main(["textures", str(maps), "--out", str(tmp_path / "tex.exr")]) == 0
    channels, _ = read_exr_channels(tmp_path / "tex.exr")
    assert set(channels) == {f"{k}.{c}" for k in ("albedo", "sigma_t", "ss_albedo", "mfp", "base_colour", "blender_radius") for c in "RGB"}
    assert np.all(channels["ss_albedo.R"] > channels["ss_albedo.B"])  # red is absorbed least
    assert main(["textures", str(maps), "--out", str(tmp_path / "tex2.exr"), "--mitsuba", str(tmp_path / "mitsuba")]) == 0
    assert {p.name for p in (tmp_path / "mitsuba").iterdir()} == {"sigma_t.vol", "albedo.vol", "skin_medium.xml"}
    assert main(["textures", str(maps), "--out", str(tmp_path / "tex3.exr"), "--mitsuba-layered", str(tmp_path / "layers")]) != 0
    assert "--mm-per-pixel" in capsys.readouterr().err
    assert main(["textures", str(maps), "--out", str(tmp_path / "tex3.exr"), "--mitsuba-layered", str(tmp_path / "layers"),
                 "--mm-per-pixel", "0.4"]) == 0
    assert {p.name for p in (tmp_path / "layers").iterdir()} == {f"{layer}_{grid}.vol" for layer in ("epidermis", "dermis")
                                                                  for grid in ("sigma_t", "albedo")} | {"skin_layers.xml"}
    assert "0.4 mm each" in (tmp_path / "layers" / "skin_layers.xml").read_text()
    spectral = tmp_path / "spectral.xml"
    assert main(["profiles", "--preset", "medium", "--format", "mitsuba-spectral", "--out", str(spectral)]) == 0
    assert "360:" in spectral.read_text() and "830:" in spectral.read_text()
    assert main(["textures", str(out), "--out", str(tmp_path / "x.exr")]) != 0


def test_fit_spectra_with_the_transport_method(tmp_path):
    """--method transport fits a transport spectrum (on the coarse grid the fit compiles for)."""
    import skinfit

    wl = np.arange(400.0, 701.0, 30.0)
    spectrum = np.asarray(skinfit.diffuse_reflectance(skinfit.SkinParams(0.05, 0.4, 0.03), wl, method="transport"))
    path = tmp_path / "spectra.csv"
    path.write_text("wavelength_nm,a\n" + "\n".join(f"{w:g},{v:.12g}" for w, v in zip(wl, spectrum)) + "\n")
    out = tmp_path / "params.csv"
    assert main(["fit-spectra", str(path), "--out", str(out), "--quiet", "--wavelengths", "400:700:30", "--method", "transport",
                 "--no-prior"]) == 0
    header, row = (line.split(",") for line in out.read_text().splitlines())
    got = [float(row[header.index(k)]) for k in ("melanin", "melanin_blend", "haemoglobin")]
    np.testing.assert_allclose(got, [0.05, 0.4, 0.03], atol=1e-6)
    assert row[header.index("status")] == "SUCCESS"


def test_the_printed_blend_lists_a_few_faces_and_summarises_many():
    """A group photo lists each face's blend; a crowd (a 4096^2 tiling held 331 faces, whose line
    ran to 5 kB) gets the median and range."""
    from types import SimpleNamespace

    from skinfit.cli._batch import blend_text

    faces = lambda n: SimpleNamespace(blends=[{"melanin_blend": 0.1 + 0.1 * k, "sd": 0.05} for k in range(n)])  # noqa: E731
    assert blend_text(faces(2)) == "0.1 (+-0.05), 0.2 (+-0.05)"
    text = blend_text(faces(331))
    assert text.startswith("median ") and "over 331 faces" in text and len(text) < 100


def test_profiles_writes_the_layered_mitsuba_media_rgb_and_spectral(tmp_path, capsys):
    import xml.etree.ElementTree as ElementTree

    for fmt, per in (("mitsuba-layered", "RGB channels"), ("mitsuba-layered-spectral", "48 wavelengths")):
        out = tmp_path / f"{fmt}.xml"
        assert main(["profiles", "--preset", "medium", "--format", fmt, "--out", str(out)]) == 0
        assert per in capsys.readouterr().out
        root = ElementTree.fromstring(f"<scene>{out.read_text()}</scene>")
        albedo = root.find("medium[@id='epidermis']/*[@name='albedo']")
        assert albedo.tag == ("rgb" if fmt == "mitsuba-layered" else "spectrum")
        if fmt == "mitsuba-layered-spectral":  # 360-830 nm, what Mitsuba samples
            nodes = [float(pair.split(":")[0]) for pair in albedo.get("value").split(", ")]
            assert nodes[0] == 360.0 and nodes[-1] == 830.0
