"""Faces and their skin in photos: MediaPipe's face detector, face mesh and selfie segmenter
(Apache-2.0, shipped in ``models/``, run by ``ai-edge-litert``) and the face's own skin colour.

``segment_faces(srgb)`` returns every face and a region map (``FaceRegion``: skin, eyes, brows,
lips, mouth, nostrils, other); ``fit_image`` fits the skin of the faces by default.
"""

from ._runtime import SegmentationUnavailable, available
from ._segment import Face, FaceRegion, FaceSegmentation, segment_faces

__all__ = ["Face", "FaceRegion", "FaceSegmentation", "SegmentationUnavailable", "available", "segment_faces"]
