"""Face segmentation (``skinfit.segmentation``) on real photos and a synthetic group: accuracy and speed.

Run: python -m benchmarks.segment_faces [--out benchmarks/results]

- The demo portrait's face crop (160 x 192, tests/data) against its skin mask, made without the face
  models (a YCbCr rule and hand-placed ellipses, ``benchmarks.demo_skin_mask``): IoU, precision,
  recall; the share of skin in boxes marked by hand on it (``tests/segmentation/test_segment.py``).
- The albedo capture (``../shared/data/face-albedo/``, 0.4 MP) against its head mask (head, ears,
  neck and chest, hair, brows, eyes and lips included): the share of the mask taken as skin, and the
  share of the skin outside it (should be ~0).
- A group: the demo portrait's face pasted at three sizes (face widths ~140, ~110 and ~70 pixels)
  and twice more on a 1600 x 1200 wall of a skin colour with grain: faces found (of 5), the wall
  taken as skin.
- Speed after a warm-up, best of 3, seconds per megapixel, at 0.03, 0.26, 0.4 and 1.9 MP and on the
  group scaled to 12 MP; the issue's target is 0.3 s/MP.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from benchmarks._record import provenance
from skinfit.colorimetry import srgb_encode
from skinfit.io import read_linear_rgb, read_mask
from skinfit.segmentation import segment_faces

ROOT = Path(__file__).resolve().parents[1]
CAPTURE = ROOT.parent / "shared/data/face-albedo"


def encoded(path) -> np.ndarray:
    rgb, _ = read_linear_rgb(path)
    return np.asarray(srgb_encode(np.clip(rgb, 0, 1)), np.float32)


def best_of(call, repeats=3) -> float:
    call()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return min(times)


def group(portrait: np.ndarray, crop: np.ndarray):
    """A 1600 x 1200 wall of sRGB (200, 150, 110) with a sine grain and noise, the portrait twice and
    its face crop at three scales; returns the image and where the faces were pasted (a bool map)."""
    rng = np.random.default_rng(0)
    wall = np.empty((1200, 1600, 3), np.float32)
    wall[:] = np.array([200, 150, 110], np.float32) / 255
    wall += 0.03 * np.sin(np.arange(1600) / 7.0)[None, :, None] + rng.normal(0, 0.01, wall.shape).astype(np.float32)
    pasted = np.zeros(wall.shape[:2], bool)
    placed = [(crop, 50, 60), (crop[::2, ::2], 700, 200), (np.repeat(np.repeat(crop, 2, 0), 2, 1), 500, 1200),
              (portrait[::2, ::2], 900, 700), (portrait[::2, ::2], 100, 500)]
    for image, top, left in placed:
        h, w = image.shape[:2]
        wall[top : top + h, left : left + w] = image
        pasted[top : top + h, left : left + w] = True
    return np.clip(wall, 0, 1), pasted, len(placed)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="benchmarks/results")
    args = parser.parse_args(argv)
    result = {**provenance(), "inputs": {}}

    crop = encoded(ROOT / "tests/data/eileen_collins_face.png")
    portrait = encoded(ROOT / "data/astronaut_eileen_collins.png")
    found = segment_faces(crop)
    rule = read_mask(ROOT / "tests/data/eileen_collins_skin_mask.png") > 0
    both = np.sum(found.skin & rule)
    result["inputs"]["demo crop (160x192) vs its rule-made skin mask"] = {
        "faces": len(found.faces), "iou": float(both / np.sum(found.skin | rule)),
        "precision": float(both / found.skin.sum()), "recall": float(both / rule.sum()),
        "seconds": best_of(lambda: segment_faces(crop)), "megapixels": crop.shape[0] * crop.shape[1] / 1e6}
    found = segment_faces(portrait)
    result["inputs"]["demo portrait (512x512)"] = {
        "faces": len(found.faces), "regions": {int(k): int(v) for k, v in zip(*np.unique(found.region, return_counts=True))},
        "seconds": best_of(lambda: segment_faces(portrait)), "megapixels": 512 * 512 / 1e6}
    if (CAPTURE / "face2_albedo.png").exists():
        capture = encoded(CAPTURE / "face2_albedo.png")
        head = read_mask(CAPTURE / "face2_mask.png") > 0
        found = segment_faces(capture)
        result["inputs"]["albedo capture (501x798) vs its head mask"] = {
            "faces": len(found.faces), "head_mask_taken_as_skin": float(found.skin[head].mean()),
            "skin_outside_head_mask": float(found.skin[~head].sum() / max(found.skin.sum(), 1)),
            "seconds": best_of(lambda: segment_faces(capture)), "megapixels": capture.shape[0] * capture.shape[1] / 1e6}
    image, pasted, placed = group(portrait, crop)
    found = segment_faces(image)
    result["inputs"]["group of 5 on a skin-coloured wall (1600x1200)"] = {
        "faces": len(found.faces), "faces_placed": placed, "wall_taken_as_skin": float(found.skin[~pasted].mean()),
        "seconds": best_of(lambda: segment_faces(image)), "megapixels": image.shape[0] * image.shape[1] / 1e6}
    big = np.repeat(np.repeat(image, 3, 0), 3, 1)[:3000, :4000]  # 12 MP
    found = segment_faces(big)
    result["inputs"]["the group at 12 MP (4000x3000)"] = {
        "faces": len(found.faces), "seconds": best_of(lambda: segment_faces(big), repeats=1), "megapixels": 12.0}
    for row in result["inputs"].values():
        row["s_per_megapixel"] = row["seconds"] / row["megapixels"]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "segment_faces.json").write_text(json.dumps(result, indent=2) + "\n")
    for name, row in result["inputs"].items():
        print(f"{name}: " + ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))


if __name__ == "__main__":
    main()
