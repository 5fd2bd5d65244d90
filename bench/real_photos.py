"""Marker corners on real photographs: opencv_contrib's ChArUco photos against the board's X-junctions.

For each photo (tests/data/opencv_contrib: img_00..03, and chocclusion_original held out), every interior marker's
corners by four methods:

- OpenCV's SUBPIX refinement;
- monodock's per-frame edge refiner (``perception.refine``);
- the refiner with the edge offset taken out (``perception.edge_offset``, pooled over img_00..03's markers from
  their code runs alone): what pnp, board and fused use once a survey has written the offset into the layout;
- the photometric fit of the whole printed marker (``perception.marker_fit``, its own offset fitted): what the
  survey (``monodock calibrate layout``) uses.

Two references for the true corners (``tests/charuco.py``):

- **X-junctions**: a local homography through the chessboard corners round each marker, which assumes every
  marker printed exactly in the middle of its square;
- **+ print placement**: the same, with each marker moved by where the printer put it, a shift in the board's
  plane measured by the same method on the *other* three calibration photos (leave one out; the held-out photo
  takes all four). A print is a raster: each marker sits 0.1-0.2 mm off its square's middle, the same in every
  photo (0.21 mm RMS, ~0.23 px: more than the corners' own error), which no corner method can see and the
  chessboard does not know. A shift moves all four corners alike, so it cannot hide a corner method's bias
  (the radial bias is the same against both references) nor its noise from photo to photo.

Prints, per photo and method, the corners' RMS error and their radial bias (the mean error along the marker's
diagonal, outward positive) against both references, and the per-marker print placement.

    python bench/real_photos.py
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from charuco import CAMERA, DICTIONARY, HELD_OUT, PHOTOS, Reference, image, one_marker_dock, radial_errors, reference
from monodock.core.camera import CameraModel
from monodock.perception.detect import Detection, MarkerDetector, MarkerObservation
from monodock.perception.edge_offset import detection_edge_offset, estimate_edge_offset, offset_detection
from monodock.perception.marker_fit import fit_marker
from monodock.perception.refine import refine_detection

METHODS = ("SUBPIX", "refined", "refined + edge offset", "photometric fit")
F64 = NDArray[np.float64]


def _markers(name: str, camera: CameraModel) -> tuple[dict[int, dict[str, F64]], list[F64]]:
    """Every marker's corners by method (the edge-offset row is added later), and its code runs."""
    gray = image(name)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementMinAccuracy = 0.01
    params.cornerRefinementMaxIterations = 50
    quads, ids, _ = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(DICTIONARY), params).detectMarkers(gray)
    out: dict[int, dict[str, F64]] = {}
    runs: list[F64] = []
    for quad, marker_id in zip(quads, ids.ravel(), strict=True):
        i = int(marker_id)
        layout = one_marker_dock(i)
        det = MarkerDetector(layout).detect(gray)
        if "center" not in det.observations:
            continue
        entry = {"SUBPIX": np.asarray(quad, dtype=np.float64).reshape(4, 2)}
        refined = refine_detection(gray, det, camera, modules=layout.modules)
        if "center" not in refined.unrefined:
            entry["refined"] = refined.observations["center"].corners
            only = Detection({"center": refined.observations["center"]}, (), refined.image_size)
            runs += detection_edge_offset(gray, only, camera, layout)
        fit = fit_marker(gray, det.observations["center"].corners, camera, layout.marker_bits(i))
        if fit is not None:
            entry["photometric fit"] = fit.corners
        out[i] = entry
    return out, runs


def _on_board(camera: CameraModel, ref: Reference, marker_id: int, corners: F64) -> F64:
    """The corners (4, 2) px in the board's plane (m), through the marker's local homography."""
    H = np.linalg.inv(ref.homographies[marker_id])
    return cv2.perspectiveTransform(camera.normalize(corners).reshape(-1, 1, 2), H).reshape(-1, 2)


