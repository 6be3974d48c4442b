"""Photos as files come: embedded ICC profiles, EXIF orientation, damaged files."""

import struct

import colour
import numpy as np
import OpenImageIO as oiio
import pytest

from skinfit._validate import SkinfitInputError
from skinfit.colorimetry import srgb_decode
from skinfit.io import read_image, read_linear_rgb, read_mask

#: Parametric curve of sRGB's transfer function (ICC type 3: g, a, b, c, d).
SRGB_CURVE = (2.4, 1 / 1.055, 0.055 / 1.055, 1 / 12.92, 0.04045)


def icc_profile(space: str, curve, description: str) -> bytes:
    """A minimal ICC v4 RGB matrix/TRC display profile of a colour-science colourspace: colorants
    adapted from its white to D50 by Bradford (as ICC requires), ``curve`` a gamma (float: ``curv``)
    or parameters of a type-3 ``para``."""
    rgb_space = colour.RGB_COLOURSPACES[space]
    adapt = colour.adaptation.matrix_chromatic_adaptation_VonKries(
        colour.xy_to_XYZ(rgb_space.whitepoint), np.array([0.9642, 1.0, 0.8249]), transform="Bradford")
    colorants = adapt @ rgb_space.matrix_RGB_to_XYZ
    s15 = lambda values: b"".join(struct.pack(">i", int(round(v * 65536))) for v in values)  # noqa: E731
    tags = {f"{c}XYZ": b"XYZ \0\0\0\0" + s15(colorants[:, i]) for i, c in enumerate("rgb")}
    if isinstance(curve, float):
        trc = b"curv\0\0\0\0" + struct.pack(">IH", 1, int(round(curve * 256))) + b"\0\0"
    else:
        trc = b"para\0\0\0\0" + struct.pack(">H", 3) + b"\0\0" + s15(curve)
    tags.update({f"{c}TRC": trc for c in "rgb"})
    text = description.encode("utf-16-be")
    tags["desc"] = b"mluc\0\0\0\0" + struct.pack(">II", 1, 12) + b"enUS" + struct.pack(">II", len(text), 28) + text
    tags["wtpt"] = b"XYZ \0\0\0\0" + s15([0.9642, 1.0, 0.8249])
    table, body, offset = b"", b"", 128 + 4 + 12 * len(tags)
    for name, data in tags.items():
        data += b"\0" * (-len(data) % 4)
        table += name.encode() + struct.pack(">II", offset + len(body), len(data))
        body += data
    size = offset + len(body)
    header = struct.pack(">I", size) + b"skft" + bytes([4, 0x40, 0, 0]) + b"mntrRGB XYZ " + b"\0" * 12 + b"acsp"
    header += b"\0" * (68 - len(header)) + s15([0.9642, 1.0, 0.8249])
    header += b"\0" * (128 - len(header))
    return header + struct.pack(">I", len(tags)) + table + body


def write_png16(path, encoded, icc: bytes | None = None, orientation: int | None = None):
    spec = oiio.ImageSpec(encoded.shape[1], encoded.shape[0], 3, oiio.UINT16)
    if icc is not None:
        spec.attribute("ICCProfile", oiio.TypeDesc(f"uint8[{len(icc)}]"), np.frombuffer(icc, np.uint8))
    if orientation is not None:
        spec.attribute("Orientation", orientation)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(np.round(np.clip(encoded, 0, 1) * 65535).astype(np.uint16))
    out.close()


@pytest.fixture
def skin_colours():
    """Linear sRGB skin-like colours and a saturated red and green (5, 4, 3)."""
    rng = np.random.default_rng(3)
    colours = rng.uniform([0.15, 0.08, 0.05], [0.7, 0.5, 0.4], (5, 4, 3))
    colours[0, 0], colours[0, 1] = [0.8, 0.05, 0.05], [0.1, 0.6, 0.1]
    return colours


@pytest.mark.parametrize(("space", "curve"), [("Display P3", SRGB_CURVE), ("Adobe RGB (1998)", 563 / 256)], ids=["display-p3", "adobe-rgb"])
def test_an_embedded_icc_profile_converts_to_linear_srgb(tmp_path, skin_colours, space, curve):
    """Encoded by colour-science into the profile's space, read back through the profile."""
    encoded = colour.RGB_to_RGB(skin_colours, colour.RGB_COLOURSPACES["sRGB"], colour.RGB_COLOURSPACES[space],
                                chromatic_adaptation_transform="Bradford", apply_cctf_encoding=True)
    write_png16(tmp_path / "photo.png", encoded, icc_profile(space, curve, f"{space} (test)"))
    rgb, _, encoding = read_image(tmp_path / "photo.png")
    assert encoding == f"ICC profile '{space} (test)'"
    np.testing.assert_allclose(rgb, skin_colours, atol=2e-4)  # 16-bit steps and 1/65536 colorants
    # without the profile the file is (wrongly, but as before) read as sRGB
    plain, _ = read_linear_rgb(tmp_path / "photo.png", "srgb")
    assert np.max(np.abs(plain - skin_colours)) > 0.01


