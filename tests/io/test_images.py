"""Image I/O: channels by name, transfer functions and input spaces."""

import numpy as np
import OpenImageIO as oiio
import pytest

from skinfit._validate import SkinfitInputError
from skinfit.colorimetry import srgb_decode
from skinfit.io import read_linear_rgb, read_mask, to_linear_srgb, write_exr


def write(path, data, fmt, names):
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], fmt)
    spec.channelnames = names
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(data)
    out.close()


def test_exr_channels_are_found_by_name_and_taken_as_linear(tmp_path):
    data = np.random.default_rng(0).uniform(0, 1, (3, 4, 4)).astype(np.float32)
    write(tmp_path / "a.exr", data, oiio.FLOAT, ("B", "A", "G", "R"))
    rgb, alpha = read_linear_rgb(tmp_path / "a.exr")
    np.testing.assert_allclose(rgb, data[..., [3, 2, 0]], rtol=1e-6)
    np.testing.assert_allclose(alpha, data[..., 1], rtol=1e-6)


def test_16_bit_png_is_srgb_decoded(tmp_path):
    data = (np.arange(3 * 4 * 3).reshape(3, 4, 3) * 1800).astype(np.uint16)
    write(tmp_path / "a.png", data, oiio.UINT16, ("R", "G", "B"))
    rgb, alpha = read_linear_rgb(tmp_path / "a.png")
    assert alpha is None
    np.testing.assert_allclose(rgb, np.asarray(srgb_decode(data / 65535.0)), atol=1e-6)
    linear, _ = read_linear_rgb(tmp_path / "a.png", "linear")
    np.testing.assert_allclose(linear, data / 65535.0, atol=1e-6)


def test_other_spaces_go_through_colour_science():
    white = np.ones((1, 1, 3))
    # same (D65) white point; colour-science's P3 and sRGB white coordinates differ by ~1e-4
    np.testing.assert_allclose(to_linear_srgb(white, "Display P3"), white, atol=1e-3)
    red = np.array([[[1.0, 0.0, 0.0]]])
    assert to_linear_srgb(red, "Display P3")[0, 0, 0] > 1.0  # P3 red lies outside sRGB
    with pytest.raises(SkinfitInputError, match="unknown input space"):
        to_linear_srgb(red, "not a space")


def test_unreadable_and_channel_less_files_give_clear_errors(tmp_path):
    with pytest.raises(SkinfitInputError, match="cannot read image"):
        read_linear_rgb(tmp_path / "missing.png")
    (tmp_path / "junk.png").write_bytes(b"not an image")
    with pytest.raises(SkinfitInputError, match="cannot read image"):
        read_linear_rgb(tmp_path / "junk.png")
    write_exr(tmp_path / "depth.exr", {"Z": np.zeros((2, 2)), "W": np.zeros((2, 2))})
    with pytest.raises(SkinfitInputError, match="R, G and B"):
        read_linear_rgb(tmp_path / "depth.exr")


@pytest.mark.parametrize(
    ("fmt", "top", "names"),
    [(oiio.UINT8, 255, ("Y",)), (oiio.UINT16, 65535, ("Y",)), (oiio.UINT8, 255, ("R", "G", "B", "A")), (oiio.UINT8, 255, ("R", "G", "B"))],
    ids=["one-channel 8-bit", "one-channel 16-bit", "alpha", "rgb"],
)
def test_masks_of_any_channel_count_and_bit_depth(tmp_path, fmt, top, names):
    """The usual skin mask is one channel; an RGBA mask is its alpha; an RGB one its largest channel."""
    keep = np.array([[1, 0, 1], [0, 1, 1]], dtype=float)
    data = np.repeat(keep[..., None], len(names), axis=-1)
    if "A" in names:
        data[..., :3] = 1.0 - keep[..., None]  # the colour is not the mask; the alpha is
    dtype = np.uint8 if fmt == oiio.UINT8 else np.uint16
    write(tmp_path / "mask.png", (data * top).astype(dtype), fmt, names)
    np.testing.assert_array_equal(read_mask(tmp_path / "mask.png"), keep)


def test_a_picture_reads_as_float32_in_the_same_values(tmp_path):
    """``dtype=np.float32`` (pictures beside a fit's maps: a third of float64's decoding) gives
    float32 arrays within float32 rounding of the float64 read, for an sRGB PNG and a linear EXR."""
    rng = np.random.default_rng(3)
    data = rng.integers(0, 65536, (9, 7, 3)).astype(np.uint16)
    write(tmp_path / "a.png", data, oiio.UINT16, ("R", "G", "B"))
    write_exr(tmp_path / "a.exr", {c: rng.uniform(0, 2, (9, 7)).astype(np.float32) for c in "RGB"})
    for name in ("a.png", "a.exr"):
        full, _ = read_linear_rgb(tmp_path / name)
        small, _ = read_linear_rgb(tmp_path / name, dtype=np.float32)
        assert full.dtype == np.float64 and small.dtype == np.float32
        np.testing.assert_allclose(small, full, rtol=2e-7, atol=1e-7)


def test_decoding_in_chunks_is_decoding_the_whole_image(tmp_path):
    """An image of more pixels than one decoding chunk (the last chunk padded) decodes to the values
    of the transfer function applied to the whole image at once, bit for bit."""
    data = np.random.default_rng(4).integers(0, 65536, (600, 480, 3)).astype(np.uint16)  # 288,000 pixels
    write(tmp_path / "big.png", data, oiio.UINT16, ("R", "G", "B"))
    encoded, _ = read_linear_rgb(tmp_path / "big.png", "linear")
    decoded, _ = read_linear_rgb(tmp_path / "big.png")
    np.testing.assert_array_equal(decoded, np.asarray(srgb_decode(encoded)))
    assert np.array_equal(read_linear_rgb(tmp_path / "big.png", dtype=np.float32)[0], decoded.astype(np.float32))