def _placement(
    camera: CameraModel, found: dict[str, dict[int, dict[str, F64]]], truth: dict[str, Reference], method: str
) -> dict[str, dict[int, F64]]:
    """Per photo and marker, the print's shift of the marker (2,) m, as ``method`` measures it on the other
    calibration photos (all four for the held-out photo)."""
    return {
        name: _shifts(camera, found, truth, method, [o for o in PHOTOS if o != name], found[name]) for name in found
    }


def _shifts(
    camera: CameraModel,
    found: dict[str, dict[int, dict[str, F64]]],
    truth: dict[str, Reference],
    method: str,
    photos: list[str],
    markers: Iterable[int],
) -> dict[int, F64]:
    """Each marker's print shift (2,) m: the mean over ``photos`` of its corners' mean offset from its square."""
    out: dict[int, F64] = {}
    for marker_id in markers:
        shifts = [
            (_on_board(camera, truth[o], marker_id, found[o][marker_id][method]) - truth[o].squares[marker_id]).mean(
                axis=0
            )
            for o in photos
            if marker_id in found[o] and method in found[o][marker_id] and marker_id in truth[o].corners
        ]
        if len(shifts) >= 2:
            out[marker_id] = np.mean(shifts, axis=0)
    return out


def _rms_bias(errors: list[tuple[F64, float]]) -> tuple[float, float]:
    rms = math.sqrt(float(np.mean([np.sum(e**2, axis=1).mean() for e, _ in errors])))
    return rms, float(np.mean([b for _, b in errors]))


def main() -> int:
    camera = CameraModel.load(CAMERA)
    names = (*PHOTOS, HELD_OUT)
    found = {}
    runs = []
    for n in names:
        found[n], r = _markers(n, camera)
        runs += r if n in PHOTOS else []
    truth = {n: reference(image(n), camera) for n in names}
    offset = estimate_edge_offset(runs)
    print(f"edge offset, pooled over {offset.markers} markers' {offset.runs} code runs of {', '.join(PHOTOS)}:")
    print(f"  {offset.offset_px:+.3f} ± {offset.sd_px:.3f} px\n")
    for n in names:
        for marker_id, entry in found[n].items():
            if "refined" in entry:
                det = Detection({"center": MarkerObservation("center", marker_id, entry["refined"])}, (), (640, 480))
                entry["refined + edge offset"] = offset_detection(det, offset.offset_px).observations["center"].corners
    placements = {m: _placement(camera, found, truth, m) for m in METHODS}
    print("Each marker's print placement (photometric fit, mean over the four calibration photos), mm:")
    markers = sorted({i for n in PHOTOS for i in truth[n].corners})
    all_four = _shifts(camera, found, truth, "photometric fit", list(PHOTOS), markers)
    print("  " + ", ".join(f"{i}: ({s[0] * 1e3:+.2f}, {s[1] * 1e3:+.2f})" for i, s in sorted(all_four.items())))
    print()
    print("| photo | reference fit px | method | corners | X-junctions: RMS / bias px | + print placement |")
    print("|---|---:|---|---:|---:|---:|")
    for n in names:
        ref = truth[n]
        for method in METHODS:
            plain, placed = [], []
            for marker_id, entry in found[n].items():
                shift = placements[method][n].get(marker_id)
                if method not in entry or marker_id not in ref.corners or shift is None:
                    continue
                plain.append(radial_errors(entry[method], ref.corners[marker_id]))
                placed.append(radial_errors(entry[method], ref.corners_at(camera, marker_id, shift)))
            (r0, b0), (r1, b1) = _rms_bias(plain), _rms_bias(placed)
            print(
                f"| {n} | {ref.fit_rms_px:.3f} | {method} | {4 * len(plain)} | {r0:.3f} / {b0:+.3f} | "
                f"{r1:.3f} / {b1:+.3f} |"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
