"""Marker corners on real photographs: opencv_contrib's ChArUco photos against the board's X-junctions.

For each photo (tests/data/opencv_contrib: img_00..03, and chocclusion_original held out), every interior marker's
corners by OpenCV's SUBPIX refinement, by monodock's edge refiner, and by the refiner with the edge offset taken out
(``perception.edge_offset``, pooled over img_00..03's markers from their code runs alone), against the true corners
that a local homography through the surrounding chessboard X-junctions gives (``tests/charuco.py``). Prints, per
photo and method, the corners' RMS error and their radial bias (the mean error along the marker's diagonal, outward
positive), and the share of the RMS that is the same in every photo (the print's own raster: no corner method can
see it, the reference does not know it).

    python bench/real_photos.py
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from charuco import CAMERA, DICTIONARY, HELD_OUT, PHOTOS, image, radial_errors, reference
from monodock.core.camera import CameraModel
from monodock.core.layout import DockLayout, MarkerSpec
from monodock.perception.detect import Detection, MarkerDetector, MarkerObservation
from monodock.perception.edge_offset import (
    detection_edge_offset,
    estimate_edge_offset,
    offset_detection,
)
from monodock.perception.refine import refine_detection


def _markers(name: str, camera: CameraModel) -> tuple[dict[int, dict[str, np.ndarray]], list[np.ndarray]]:
    gray = image(name)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementMinAccuracy = 0.01
    params.cornerRefinementMaxIterations = 50
    quads, ids, _ = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(DICTIONARY), params).detectMarkers(gray)
    out: dict[int, dict[str, np.ndarray]] = {}
    runs: list[np.ndarray] = []
    for quad, marker_id in zip(quads, ids.ravel(), strict=True):
        i = int(marker_id)
        layout = DockLayout(
            "DICT_6X6_250",
            0.02,
            (
                MarkerSpec("left", (i + 1) % 250, 0.08, 0.3),
                MarkerSpec("center", i, 0.0, 0.3),
                MarkerSpec("right", (i + 2) % 250, -0.08, 0.3),
            ),
        )
        det = MarkerDetector(layout).detect(gray)
        if "center" not in det.observations:
            continue
        refined = refine_detection(gray, det, camera, modules=layout.modules)
        entry = {"SUBPIX": np.asarray(quad, dtype=np.float64).reshape(4, 2)}
        if "center" not in refined.unrefined:
            entry["refined"] = refined.observations["center"].corners
            only = refined.observations["center"]
            runs += detection_edge_offset(gray, Detection({"center": only}, (), refined.image_size), camera, layout)
        out[i] = entry
    return out, runs


def main() -> int:
    camera = CameraModel.load(CAMERA)
    names = (*PHOTOS, HELD_OUT)
    found = {n: _markers(n, camera) for n in names}
    truth = {n: reference(image(n), camera) for n in names}
    offset = estimate_edge_offset([r for n in PHOTOS for r in found[n][1]])
    print(f"edge offset, pooled over {offset.markers} markers' {offset.runs} code runs of {', '.join(PHOTOS)}:")
    print(f"  {offset.offset_px:+.3f} ± {offset.sd_px:.3f} px\n")
    print("| photo | reference fit px | method | corners | RMS px | radial bias px |")
    print("|---|---:|---|---:|---:|---:|")
    for n in names:
        markers, _ = found[n]
        rows: dict[str, list[tuple[np.ndarray, float]]] = {"SUBPIX": [], "refined": [], "refined + edge offset": []}
        for marker_id, entry in markers.items():
            true = truth[n].corners.get(marker_id)
            if true is None:
                continue
            rows["SUBPIX"].append(radial_errors(entry["SUBPIX"], true))
            if "refined" in entry:
                rows["refined"].append(radial_errors(entry["refined"], true))
                det = Detection({"center": MarkerObservation("center", marker_id, entry["refined"])}, (), (640, 480))
                moved = offset_detection(det, offset.offset_px).observations["center"].corners
                rows["refined + edge offset"].append(radial_errors(moved, true))
        for method, errors in rows.items():
            rms = math.sqrt(float(np.mean([np.sum(e**2, axis=1).mean() for e, _ in errors])))
            bias = float(np.mean([b for _, b in errors]))
            print(f"| {n} | {truth[n].fit_rms_px:.3f} | {method} | {4 * len(errors)} | {rms:.3f} | {bias:+.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