def test_a_littlecms_srgb_profile_decodes_as_srgb(tmp_path, skin_colours):
    """An independent writer's profile (Pillow's littleCMS sRGB) gives sRGB decoding."""
    from PIL import ImageCms

    icc = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    encoded = colour.cctf_encoding(skin_colours, "sRGB")
    write_png16(tmp_path / "photo.png", encoded, icc)
    rgb, _, encoding = read_image(tmp_path / "photo.png")
    assert encoding.startswith("ICC profile")
    np.testing.assert_allclose(rgb, np.asarray(srgb_decode(np.round(encoded * 65535) / 65535)), atol=1e-3)


@pytest.mark.parametrize("kind", ["lab", "lut"])
def test_an_unsupported_profile_warns_and_reads_as_srgb(tmp_path, skin_colours, kind):
    """A Lab profile (Pillow's littleCMS) and an RGB profile without colorants (as LUT-based ones)."""
    from PIL import ImageCms

    if kind == "lab":
        icc, message = ImageCms.ImageCmsProfile(ImageCms.createProfile("LAB")).tobytes(), "not RGB"
    else:
        icc, message = icc_profile("sRGB", SRGB_CURVE, "lut").replace(b"rXYZ", b"A2B0"), "LUT-based"
    encoded = colour.cctf_encoding(skin_colours, "sRGB")
    write_png16(tmp_path / "photo.tif", encoded, icc)  # TIFF keeps any profile (libpng drops a Lab one)
    with pytest.warns(UserWarning, match=message):
        rgb, _ = read_linear_rgb(tmp_path / "photo.tif")
    np.testing.assert_allclose(rgb, np.asarray(srgb_decode(np.round(encoded * 65535) / 65535)), atol=1e-6)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_is_applied_as_openimageio_does(tmp_path, orientation):
    """Pixels come out as shown; OpenImageIO's own reorient is the reference. Masks follow."""
    data = np.arange(2 * 3 * 3, dtype=float).reshape(2, 3, 3) / 20.0
    write_png16(tmp_path / "photo.tif", data, orientation=orientation)
    buf = oiio.ImageBuf(str(tmp_path / "photo.tif"))
    assert buf.spec().get_int_attribute("Orientation", 1) == orientation
    expected = oiio.ImageBufAlgo.reorient(buf).get_pixels(oiio.FLOAT)
    rgb, _ = read_linear_rgb(tmp_path / "photo.tif", "linear")
    np.testing.assert_allclose(rgb, expected, atol=1e-6)
    np.testing.assert_allclose(read_mask(tmp_path / "photo.tif"), expected.max(axis=-1), atol=1e-6)


def test_truncated_and_corrupt_photos_are_refused(tmp_path):
    """A JPEG cut to its first 5 KB reads as grey under libjpeg; it must not be fitted."""
    rng = np.random.default_rng(0)
    image = oiio.ImageBuf(oiio.ImageSpec(320, 240, 3, oiio.UINT8))
    image.set_pixels(oiio.ROI(), rng.uniform(0, 1, (240, 320, 3)).astype(np.float32))
    image.write(str(tmp_path / "whole.jpg"))
    whole = (tmp_path / "whole.jpg").read_bytes()
    assert len(whole) > 20_000
    read_linear_rgb(tmp_path / "whole.jpg")  # the whole file reads
    (tmp_path / "cut.jpg").write_bytes(whole[:5000])
    with pytest.raises(SkinfitInputError, match="truncated or corrupt"):
        read_linear_rgb(tmp_path / "cut.jpg")
    image.write(str(tmp_path / "whole.png"))
    png = (tmp_path / "whole.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(png[: len(png) // 3])
    with pytest.raises(SkinfitInputError, match="cannot read image"):
        read_linear_rgb(tmp_path / "cut.png")


def test_camera_raw_goes_through_rawpy_linear(tmp_path, monkeypatch):
    """A raw file is demosaicked by rawpy with gamma 1, no brightening and the camera's balance, and
    its 16-bit output scaled to linear [0, 1] (rawpy stood in for: no raw file ships with the tests);
    without rawpy the error names the extra to install."""
    import sys
    import types

    calls = {}

    class Raw:
        def __enter__(self):
            return self

        def __exit__(self, *exc):
            return False

        def postprocess(self, **options):
            calls.update(options)
            return np.full((2, 3, 3), 32768, np.uint16)

    fake = types.SimpleNamespace(imread=lambda path: Raw(), ColorSpace=types.SimpleNamespace(sRGB="sRGB"))
    (tmp_path / "shot.dng").write_bytes(b"raw")
    monkeypatch.setitem(sys.modules, "rawpy", fake)
    rgb, alpha, encoding = read_image(tmp_path / "shot.dng")
    assert alpha is None and encoding.startswith("camera raw")
    np.testing.assert_allclose(rgb, 32768 / 65535)
    assert calls["gamma"] == (1, 1) and calls["no_auto_bright"] and calls["use_camera_wb"] and calls["output_color"] == "sRGB"
    monkeypatch.setitem(sys.modules, "rawpy", None)  # not installed
    with pytest.raises(SkinfitInputError, match=r"skinfit\[raw\]"):
        read_linear_rgb(tmp_path / "shot.dng")
