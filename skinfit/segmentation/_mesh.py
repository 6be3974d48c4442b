"""The 468-point face mesh (MediaPipe's face landmark model) on a face's rotated crop, and the
contours of the mesh that bound the face's regions."""

from __future__ import annotations

import numpy as np

from ._raster import warp
from ._runtime import run_model

#: Contour loops of the mesh: MediaPipe's ``face_mesh_connections`` (the subject's left and right).
FACE_OVAL = (10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377, 152, 148,
             176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109)
LEFT_EYE = (263, 249, 390, 373, 374, 380, 381, 382, 362, 398, 384, 385, 386, 387, 388, 466)
RIGHT_EYE = (33, 7, 163, 144, 145, 153, 154, 155, 133, 173, 157, 158, 159, 160, 161, 246)
LEFT_BROW = (276, 283, 282, 295, 285, 336, 296, 334, 293, 300)
RIGHT_BROW = (46, 53, 52, 65, 55, 107, 66, 105, 63, 70)
LIPS_OUTER = (61, 146, 91, 181, 84, 17, 314, 405, 321, 375, 291, 409, 270, 269, 267, 0, 37, 39, 40, 185)
LIPS_INNER = (78, 95, 88, 178, 87, 14, 317, 402, 318, 324, 308, 415, 310, 311, 312, 13, 82, 81, 80, 191)
#: Ours: the underside of the nose (alae and columella), where the nostrils are.
NOSE_BOTTOM = (98, 97, 2, 326, 327, 294, 278, 344, 440, 275, 4, 45, 220, 115, 48, 64)
#: Ours: patches of bare skin on every face (cheeks, nose bridge, chin) whose colour is the face's.
SKIN_SAMPLES = (
    (117, 118, 101, 36, 205, 187, 123),
    (346, 347, 330, 266, 425, 411, 352),
    (6, 351, 412, 399, 437, 4, 217, 174, 188, 122),
    (18, 83, 182, 106, 43, 202, 210, 169, 150, 149, 176, 148, 152, 377, 400, 378, 379, 394, 430, 422, 273, 335, 406, 313),
)
#: Landmarks of the chin, the forehead's top and the two brows' middles (the face's own up axis).
CHIN, FOREHEAD, BROW_MIDDLES = 152, 10, (105, 334)
#: The outer eye corners, whose line sets the crop's rotation.
EYE_CORNERS = (33, 263)

MESH_FILE = "face_landmark.tflite"
_SIDE = 192  # the mesh model's input
_CROP_SCALE = 1.5  # MediaPipe's: the crop is 1.5x the face box, square


def crop_for(box: np.ndarray, right_eye: np.ndarray, left_eye: np.ndarray) -> tuple[float, float, float, float]:
    """Centre (x, y), side and rotation (radians) of the mesh's crop of a face box (x0 y0 x1 y1),
    turned so that the line from the subject's right eye to the left one is level."""
    side = _CROP_SCALE * max(box[2] - box[0], box[3] - box[1])
    angle = np.arctan2(left_eye[1] - right_eye[1], left_eye[0] - right_eye[0])
    return (box[0] + box[2]) / 2, (box[1] + box[3]) / 2, side, angle


def face_mesh(image: np.ndarray, crop: tuple[float, float, float, float]) -> tuple[np.ndarray, float]:
    """The 468 landmarks (x, y in image pixels, depth in the same scale) of the face in ``crop``,
    and the model's probability that a face is there."""
    cx, cy, side, angle = crop
    landmarks, presence = run_model(MESH_FILE, warp(image, cx, cy, side, angle, _SIDE))  # input in [0, 1]
    landmarks = landmarks.reshape(468, 3) / _SIDE
    u, v = (landmarks[:, 0] - 0.5) * side, (landmarks[:, 1] - 0.5) * side
    c, s = np.cos(angle), np.sin(angle)
    points = np.stack([c * u - s * v + cx, s * u + c * v + cy, landmarks[:, 2] * side], axis=1)
    return points, float(1.0 / (1.0 + np.exp(-presence.ravel()[0])))


def crop_of_mesh(points: np.ndarray) -> tuple[float, float, float, float]:
    """The crop of a face from its own mesh (MediaPipe's second pass: a tighter, better-turned crop)."""
    box = np.array([points[:, 0].min(), points[:, 1].min(), points[:, 0].max(), points[:, 1].max()])
    return crop_for(box, points[EYE_CORNERS[0]], points[EYE_CORNERS[1]])
