"""Make ``tests/data/eileen_collins_skin_mask.png``, the skin mask of the demo photo.

Independent of the skin model (so that judging the fit on it is not circular): a standard skin-colour
rule in YCbCr (ITU-R BT.601; Cr 135-180, Cb 85-135, luma above 80 of 255) inside the face and neck
region, minus hand-placed ellipses over the eyes, brows and mouth (lips and teeth) and the rows of the
hair fringe. The ellipses were placed by looking at the photo at 4x. Run:
``python -m benchmarks.demo_skin_mask`` (writes the mask and ``benchmarks/results/demo_skin_mask.png``,
an overlay to check it by eye).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PHOTO = ROOT / "tests" / "data" / "eileen_collins_face.png"
MASK = ROOT / "tests" / "data" / "eileen_collins_skin_mask.png"

#: (centre x, centre y, radius x, radius y) in pixels of the 160 x 192 photo.
FACE = (80, 112, 44, 60)
EXCLUDED = {
    "right eye": (58, 86, 11, 5),
    "left eye": (102, 87, 11, 5),
    "right brow": (58, 76, 13, 3.5),
    "left brow": (102, 76, 13, 3.5),
    "mouth": (80, 130, 22, 9),
}
FRINGE_ROWS = 68  # rows above this are hair
NECK = (44, 116, 140, 170)  # x0, x1, y0, y1


def skin_colour(srgb8: np.ndarray) -> np.ndarray:
    """The YCbCr skin-colour rule (ITU-R BT.601; Cr 135-180, Cb 85-135, luma above 80 of 255) per
    pixel (h, w) of an 8-bit sRGB image (h, w, 3): no skin model, no framing."""
    r, g, b = (srgb8[..., c].astype(float) for c in range(3))
    luma = 0.299 * r + 0.587 * g + 0.114 * b
    cb = 128 - 0.168736 * r - 0.331264 * g + 0.5 * b
    cr = 128 + 0.5 * r - 0.418688 * g - 0.081312 * b
    return (cr > 135) & (cr < 180) & (cb > 85) & (cb < 135) & (luma > 80)


def skin_mask(srgb8: np.ndarray) -> np.ndarray:
    """Boolean skin mask (h, w) of an 8-bit sRGB photo (h, w, 3) of the demo's framing."""
    skin = skin_colour(srgb8)
    y, x = np.mgrid[: srgb8.shape[0], : srgb8.shape[1]]

    def ellipse(cx, cy, rx, ry):
        return ((x - cx) / rx) ** 2 + ((y - cy) / ry) ** 2 <= 1

    x0, x1, y0, y1 = NECK
    region = ellipse(*FACE) | ((x > x0) & (x < x1) & (y > y0) & (y < y1))
    mask = skin & region & (y >= FRINGE_ROWS)
    for shape in EXCLUDED.values():
        mask &= ~ellipse(*shape)
    return mask


def main() -> None:
    from PIL import Image

    photo = np.asarray(Image.open(PHOTO).convert("RGB"))
    mask = skin_mask(photo)
    Image.fromarray((mask * 255).astype(np.uint8), mode="L").save(MASK)
    overlay = np.where(mask[..., None], photo, (photo * 0.3).astype(np.uint8))
    out = ROOT / "benchmarks" / "results" / "demo_skin_mask.png"
    out.parent.mkdir(exist_ok=True)
    Image.fromarray(overlay).save(out)
    print(f"wrote {MASK.relative_to(ROOT)}: {int(mask.sum())} skin pixels of {mask.size}")


if __name__ == "__main__":
    main()
