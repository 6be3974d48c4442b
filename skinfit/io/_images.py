"""Image input and output through OpenImageIO: linear sRGB in, named-channel EXR and PNG out.

Encodings. A file with an embedded ICC profile of matrix/TRC type (phones write Display P3,
cameras Adobe RGB) is converted through it to linear sRGB in floating point (``_icc``). Other
integer files (8/16-bit PNG, JPEG, TIFF) are taken as sRGB-encoded and decoded with the sRGB
transfer function unless their metadata says linear; half and float data (EXR, float TIFF) are
taken as linear. ``input_space`` overrides all of this: ``"srgb"``, ``"linear"`` (linear sRGB
primaries), or the name of any colour-science RGB colourspace (``"Display P3"``, ``"Adobe RGB
(1998)"``, ``"ACEScg"``, ...), decoded with that space's transfer function and converted to linear
sRGB (Bradford adaptation where the white points differ). Channels are found by name (R, G, B and
optionally A), not by position.

Files as cameras write them: camera raw files (DNG, CR2/CR3, NEF, ARW, RAF, ORF, RW2, ...) go
through rawpy (LibRaw, optional: ``skinfit[raw]``) to linear sRGB with the camera's white balance;
the EXIF orientation is applied (pixels come out as the photo is
shown), and a file the decoder reports damaged (a truncated JPEG, whose missing part libjpeg
fills with grey; a PNG cut short) is refused with a one-line error rather than fitted.
"""

from __future__ import annotations

import contextlib
import functools
import os
import tempfile
import warnings
from pathlib import Path

import numpy as np

from .. import _scratch as scratch
from .._batching import padded_rows
from .._validate import SkinfitInputError
from ..colorimetry import srgb_decode
from ._icc import UnsupportedProfile, parse_icc


def _oiio():
    import OpenImageIO as oiio

    return oiio


def read_linear_rgb(path: str | os.PathLike, input_space: str | None = None, dtype=np.float64) -> tuple[np.ndarray, np.ndarray | None]:
    """Read an image as linear sRGB, (h, w, 3) float64 (or ``dtype``: float32 for a picture, in a third
    of the memory of float64's decoding), and its alpha (h, w) or None."""
    rgb, alpha, _ = read_image(path, input_space, dtype)
    return rgb, alpha


#: Camera raw files, read through rawpy (LibRaw) when it is installed (``skinfit[raw]``).
RAW_SUFFIXES = frozenset({".dng", ".cr2", ".cr3", ".nef", ".arw", ".raf", ".orf", ".rw2", ".pef", ".srw"})


