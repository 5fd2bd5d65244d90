"""The papers' estimator at run time (§2, Fig. 2b; §4.8): features → depth model → that depth's angle model →
lateral offset by back-projection → DockPose in base_link.

The lateral offset is the general form of the papers' K = Z·P/f: marker 2's centre pixel is back-projected
along its ray (through the lens and the camera mount) to the plane x = predicted depth in base_link, where
the marker's centre stands on an upright dock. With the camera at the origin looking forward and no lens
distortion it reduces to Z·P/f exactly.
"""

from __future__ import annotations

import functools
import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.pose import DockPose
from monodock.core.robot import RobotConfig
from monodock.estimation.pnp import PoseEstimate
from monodock.perception.detect import Detection
from monodock.perception.features import (
    MARKER_SETS,
    choose_marker_set,
    feature_vector,
    model_feature_names,
    model_features,
)

if TYPE_CHECKING:
    from monodock.estimation.bundle import Bundle

__all__ = [
    "ANGLE_LABELS",
    "DEPTH_LABELS",
    "RANGE_TOLERANCE_M",
    "RegressionEstimator",
    "lateral_by_back_projection",
    "lateral_from_normalised",
]

# Which label columns the models learn: the papers' (default) or the line fit's.
DEPTH_LABELS = {"point": "label_x_m", "line": "label_x_line_m"}
ANGLE_LABELS = {"line": "label_yaw_deg", "endpoints": "label_yaw_endpoints_deg"}

# Predicted depths this close outside the segment table still use the edge segment's model; further out
# the frame is outside what the models were trained on and gets no estimate.
RANGE_TOLERANCE_M = 0.02


def lateral_by_back_projection(
    centre_px: NDArray[np.float64], x: float, camera: CameraModel, robot: RobotConfig
) -> float:
    """The y in base_link where marker 2's centre ray reaches the plane x = ``x`` (the papers' K, in general).

    Args:
        centre_px: marker 2's centre pixel (through the lens), shape (2,).
        x: the predicted depth, base_link x of the dock (and so of marker 2's centre), metres.
        camera: the intrinsics and distortion.
        robot: the camera mount.
    """
    return lateral_from_normalised(camera.normalize(centre_px)[0], x, robot)


def lateral_from_normalised(n: NDArray[np.float64], x: float, robot: RobotConfig) -> float:
    """The same from marker 2's centre in undistorted normalised image coordinates (x/z, y/z)."""
    T = robot.base_T_optical()
    d = T[:3, :3] @ np.array([n[0], n[1], 1.0])
    c = T[:3, 3]
    if d[0] <= 1e-9:
        return math.nan
    t = (x - c[0]) / d[0]
    return float(c[1] + t * d[1])


class RegressionEstimator:
    """Per-frame DockPose from a trained model bundle (the ``regression`` method).

    Args:
        bundle: the loaded model bundle (ONNX models and their segment table).
        camera, robot: the calibration at run time (normally the bundle's own).
    """

    method = "regression"

    def __init__(self, bundle: Bundle, camera: CameraModel, robot: RobotConfig) -> None:
        self.bundle, self.camera, self.robot = bundle, camera, robot
        self.segments = bundle.segments
        lo = self.segments.start_m
        self.range_m = (lo, lo + self.segments.count * self.segments.width_m)

    def estimate(self, detection: Detection) -> PoseEstimate:
        """The DockPose of one detection, or an invalid estimate with the reason."""
        return self.estimate_raw(feature_vector(detection, self.camera), detection.roles_seen)

    def estimate_raw(self, raw: NDArray[np.float64], roles_seen: tuple[str, ...]) -> PoseEstimate:
        """The same from a raw feature vector (FEATURE_NAMES order) and the roles seen."""
        if "center" not in roles_seen:
            return PoseEstimate(self.method, None, "marker 2 not detected", roles_seen)
        set_name = choose_marker_set(roles_seen, self.bundle.sets)
        if set_name is None:
            return PoseEstimate(self.method, None, "no model for the markers seen", roles_seen)
        X = model_features(raw, self.camera, set_name)
        if not np.all(np.isfinite(X)):
            return PoseEstimate(self.method, None, "degenerate marker geometry", roles_seen)
        x = float(self.bundle.predict_depth(set_name, X)[0])
        depth = x - self.robot.camera_mount.x
        lo, hi = self.range_m
        if not (lo - RANGE_TOLERANCE_M <= depth <= hi + RANGE_TOLERANCE_M):
            return PoseEstimate(
                self.method,
                None,
                f"predicted depth {depth:.2f} m is outside the trained range {lo:.2f}-{hi:.2f} m",
                roles_seen,
            )
        segment = self.segments.index(min(max(depth, lo), hi))
        assert segment is not None
        yaw_deg = math.nan
        used = set_name
        # The richest marker set that has an angle model for this segment; smaller sets were trained on
        # more rows (every row has marker 2), so they often cover segments the larger set could not.
        for candidate in sorted(self.bundle.sets, key=lambda s: -len(s)):
            if choose_marker_set(roles_seen, (candidate,)) is None or not self.bundle.has_angle_model(
                candidate, segment
            ):
                continue
            Xc = X if candidate == set_name else model_features(raw, self.camera, candidate)
            yaw_deg = float(self.bundle.predict_yaw_deg(candidate, segment, Xc)[0])
            used = candidate
            break
        if not math.isfinite(yaw_deg):
            lo_s, hi_s = self.segments.bounds(segment)
            return PoseEstimate(
                self.method,
                None,
                f"no angle model for the {lo_s * 100:.0f}-{hi_s * 100:.0f} cm segment",
                roles_seen,
            )
        # Marker 2's centre through the lens is among the model inputs already: (m2_u, m2_v), normalised.
        iu = _m2_centre_columns(set_name)
        y = lateral_from_normalised(X[0, iu], x, self.robot)
        if not math.isfinite(y):
            return PoseEstimate(self.method, None, "marker 2 is behind the camera's y-z plane", roles_seen)
        return PoseEstimate(self.method, DockPose(x, y, math.radians(yaw_deg)), "", MARKER_SETS[used])


@functools.lru_cache(maxsize=8)
def _m2_centre_columns(set_name: str) -> list[int]:
    names = model_feature_names(set_name)
    return [names.index("m2_u"), names.index("m2_v")]
