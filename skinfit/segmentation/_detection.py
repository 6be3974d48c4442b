"""Faces found by BlazeFace (MediaPipe's face detector), at every scale of the photo.

The detector sees a 192 x 192 letterboxed view (full range; 128 x 128 short range for close-ups):
faces below ~15 % of the photo's long side are too small there, so the photo is also cut into
overlapping tiles of a pyramid (long side 384 and 768 pixels), each a view of its own. Boxes from
all views are merged by MediaPipe's weighted non-maximum suppression.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._caching import eager_cache
from ._raster import letterbox
from ._runtime import run_model


@dataclasses.dataclass(frozen=True)
class Detector:
    """One BlazeFace model: its file, input side (pixels), anchor strides and the score it keeps."""

    file: str
    side: int
    strides: tuple[int, ...]
    two_per_layer: bool  # MediaPipe's interpolated_scale_aspect_ratio: a second anchor per layer
    min_score: float


FULL_RANGE = Detector("face_detection_full_range_sparse.tflite", 192, (4,), False, 0.6)
SHORT_RANGE = Detector("face_detection_short_range.tflite", 128, (8, 16, 16, 16), True, 0.5)

#: Pyramid levels beyond the whole view: long sides of 2 and 4 views (at most 1.25x the photo).
_LEVELS = 2

#: IoU beyond which two boxes are one face.
_SAME_FACE_IOU = 0.3


@eager_cache(maxsize=None)
def anchors(detector: Detector) -> np.ndarray:
    """Anchor centres (n, 2) in [0, 1] of MediaPipe's SSD anchors with a fixed size and aspect 1:
    per cell of each stride's grid one anchor per layer of that stride (two with
    ``two_per_layer``), in row-major order."""
    out, layer, strides = [], 0, detector.strides
    while layer < len(strides):
        last = layer
        while last < len(strides) and strides[last] == strides[layer]:
            last += 1
        per_cell = (last - layer) * (2 if detector.two_per_layer else 1)
        cells = int(np.ceil(detector.side / strides[layer]))
        y, x = np.meshgrid((np.arange(cells) + 0.5) / cells, (np.arange(cells) + 0.5) / cells, indexing="ij")
        out.append(np.repeat(np.stack([x.ravel(), y.ravel()], axis=1), per_cell, axis=0))
        layer = last
    return np.concatenate(out).astype(np.float32)


def _decode(detector: Detector, view: np.ndarray):
    """Boxes (n, 4: x0 y0 x1 y1), scores (n,) and six keypoints (n, 6, 2) in view pixels of one
    view (side, side, 3) in [0, 1]. Keypoints: the subject's right eye, left eye, nose tip, mouth
    centre, right and left ear tragion."""
    regressors, logits = run_model(detector.file, view * 2.0 - 1.0)  # the models take [-1, 1]
    score = 1.0 / (1.0 + np.exp(-np.clip(logits[0, :, 0], -80.0, 80.0)))
    keep = score >= detector.min_score
    r, score, a = regressors[0][keep], score[keep], anchors(detector)[keep]
    s = detector.side
    cx, cy, w, h = r[:, 0] / s + a[:, 0], r[:, 1] / s + a[:, 1], r[:, 2] / s, r[:, 3] / s
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1) * s
    keypoints = (r[:, 4:16].reshape(-1, 6, 2) / s + a[:, None, :]) * s
    return boxes, score, keypoints


def _weighted_nms(boxes, scores, keypoints):
    """MediaPipe's weighted non-maximum suppression: each cluster (IoU > 0.3 with its best box)
    becomes the score-weighted mean of its boxes and keypoints, with the best score."""
    order = np.argsort(-scores)
    boxes, scores, keypoints = boxes[order], scores[order], keypoints[order]
    faces, remaining = [], np.arange(len(scores))
    while remaining.size:
        b = boxes[remaining]
        width = np.clip(np.minimum(b[0, 2], b[:, 2]) - np.maximum(b[0, 0], b[:, 0]), 0, None)
        height = np.clip(np.minimum(b[0, 3], b[:, 3]) - np.maximum(b[0, 1], b[:, 1]), 0, None)
        area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
        iou = width * height / (area[0] + area - width * height + 1e-9)
        cluster = remaining[iou > _SAME_FACE_IOU]
        weight = scores[cluster][:, None]
        faces.append(((boxes[cluster] * weight).sum(0) / weight.sum(), float(scores[cluster[0]]),
                      (keypoints[cluster] * weight[:, :, None]).sum(0) / weight.sum()))
        remaining = remaining[iou <= _SAME_FACE_IOU]
    return faces


def detect_faces(image: np.ndarray, detector: Detector = FULL_RANGE):
    """Faces in an sRGB-encoded image (h, w, 3) in [0, 1]: a list of (box (4,), score, keypoints
    (6, 2)) in image pixels, from the whole view and the tiles of the pyramid."""
    h, w = image.shape[:2]
    side = detector.side
    found = []
    for level in range(_LEVELS + 1):
        size = side * 2**level
        if level and size > 1.25 * max(h, w):
            break
        square, scale, ox, oy = letterbox(image, size)
        nh, nw = round(h * scale), round(w * scale)
        step = side // 2  # tiles overlap by half: a face cut by one tile's edge is whole in the next
        starts_x, starts_y = ([0], [0]) if level == 0 else (_starts(ox, nw, side, step), _starts(oy, nh, side, step))
        for ty in starts_y:
            for tx in starts_x:
                tile = square[ty : ty + side, tx : tx + side]
                tile = np.pad(tile, ((0, side - tile.shape[0]), (0, side - tile.shape[1]), (0, 0)))
                boxes, scores, keypoints = _decode(detector, tile)
                if level and len(scores):  # drop boxes cut by an inner tile edge
                    keep = np.ones(len(scores), bool)
                    keep &= (boxes[:, 0] > 2) | (tx <= ox)
                    keep &= (boxes[:, 1] > 2) | (ty <= oy)
                    keep &= (boxes[:, 2] < side - 2) | (tx + side >= ox + nw)
                    keep &= (boxes[:, 3] < side - 2) | (ty + side >= oy + nh)
                    boxes, scores, keypoints = boxes[keep], scores[keep], keypoints[keep]
                if len(scores):
                    offset = np.array([tx - ox, ty - oy], np.float32)
                    found.append(((boxes + np.tile(offset, 2)) / scale, scores, (keypoints + offset) / scale))
    if not found:
        return []
    return _weighted_nms(*(np.concatenate(parts) for parts in zip(*found)))


def _starts(offset: int, length: int, side: int, step: int) -> list[int]:
    starts = list(range(offset, max(offset + length - side, offset) + 1, step))
    if starts[-1] + side < offset + length:
        starts.append(offset + length - side)
    return starts