def read_image(path: str | os.PathLike, input_space: str | None = None, dtype=np.float64,
               out_of_core: bool | None = None) -> tuple[np.ndarray, np.ndarray | None, str]:
    """``read_linear_rgb`` and a description of the encoding it decoded (``"sRGB"``, ``"linear"``,
    ``"ICC profile 'Display P3'"``, ``"camera raw (LibRaw)"``, or the ``input_space`` given).

    Read and decoded a band of rows at a time, with no full-size copy beside the result; a large
    image's result is mapped from disk (``out_of_core``: default from its size, see
    ``skinfit._scratch``)."""
    path = Path(path)
    if path.suffix.lower() in RAW_SUFFIXES:
        return _read_raw(path).astype(dtype, copy=False), None, "camera raw (LibRaw, camera white balance, linear sRGB)"
    oiio = _oiio()
    with _opened(path) as image:
        spec = image.spec()
        names = [name.upper() for name in spec.channelnames]
        index = {}
        for channel in ("R", "G", "B", "A"):
            matches = [i for i, name in enumerate(names) if name == channel or name.endswith("." + channel)]
            if matches:
                index[channel] = matches[0]
        if not all(c in index for c in "RGB"):
            if spec.nchannels in (3, 4) and not any(name in ("R", "G", "B") for name in names):
                index = {"R": 0, "G": 1, "B": 2, **({"A": 3} if spec.nchannels == 4 else {})}  # unnamed channels
            else:
                raise SkinfitInputError(
                    f"{path} has channels {', '.join(spec.channelnames)}; an R, G and B channel are needed"
                )
        decode, encoding = _decoder(path, spec, input_space)
        h, w = spec.height, spec.width
        if h * w == 0:
            raise SkinfitInputError(f"{path} is empty")
        on_disk = scratch.out_of_core(h * w, out_of_core)
        rgb = scratch.image_array((h, w, 3), dtype, on_disk)
        alpha = np.empty((h, w), np.float64) if "A" in index else None
        channels = [index["R"], index["G"], index["B"]]
        rows = max(1, _DECODE_CHUNK // w)
        for top in range(0, h, rows):
            bottom = min(top + rows, h)
            band = image.read_scanlines(0, 0, top, bottom, 0, 0, spec.nchannels, oiio.FLOAT)
            if band is None or _damaged(image):
                raise SkinfitInputError(f"cannot read image {path}: {_first_line(image.geterror()) or 'no pixels'} (truncated or corrupt file)")
            band = np.asarray(band, np.float32).reshape(bottom - top, w, spec.nchannels)  # OIIO's float32, exactly as read
            rgb[top:bottom] = _decoded(band, channels, decode, dtype, pad=h * w > _DECODE_CHUNK)
            if alpha is not None:
                alpha[top:bottom] = band[..., index["A"]]
            scratch.release_pages()
    orientation = spec.get_int_attribute("Orientation", 1)
    if orientation in _ORIENTATIONS and orientation != 1:
        rgb = _oriented_copy(rgb, orientation)
        alpha = None if alpha is None else orient(alpha, orientation)
    return rgb, alpha, encoding


def _decoder(path: Path, spec, input_space: str | None):
    """(decode: float64 (n, 3) -> linear sRGB, description) for the file's encoding."""
    if input_space is None and spec.getattribute("ICCProfile") is not None and spec.format.basetype not in _float_types():
        try:
            profile = parse_icc(bytes(np.asarray(spec.getattribute("ICCProfile"), dtype=np.uint8)))
        except UnsupportedProfile as error:
            warnings.warn(f"{path.name}: {error}; its pixels are taken as sRGB (give input_space to say otherwise)", stacklevel=3)
        else:
            return profile.to_linear_srgb, f"ICC profile {profile.description!r}"
    space = input_space or _default_space(spec)
    return functools.partial(to_linear_srgb, space=space), space


#: Pixels per chunk of ``_decoded`` (padded: one shape of each decoding program for every image).
_DECODE_CHUNK = 1 << 18


def _decoded(pixels: np.ndarray, channels: list[int], decode, dtype, pad: bool) -> np.ndarray:
    """``decode`` (float64 (n, 3) -> linear sRGB) of the ``channels`` of ``pixels`` (h, w, c), at
    most ``_DECODE_CHUNK`` pixels, into a ``dtype`` array (h, w, 3); ``pad``: to ``_DECODE_CHUNK``
    pixels (the values of decoding the whole image in float64: the transfer functions work per
    pixel, and one padded shape keeps one program per decoder)."""
    h, w, count = pixels.shape
    part = np.asarray(pixels.reshape(-1, count)[:, channels], np.float64)
    n = len(part)
    if pad:
        part = padded_rows(part, _DECODE_CHUNK)
    return np.asarray(np.asarray(decode(part))[:n], dtype).reshape(h, w, 3)


def _oriented_copy(stored: np.ndarray, orientation: int) -> np.ndarray:
    """``orient``ed copy of ``stored`` (h, w, 3), out of core where it is, a band of rows at a time."""
    view = _ORIENTATIONS[orientation](stored)
    out = scratch.like(stored, shape=view.shape)
    rows = max(1, _DECODE_CHUNK // max(view.shape[1], 1))
    for top in range(0, view.shape[0], rows):
        out[top : top + rows] = view[top : top + rows]
        scratch.release_pages()
    return out


def _read_raw(path: Path) -> np.ndarray:
    """A camera raw file as linear sRGB (h, w, 3) float64: LibRaw's demosaic with the camera's white
    balance, no brightening, gamma 1 (linear), sRGB primaries, 16 bits, its orientation applied."""
    try:
        import rawpy
    except ImportError as error:
        raise SkinfitInputError(f"{path.name} is a camera raw file: reading it needs rawpy (pip install 'skinfit[raw]')") from error
    if not path.is_file():
        raise SkinfitInputError(f"cannot read image {path}: no such file")
    try:
        with rawpy.imread(str(path)) as raw:
            rgb = raw.postprocess(gamma=(1, 1), no_auto_bright=True, output_bps=16, use_camera_wb=True,
                                  output_color=rawpy.ColorSpace.sRGB)
    except Exception as error:  # LibRaw's errors (unsupported camera, damaged file) have no common base
        raise SkinfitInputError(f"cannot read camera raw file {path}: {_first_line(str(error)) or type(error).__name__}") from error
    return np.asarray(rgb, dtype=np.float64) / 65535.0


def read_mask(path: str | os.PathLike) -> np.ndarray:
    """Read a mask image as (h, w) floats in [0, 1] (0: not fitted), whatever its channels and bit
    depth: its alpha channel if it has one, else its only channel (``Y``, ``A`` or unnamed), else the
    largest of its channels. Integer files are scaled to [0, 1]; no transfer function is applied."""
    path = Path(path)
    spec, pixels = _read_pixels(path)
    names = [name.upper() for name in spec.channelnames]
    alpha = [i for i, name in enumerate(names) if name == "A" or name.endswith(".A")]
    if alpha and spec.nchannels > 1:
        return pixels[..., alpha[0]]
    return pixels.max(axis=-1)


def _default_space(spec) -> str:
    declared = (spec.get_string_attribute("oiio:ColorSpace") or "").lower()
    if "linear" in declared or "scene_linear" in declared:
        return "linear"
    if "srgb" in declared:
        return "srgb"
    return "linear" if spec.format.basetype in _float_types() else "srgb"


def _float_types():
    oiio = _oiio()
    return (oiio.HALF, oiio.FLOAT, oiio.DOUBLE)


def to_linear_srgb(rgb: np.ndarray, space: str) -> np.ndarray:
    """Convert RGB in ``space`` (see the module docstring) to linear sRGB."""
    import colour


    key = space.lower()
    if key == "linear":
        return rgb
    if key == "srgb":
        return np.asarray(srgb_decode(rgb))
    if space not in colour.RGB_COLOURSPACES:
        raise SkinfitInputError(
            f"unknown input space {space!r}: use srgb, linear or a colour-science RGB colourspace name"
        )
    converted = colour.RGB_to_RGB(
        rgb, colour.RGB_COLOURSPACES[space], colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=True
    )
    return np.asarray(converted, dtype=np.float64)


def write_exr(path: str | os.PathLike, channels: dict[str, np.ndarray], attributes: dict[str, str] | None = None) -> None:
    """Write (h, w) float maps as one EXR with the given channel names (float32, zip)."""
    oiio = _oiio()
    names = list(channels)
    h, w = np.shape(channels[names[0]])[:2]
    spec = oiio.ImageSpec(w, h, len(names), oiio.FLOAT)
    spec.channelnames = tuple(names)
    spec.attribute("compression", "zip")
    for key, value in (attributes or {}).items():
        spec.attribute(key, str(value))

    def band(top, bottom):  # interleaved float32 rows: a 4096 x 4096 image is never stacked whole
        return np.stack([np.asarray(channels[n][top:bottom], dtype=np.float32) for n in names], axis=-1)

    _write(path, spec, band, h)


def read_exr_channels(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Channels of an EXR by name, and its string attributes."""
    spec, data = _read_pixels(Path(path))
    attributes = {p.name: str(p.value) for p in spec.extra_attribs}
    return {name: data[..., i] for i, name in enumerate(spec.channelnames)}, attributes


def _read_pixels(path: Path, dtype=np.float64):
    """(spec, pixels (h, w, channels) float64 or ``dtype``, as displayed: EXIF orientation applied) of the
    first subimage; unreadable, truncated or corrupt files raise ``SkinfitInputError``."""
    oiio = _oiio()
    with _opened(path) as image:
        spec = image.spec()
        pixels = image.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        if pixels is None or _damaged(image):
            raise SkinfitInputError(f"cannot read image {path}: {_first_line(image.geterror()) or 'no pixels'} (truncated or corrupt file)")
    pixels = np.asarray(pixels, dtype=dtype).reshape(spec.height, spec.width, spec.nchannels)
    if pixels.size == 0:
        raise SkinfitInputError(f"{path} is empty")
    return spec, orient(pixels, spec.get_int_attribute("Orientation", 1))


@contextlib.contextmanager
def _opened(path: Path):
    """The file's OIIO ``ImageInput``, closed on leaving; a missing or unreadable file raises
    ``SkinfitInputError``."""
    oiio = _oiio()
    if not path.is_file():
        raise SkinfitInputError(f"cannot read image {path}: no such file")
    image = oiio.ImageInput.open(str(path))
    if image is None:
        raise SkinfitInputError(f"cannot read image {path}: {_first_line(oiio.geterror()) or 'unknown format'}")
    try:
        yield image
    finally:
        image.close()


def _damaged(image) -> bool:
    """Whether the decoder met damage (libjpeg fills a truncated JPEG with grey and goes on)."""
    return bool(image.has_error() if callable(image.has_error) else image.has_error)


def _first_line(message: str) -> str:
    return message.strip().splitlines()[0] if message and message.strip() else ""


def orient(pixels: np.ndarray, orientation: int) -> np.ndarray:
    """Stored pixels (h, w, ...) as displayed under EXIF orientation 1-8 (TIFF/EXIF tag 274: 2
    mirrored, 3 rotated 180, 4 flipped, 5 transposed, 6 rotated 90 clockwise, 7 transversed, 8
    rotated 90 anticlockwise); other values leave them as they are."""
    return np.ascontiguousarray(_ORIENTATIONS[orientation](pixels)) if orientation in _ORIENTATIONS else pixels


def _transpose(a: np.ndarray) -> np.ndarray:
    return np.swapaxes(a, 0, 1)


#: The displayed view of stored pixels for each EXIF orientation (see ``orient``).
_ORIENTATIONS = {
    1: lambda a: a, 2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1],
    5: _transpose, 6: lambda a: _transpose(a)[:, ::-1], 7: lambda a: _transpose(a)[::-1, ::-1], 8: lambda a: _transpose(a)[::-1],
}


def write_png(path: str | os.PathLike, encoded_rgb: np.ndarray, bits: int = 8) -> None:
    """Write encoded values in [0, 1] (h, w, 3) as an 8- or 16-bit PNG."""
    oiio = _oiio()
    if bits not in (8, 16):
        raise SkinfitInputError(f"PNG bits must be 8 or 16, got {bits}")
    top, dtype, fmt = (255.0, np.uint8, oiio.UINT8) if bits == 8 else (65535.0, np.uint16, oiio.UINT16)
    h, w, channels = np.shape(encoded_rgb)
    spec = oiio.ImageSpec(w, h, channels, fmt)

    def band(first, last):
        return np.round(np.clip(encoded_rgb[first:last], 0.0, 1.0) * top).astype(dtype)

    _write(path, spec, band, h)


#: Rows per band of ``_write``.
_WRITE_ROWS = 256


def _write(path, spec, band, height: int) -> None:
    """Write the rows ``band(top, bottom)`` gives, ``_WRITE_ROWS`` at a time, through a temporary file
    and rename, so that an interrupted run leaves no partial file and no whole-image copy is made."""
    oiio = _oiio()
    path = Path(path)
    handle, temp = tempfile.mkstemp(suffix=path.suffix, dir=path.parent)
    os.close(handle)
    try:
        out = oiio.ImageOutput.create(temp)
        if out is None or not out.open(temp, spec):
            raise OSError(f"cannot write {path}: {oiio.geterror()}")
        ok = True
        for top in range(0, height, _WRITE_ROWS):
            bottom = min(top + _WRITE_ROWS, height)
            ok = ok and out.write_scanlines(top, bottom, 0, np.ascontiguousarray(band(top, bottom)))
            scratch.release_pages()  # the rows of out-of-core maps just written
        out.close()
        if not ok:
            raise OSError(f"cannot write {path}: {out.geterror()}")
        os.replace(temp, path)
    finally:
        if os.path.exists(temp):
            os.remove(temp)
