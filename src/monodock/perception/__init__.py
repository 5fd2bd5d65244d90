"""From image to markers: ArUco detection, bias-free corner refinement, the papers' side-length features."""

from __future__ import annotations

from typing import TYPE_CHECKING

from monodock.core.face import lazy_face

if TYPE_CHECKING:
    from monodock.perception.detect import Detection, MarkerDetector, as_gray
    from monodock.perception.edge_offset import EdgeOffset
    from monodock.perception.features import MARKER_SETS, feature_vector
    from monodock.perception.refine import refine_detection

__all__ = [
    "MARKER_SETS",
    "Detection",
    "EdgeOffset",
    "MarkerDetector",
    "as_gray",
    "feature_vector",
    "refine_detection",
]

__getattr__, __dir__ = lazy_face(__name__, __all__)
