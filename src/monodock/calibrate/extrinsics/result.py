"""Camera-LiDAR extrinsics: the result every method returns, its YAML and tf line, and small geometry."""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from monodock.core import transforms
from monodock.core.atomic import write_text_atomic
from monodock.core.config import yaml_text
from monodock.core.robot import Mount, RobotConfig
from monodock.core.settings import to_mapping

PAIRING_TOLERANCE_S = 0.05
# A LiDAR segment on a flat face (the charger's, a target's edge) is this straight at most (RMS, metres).
MAX_LINE_RMS_M = 0.02


@dataclass(frozen=True)
class ExtrinsicsResult:
    """A calibrated LiDAR mount and how well it fits.

    Attributes:
        method: "pairs" (PnP on LiDAR point / pixel pairs) or "dock" (point-to-plane on the charger face).
        laser_mount: the laser frame's pose in base_link (URDF x y z roll pitch yaw).
        optical_T_laser: the laser frame's pose in the camera's optical frame, 4x4.
        prior_mount: the mount the calibration started from (the robot file's).
        rms: RMS residual: pixels for "pairs", metres point-to-plane for "dock".
        residual_unit: "px" or "m".
        count: pairs used ("pairs") or views used ("dock").
        points: LiDAR points used in total.
        view_rms: per-view RMS point-to-plane distance, metres ("dock"; empty for "pairs").
        std: standard deviation of each solved parameter from the fit's covariance (keys as Mount fields).
        condition: condition number of the normalised normal equations (large: poorly observed).
        fixed: mount fields kept from the prior, not solved.
        notes: what a user should know about the result.
    """

    method: str
    laser_mount: Mount
    optical_T_laser: NDArray[np.float64] = dataclasses.field(repr=False)
    prior_mount: Mount
    rms: float
    residual_unit: str
    count: int
    points: int
    view_rms: tuple[float, ...] = ()
    std: dict[str, float] = dataclasses.field(default_factory=dict)
    condition: float = math.nan
    fixed: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    def base_T_laser(self) -> NDArray[np.float64]:
        """The calibrated laser frame in base_link, 4x4."""
        return self.laser_mount.matrix()

    def robot(self, base: RobotConfig) -> RobotConfig:
        """The robot description with the calibrated LiDAR mount."""
        return dataclasses.replace(base, laser_mount=self.laser_mount)

    def summary(self) -> str:
        """A few lines for a person: the mount, the change from the prior, residuals and notes."""
        m, p = self.laser_mount, self.prior_mount
        what = f"{self.count} {'pairs' if self.method == 'pairs' else 'views'}, {self.points} LiDAR points"
        lines = [
            f"laser mount in base_link ({self.method}: {what}):",
            f"  x {m.x:+.4f} m  y {m.y:+.4f} m  z {m.z:+.4f} m  roll {math.degrees(m.roll):+.3f} deg  "
            f"pitch {math.degrees(m.pitch):+.3f} deg  yaw {math.degrees(m.yaw):+.3f} deg",
            f"  change from the prior: dx {(m.x - p.x) * 100:+.2f} cm  dy {(m.y - p.y) * 100:+.2f} cm  "
            f"dz {(m.z - p.z) * 100:+.2f} cm  dyaw {math.degrees(m.yaw - p.yaw):+.3f} deg",
        ]
        unit = "px" if self.residual_unit == "px" else "cm"
        scale = 1.0 if self.residual_unit == "px" else 100.0
        lines.append(f"  residual RMS {self.rms * scale:.3f} {unit}" + _view_stats(self.view_rms))
        if self.std:
            parts = [
                f"{k} {math.degrees(v):.3f} deg" if k in ("roll", "pitch", "yaw") else f"{k} {v * 100:.2f} cm"
                for k, v in self.std.items()
            ]
            lines.append(f"  1-sigma: {', '.join(parts)}; condition {self.condition:.1f}")
        lines.append(f"  tf base_link -> laser: {tf_line(self)}")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


def _view_stats(view_rms: Sequence[float]) -> str:
    if not view_rms:
        return ""
    v = np.asarray(view_rms) * 100.0
    return f" (per view: median {np.median(v):.2f} cm, max {v.max():.2f} cm)"


# --- small geometry ---------------------------------------------------------------------------------


def _pose_text(T: NDArray[np.float64]) -> str:
    qx, qy, qz, qw = transforms.quaternion_from_matrix(T[:3, :3])
    x, y, z = (float(v) for v in T[:3, 3])
    return f"{x:.6f} {y:.6f} {z:.6f} {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}"


def tf_line(result: ExtrinsicsResult) -> str:
    """base_link -> laser as ``x y z qx qy qz qw`` (static_transform_publisher's argument order)."""
    return _pose_text(result.base_T_laser())


def line_spread(xy: NDArray[np.float64]) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """RMS distance of 2-D points from their total-least-squares line, the line's centroid and direction."""
    mean = xy.mean(axis=0)
    _, s, vt = np.linalg.svd(xy - mean, full_matrices=False)
    spread = float(s[1] / math.sqrt(len(xy))) if len(s) > 1 else 0.0
    return spread, mean, vt[0]


# --- outputs ------------------------------------------------------------------------------------------


def result_yaml(result: ExtrinsicsResult) -> str:
    """The result as YAML: ``laser_mount`` (as in the robot file), the laser in camera_optical, the tf line."""

    o = result.optical_T_laser
    qx, qy, qz, qw = transforms.quaternion_from_matrix(o[:3, :3])
    data: dict[str, Any] = {
        "laser_mount": to_mapping(result.laser_mount),
        "camera_optical_to_laser": {
            "x": float(o[0, 3]),
            "y": float(o[1, 3]),
            "z": float(o[2, 3]),
            "qx": qx,
            "qy": qy,
            "qz": qz,
            "qw": qw,
        },
        "tf_base_link_to_laser": tf_line(result),
        "method": result.method,
        "solved": [k for k in ("x", "y", "z", "roll", "pitch", "yaw") if k not in result.fixed],
        "fixed_from_prior": list(result.fixed),
        "prior_laser_mount": to_mapping(result.prior_mount),
        "residual_rms": float(result.rms),
        "residual_unit": result.residual_unit,
        "pairs" if result.method == "pairs" else "views": result.count,
        "lidar_points": result.points,
        "std": {k: float(v) for k, v in result.std.items()},
        "condition": float(result.condition),
        "notes": list(result.notes),
    }
    if result.view_rms:
        data["view_rms_m"] = [round(float(v), 6) for v in result.view_rms]
    head = (
        "# monodock calibrate extrinsics: the LiDAR (laser frame) in base_link; paste laser_mount into the robot file\n"
    )
    return head + yaml_text(data, flow=None, width=1000)


def write_result_yaml(path: str | os.PathLike[str], result: ExtrinsicsResult, *, force: bool = False) -> None:
    """Write result_yaml atomically (an existing file only with ``force``)."""

    write_text_atomic(path, result_yaml(result), force=force)


def covariance(J: NDArray[np.float64], sigma: float, keys: Sequence[str]) -> tuple[dict[str, float], float]:
    """Parameter 1-sigma from J and the residual sigma, and the condition of the column-normalised J^T J."""
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    Jn = J / norms
    JtJ = Jn.T @ Jn
    cond = float(np.linalg.cond(JtJ))
    try:
        cov = np.linalg.inv(JtJ) / np.outer(norms, norms) * sigma**2
        std = {k: float(math.sqrt(max(cov[i, i], 0.0))) for i, k in enumerate(keys)}
    except np.linalg.LinAlgError:
        std = dict.fromkeys(keys, math.inf)
    return std, cond
