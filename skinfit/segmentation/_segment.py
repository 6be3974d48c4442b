"""Skin and the other regions of every face in a photo: detection, the face mesh, the mesh's
polygons, then the face's own skin colour.

The mesh gives the regions a colour rule cannot tell: eyes (closed too), brows, lips, the mouth and
the nostrils. Inside the face oval the mesh cannot see hair, beard or glasses, so a pixel is skin
only if its chroma (YCbCr on the sRGB values) is within a Mahalanobis radius of the face's own
skin (sampled on the cheeks, nose and chin) and its luma within a factor of theirs. Ears and
neck lie outside the oval: pixels of the face's skin colour connected to the oval's skin, below
the brows (along the face's own up axis) and inside the person mask of the selfie model, are
skin too. Faces smaller than about 30 pixels are not found.
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np
from scipy import ndimage

from ._detection import FULL_RANGE, SHORT_RANGE, detect_faces
from ._mesh import (
    BROW_MIDDLES,
    CHIN,
    FACE_OVAL,
    FOREHEAD,
    LEFT_BROW,
    LEFT_EYE,
    LIPS_INNER,
    LIPS_OUTER,
    NOSE_BOTTOM,
    RIGHT_BROW,
    RIGHT_EYE,
    SKIN_SAMPLES,
    crop_for,
    crop_of_mesh,
    face_mesh,
)
from ._raster import box_downscale, fill_polygon, warp
from ._runtime import run_model


class FaceRegion(enum.IntEnum):
    """What each pixel of a photo is (the ``region`` map)."""

    BACKGROUND = 0  #: not a face's (background, clothes, hair outside the face, skin of no face)
    SKIN = 1  #: the skin of a face, its ears and neck
    EYES = 2
    BROWS = 3
    LIPS = 4
    MOUTH = 5  #: the mouth's opening: teeth, tongue
    NOSTRILS = 6
    OTHER = 7  #: inside the face but not its skin's colour: hair over the forehead, beard, glasses


@dataclasses.dataclass(frozen=True)
class Face:
    """One face: its box (x0, y0, x1, y1, pixels), the detector's score, the mesh's presence
    probability and its 468 landmarks (x, y, depth; pixels)."""

    box: np.ndarray
    score: float
    presence: float
    landmarks: np.ndarray


@dataclasses.dataclass(frozen=True)
class FaceSegmentation:
    """The faces of a photo, its region map ((h, w) ``FaceRegion`` codes, uint8) and which face
    each painted pixel belongs to (``face_index``: (h, w) int16, k + 1 for ``faces[k]``, 0 for
    none): what a per-face quantity (the melanin blend) is pooled over."""

    faces: tuple[Face, ...]
    region: np.ndarray
    face_index: np.ndarray | None = None

    @property
    def skin(self) -> np.ndarray:
        """(h, w) bool: the skin of the faces."""
        return self.region == FaceRegion.SKIN


#: Mesh presence probability below which a detection is not a face.
_MIN_PRESENCE = 0.5
#: Boxes overlapping by more than this fraction of the smaller one are one face.
_SAME_FACE = 0.5
#: Squared Mahalanobis distance in (Cb, Cr) within which a colour is the face's skin.
_CHROMA_D2 = 16.0
#: Luma range of skin relative to the sample's median (shadowed cheek to lit forehead).
_LUMA_RANGE = (0.45, 1.8)
#: Growth of the eye, brow and lip polygons about their centres (lashes, brow hair, lip line).
_EYE_GROWTH, _BROW_GROWTH, _LIP_GROWTH = 1.25, 1.15, 1.05
#: Non-skin blobs inside the oval smaller than this fraction of it are skin (pores, freckles, glints).
_SPECK = 0.004
#: Margin of the window around a face that its ears and neck may fill, in face sizes.
_WINDOW = 0.8
SELFIE_FILE = "selfie_segmentation.tflite"


#: Long side above which faces are found on a box-downscaled copy (a face of 30 pixels there is
#: 0.7 % of the side; a float copy of a 48 MP photo would hold 0.6 GB).
MAX_SIDE = 4096


def segment_faces(image: np.ndarray) -> FaceSegmentation:
    """Faces and regions of an sRGB-encoded photo (h, w, 3) in [0, 1] (as displayed: the models
    were trained on such photos). No face found: an empty ``faces`` and an all-background map.
    A photo longer than ``MAX_SIDE`` is segmented on a box-downscaled copy; the boxes, landmarks
    and region map come back at the photo's size."""
    image = np.asarray(image, np.float32)  # no copy of a float32 photo
    factor = int(np.ceil(max(image.shape[:2]) / MAX_SIDE))
    if factor == 1:
        return _segment(np.clip(image, 0.0, 1.0))
    h, w = image.shape[:2]
    found = _segment(np.clip(box_downscale(image, factor), 0.0, 1.0))
    rows = np.minimum(np.arange(h) // factor, found.region.shape[0] - 1)  # nearest; the remainder as the edge
    cols = np.minimum(np.arange(w) // factor, found.region.shape[1] - 1)
    faces = tuple(dataclasses.replace(f, box=f.box * factor, landmarks=f.landmarks * factor) for f in found.faces)
    return FaceSegmentation(faces, found.region[rows][:, cols], found.face_index[rows][:, cols])


def _segment(image: np.ndarray) -> FaceSegmentation:
    h, w = image.shape[:2]
    detections = detect_faces(image, FULL_RANGE) or detect_faces(image, SHORT_RANGE)  # close-ups: short range
    faces: list[Face] = []
    for box, score, keypoints in detections:
        points, presence = face_mesh(image, crop_for(box, keypoints[0], keypoints[1]))
        if presence < _MIN_PRESENCE:
            continue
        points, presence = face_mesh(image, crop_of_mesh(points))
        if presence < _MIN_PRESENCE:
            continue
        mesh_box = np.array([points[:, 0].min(), points[:, 1].min(), points[:, 0].max(), points[:, 1].max()])
        if not any(_overlap(mesh_box, f.box) > _SAME_FACE for f in faces):
            faces.append(Face(mesh_box, float(score), presence, points))
    region, face_index = np.zeros((h, w), np.uint8), np.zeros((h, w), np.int16)
    order = sorted(range(len(faces)), key=lambda k: faces[k].box[2] - faces[k].box[0])
    for k in order:  # nearer (larger) faces painted last
        _paint_face(image, faces[k], region, face_index, k + 1)
    return FaceSegmentation(tuple(faces), region, face_index)


def _overlap(a: np.ndarray, b: np.ndarray) -> float:
    width = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    height = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    smaller = min((a[2] - a[0]) * (a[3] - a[1]), (b[2] - b[0]) * (b[3] - b[1]))
    return width * height / max(smaller, 1e-9)


def _paint_face(image: np.ndarray, face: Face, region: np.ndarray, face_index: np.ndarray, index: int) -> None:
    """Write one face's regions into ``region`` and its ``index`` into ``face_index``, within a
    window around it (room for ears, neck)."""
    h, w = region.shape
    x0, y0, x1, y1 = face.box
    fw, fh = x1 - x0, y1 - y0
    margin = _WINDOW * max(fw, fh)  # on every side: the neck is below the face in its own axes, not the photo's
    left, right = int(max(0, x0 - margin)), int(min(w, x1 + margin))
    top, bottom = int(max(0, y0 - margin)), int(min(h, y1 + margin))
    shape = (bottom - top, right - left)
    points = face.landmarks[:, :2] - np.array([left, top])

    def polygon(loop, growth=1.0):
        p = points[list(loop)]
        return fill_polygon(p.mean(0) + (p - p.mean(0)) * growth, shape)

    oval = polygon(FACE_OVAL)
    eyes = polygon(LEFT_EYE, _EYE_GROWTH) | polygon(RIGHT_EYE, _EYE_GROWTH)
    brows = polygon(LEFT_BROW, _BROW_GROWTH) | polygon(RIGHT_BROW, _BROW_GROWTH)
    lips, mouth = polygon(LIPS_OUTER, _LIP_GROWTH), polygon(LIPS_INNER)
    features = eyes | brows | lips
    window = image[top:bottom, left:right]
    sample = np.zeros(shape, bool)
    for loop in SKIN_SAMPLES:
        sample |= polygon(loop)
    colour_skin = _skin_colour(window, sample & oval & ~features)
    skin = ndimage.binary_closing(colour_skin, iterations=max(1, round(fw / 80))) | colour_skin
    not_skin = oval & ~skin & ~features
    labels, n = ndimage.label(not_skin)
    if n:
        sizes = ndimage.sum(not_skin, labels, np.arange(1, n + 1))
        skin |= np.concatenate([[False], sizes < _SPECK * oval.sum()])[labels]
    local = np.zeros(shape, np.uint8)
    local[oval] = FaceRegion.SKIN
    local[oval & ~skin] = FaceRegion.OTHER
    local[polygon(NOSE_BOTTOM) & ~colour_skin & oval] = FaceRegion.NOSTRILS
    # ears and neck: the face's skin colour outside the oval, connected to its skin, below the brows
    up = points[FOREHEAD] - points[CHIN]
    up = up / (np.linalg.norm(up) + 1e-9)
    brow = points[list(BROW_MIDDLES)].mean(0)
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    below_brows = (xx + 0.5 - brow[0]) * up[0] + (yy + 0.5 - brow[1]) * up[1] <= 0
    outside = skin & ~oval & below_brows & _person(image, left, top, right, bottom)
    labels, _ = ndimage.label(ndimage.binary_opening(outside | (oval & skin), iterations=2))
    connected = np.isin(labels, np.unique(labels[oval & skin & (labels > 0)]))
    local[connected & outside & (local == FaceRegion.BACKGROUND)] = FaceRegion.SKIN
    local[brows & oval] = FaceRegion.BROWS
    local[eyes] = FaceRegion.EYES
    local[lips] = FaceRegion.LIPS
    local[mouth] = FaceRegion.MOUTH
    painted = local > 0
    region[top:bottom, left:right][painted] = local[painted]
    face_index[top:bottom, left:right][painted] = index


def _ycbcr(rgb: np.ndarray) -> np.ndarray:
    """BT.601 Y, Cb, Cr of sRGB-encoded values."""
    y = 0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]
    return np.stack([y, 0.564 * (rgb[..., 2] - y), 0.713 * (rgb[..., 0] - y)], axis=-1)


def _skin_colour(window: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """(h, w) bool: pixels of the window of the sample's skin colour: chroma within ``_CHROMA_D2``
    of the sample's robust mean and covariance (the 90 % nearest, twice), luma in ``_LUMA_RANGE``
    of its median. Too small a sample (a tiny face): every pixel."""
    ycc = _ycbcr(window)
    chroma = ycc[sample][:, 1:]
    if len(chroma) < 20:
        return np.ones(window.shape[:2], bool)
    centre, inliers = np.median(chroma, axis=0), np.ones(len(chroma), bool)
    for _ in range(2):
        inverse = np.linalg.inv(np.cov((chroma - centre).T) + 1e-6 * np.eye(2))
        d2 = np.einsum("ni,ij,nj->n", chroma - centre, inverse, chroma - centre)
        inliers = d2 < np.quantile(d2, 0.9)
        centre = chroma[inliers].mean(axis=0)
    inverse = np.linalg.inv(np.cov(chroma[inliers].T) + 0.006**2 * np.eye(2))  # 0.006: 1.5 code values of 8 bits; a crease in shadow is redder
    offset = ycc[..., 1:] - centre
    d2 = np.einsum("...i,ij,...j->...", offset, inverse, offset)
    luma = np.median(ycc[sample][:, 0])
    return (d2 < _CHROMA_D2) & (ycc[..., 0] > _LUMA_RANGE[0] * luma) & (ycc[..., 0] < _LUMA_RANGE[1] * luma + 0.05)


def _person(image: np.ndarray, left: int, top: int, right: int, bottom: int) -> np.ndarray:
    """The selfie model's person mask (probability >= 0.5) over a window, run on a square around it."""
    cx, cy, side = (left + right) / 2, (top + bottom) / 2, max(right - left, bottom - top)
    (probability,) = run_model(SELFIE_FILE, warp(image, cx, cy, side, 0.0, 256))
    rows = ((np.arange(top, bottom) + 0.5 - (cy - side / 2)) / side * 256).astype(int).clip(0, 255)
    cols = ((np.arange(left, right) + 0.5 - (cx - side / 2)) / side * 256).astype(int).clip(0, 255)
    return probability[0, :, :, 0][rows][:, cols] >= 0.5
