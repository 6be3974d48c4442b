"""Embedded ICC profiles of matrix/TRC type (what cameras and phones write: Display P3, Adobe RGB,
sRGB, ProPhoto) to linear sRGB, in floating point.

A matrix/TRC profile maps encoded RGB to the profile connection space (XYZ, D50) through one
tone curve per channel (``rTRC``, ``gTRC``, ``bTRC``) and the colorants (``rXYZ``, ``gXYZ``,
``bXYZ``, already adapted to D50). Linear sRGB follows through sRGB's colorants adapted to D50
with the Bradford transform, as ICC profiles adapt theirs. Unlike a colour-management module's
8-bit transform, nothing is clipped or quantised: colours outside sRGB come out negative or
above one, as the fit's screening expects. Profiles of other kinds (LUT-based, grey, CMYK) are
reported as unsupported by name (ICC.1:2010 sections 7 and 10 for the layout).
"""

from __future__ import annotations

import dataclasses
import struct

import numpy as np


class UnsupportedProfile(ValueError):
    """An embedded profile that is not an RGB matrix/TRC profile."""


@dataclasses.dataclass(frozen=True)
class MatrixTRCProfile:
    """An RGB matrix/TRC ICC profile: its description, colorants (3 x 3, columns r, g, b in XYZ
    D50) and tone curves (encoded -> linear, each a function of an array in [0, 1])."""

    description: str
    colorants: np.ndarray
    curves: tuple

    def to_linear_srgb(self, encoded: np.ndarray) -> np.ndarray:
        """Encoded RGB (..., 3) in [0, 1] -> linear sRGB (..., 3), float64."""
        linear = np.stack([curve(np.asarray(encoded[..., c], dtype=np.float64)) for c, curve in enumerate(self.curves)], axis=-1)
        return linear @ (np.linalg.solve(_srgb_colorants_d50(), self.colorants)).T


def parse_icc(data: bytes) -> MatrixTRCProfile:
    """Parse an ICC profile (bytes); ``UnsupportedProfile`` if it is not RGB matrix/TRC."""
    data = bytes(data)
    if len(data) < 132 or data[36:40] != b"acsp":
        raise UnsupportedProfile("not an ICC profile")
    tags = {}
    (count,) = struct.unpack(">I", data[128:132])
    for i in range(count):
        signature, offset, size = struct.unpack(">4sII", data[132 + 12 * i : 144 + 12 * i])
        tags[signature.decode("latin-1")] = data[offset : offset + size]
    description = _description(tags.get("desc", b""))
    if data[16:20] != b"RGB ":
        raise UnsupportedProfile(f"ICC profile {description!r} is of colour space {data[16:20].decode('latin-1').strip()!r}, not RGB")
    needed = ("rXYZ", "gXYZ", "bXYZ", "rTRC", "gTRC", "bTRC")
    if not all(t in tags for t in needed):
        raise UnsupportedProfile(f"ICC profile {description!r} is not a matrix/TRC profile (LUT-based)")
    colorants = np.stack([_xyz(tags[t]) for t in needed[:3]], axis=-1)
    return MatrixTRCProfile(description, colorants, tuple(_curve(tags[t]) for t in needed[3:]))


def _s15(raw: bytes, n: int) -> np.ndarray:
    return np.array(struct.unpack(f">{n}i", raw[: 4 * n]), dtype=np.float64) / 65536.0


def _xyz(tag: bytes) -> np.ndarray:
    if tag[:4] != b"XYZ ":
        raise UnsupportedProfile(f"colorant tag of type {tag[:4]!r}")
    return _s15(tag[8:], 3)


def _curve(tag: bytes):
    kind = tag[:4]
    if kind == b"curv":
        (n,) = struct.unpack(">I", tag[8:12])
        if n == 0:
            return lambda x: x
        if n == 1:
            gamma = struct.unpack(">H", tag[12:14])[0] / 256.0  # u8Fixed8
            return lambda x: np.power(np.clip(x, 0.0, None), gamma)
        table = np.array(struct.unpack(f">{n}H", tag[12 : 12 + 2 * n]), dtype=np.float64) / 65535.0
        nodes = np.linspace(0.0, 1.0, n)
        return lambda x: np.interp(x, nodes, table)
    if kind == b"para":
        (function,) = struct.unpack(">H", tag[8:10])
        counts = {0: 1, 1: 3, 2: 4, 3: 5, 4: 7}
        if function not in counts:
            raise UnsupportedProfile(f"parametric curve of type {function}")
        g, a, b, c, d, e, f = np.concatenate([_s15(tag[12:], counts[function]), np.zeros(7 - counts[function])])
        if function == 0:
            return lambda x: np.power(np.clip(x, 0.0, None), g)
        if function in (1, 2):  # (a x + b)^g (+ c) above -b / a, else (c)
            offset = c if function == 2 else 0.0
            return lambda x: np.where(x >= -b / a, np.power(np.clip(a * x + b, 0.0, None), g), 0.0) + offset
        if function == 3:  # sRGB-like: (a x + b)^g above d, c x below
            return lambda x: np.where(x >= d, np.power(np.clip(a * x + b, 0.0, None), g), c * x)
        return lambda x: np.where(x >= d, np.power(np.clip(a * x + b, 0.0, None), g) + e, c * x + f)
    raise UnsupportedProfile(f"tone curve of type {kind!r}")


def _description(tag: bytes) -> str:
    if tag[:4] == b"desc":  # ICC v2 textDescriptionType: ASCII count then text
        (n,) = struct.unpack(">I", tag[8:12])
        return tag[12 : 12 + n].split(b"\0")[0].decode("latin-1", "replace")
    if tag[:4] == b"mluc":  # ICC v4 multiLocalizedUnicodeType: the first record, UTF-16BE
        length, offset = struct.unpack(">II", tag[20:28])
        return tag[offset : offset + length].decode("utf-16-be", "replace")
    return "unnamed"


def _srgb_colorants_d50() -> np.ndarray:
    """sRGB's RGB -> XYZ matrix adapted from D65 to D50 by Bradford (as ICC profiles adapt)."""
    import colour

    srgb = colour.RGB_COLOURSPACES["sRGB"]
    d65 = colour.xy_to_XYZ(srgb.whitepoint)
    d50 = np.array([0.9642, 1.0, 0.8249])  # the ICC PCS illuminant (ICC.1:2010 7.2.16)
    adapt = colour.adaptation.matrix_chromatic_adaptation_VonKries(d65, d50, transform="Bradford")
    return adapt @ srgb.matrix_RGB_to_XYZ
