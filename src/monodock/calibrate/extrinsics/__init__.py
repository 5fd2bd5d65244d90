"""Camera-LiDAR extrinsic calibration: where the 2D LiDAR sits on the base, given the camera's mount.

Two ways, both ending in the LiDAR mount (``laser`` in ``base_link``) and the laser pose in the camera's
optical frame:

- **pairs** (the papers' way): LiDAR returns (laser frame, the scan plane z = 0) matched by hand to the pixels
  where they hit a target. ``cv2.solvePnP`` on the pairs gives optical_T_laser; base_T_laser follows from the
  known camera mount. The points must not all lie on one line in the scan plane (one flat target seen once
  gives a line): put the target at several positions.
- **dock** (no target but the charger): over many recorded views, the charger face plane that the camera sees
  (3-marker board PnP, under the known camera mount) must contain the straight segment the LiDAR sees on the
  same face; the LiDAR mount that puts the scan's face points on the camera's face planes is found by
  point-to-plane least squares (Zhang & Pless 2004). The face is vertical, so these constraints fix the
  laser's x, y and yaw but hardly its z, roll and pitch: those are kept from the prior (the robot file).
- **diamond target**: the LiDAR segment's ends on a diamond board's slanted edges, seen by the camera, give
  point/pixel pairs for the pairs method.

One module per method (``pairs``, ``dock``, ``diamond``) and the result they share (``result``: the
ExtrinsicsResult, its YAML and tf line); every public name is importable from here.
"""

from __future__ import annotations

from monodock.calibrate.extrinsics.diamond import (
    EdgeFit,
    edge_pairs_from_views,
    extrinsics_from_target_views,
    target_views_from_recording,
)
from monodock.calibrate.extrinsics.dock import (
    FACE_GATE_M,
    DockView,
    extrinsics_from_dock_views,
    extrinsics_from_recording,
    face_half_width,
    face_points,
)
from monodock.calibrate.extrinsics.pairs import MIN_PAIRS, extrinsics_from_pairs, read_pairs_csv, write_pairs_csv
from monodock.calibrate.extrinsics.result import (
    PAIRING_TOLERANCE_S,
    ExtrinsicsResult,
    result_yaml,
    tf_line,
    write_result_yaml,
)

__all__ = [
    "FACE_GATE_M",
    "MIN_PAIRS",
    "PAIRING_TOLERANCE_S",
    "DockView",
    "EdgeFit",
    "ExtrinsicsResult",
    "edge_pairs_from_views",
    "extrinsics_from_dock_views",
    "extrinsics_from_pairs",
    "extrinsics_from_recording",
    "extrinsics_from_target_views",
    "face_half_width",
    "face_points",
    "read_pairs_csv",
    "result_yaml",
    "target_views_from_recording",
    "tf_line",
    "write_pairs_csv",
    "write_result_yaml",
]
