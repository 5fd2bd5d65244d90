"""Teach the charging pose: where base_link must end, in the dock frame as this camera and this layout see it.

A person drives or pushes the robot onto the charger's contacts until it charges, then lets it back off about a
metre straight on its odometry while recording (images, camera_info, ``nav_msgs/Odometry``, and the battery's
``sensor_msgs/BatteryState``). Every frame of the back-off sees the dock from a little further out; the
odometry says how far that frame's base_link is from where it charged. Together they place the charging pose in
the dock frame, once per frame, and the frames' estimates are combined by their covariances (the camera's, and
the odometry's, which grows with the distance backed).

Because the same camera, layout and mount measure the dock at docking time, whatever is left of their biases
near the face (a layout surveyed a fraction of a millimetre off, a mount a tenth of a degree off, contacts
1 cm off the robot file's ``front_offset``) is in the taught pose and cancels where it matters: at the end.
The result is a ``charging_offset`` (``monodock.dock.config.ChargingOffset``), which ``DockingConfig``, dock-sim
and the docking node take.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from monodock.calibrate.mount import camera_and_odometry, odometry_at
from monodock.core.camera import CameraModel
from monodock.core.config import yaml_text
from monodock.core.layout import DockLayout
from monodock.core.pose import wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.config import ChargingOffset, DockingConfig, docking_config_to_dict
from monodock.errors import InputError
from monodock.estimation.factory import make_estimator
from monodock.recording.read import open_recording

__all__ = ["TaughtPose", "TeachFrame", "taught_config_text", "teach_charging_pose", "teach_from_recording"]

# The odometry's error while backing straight: distance and heading per metre backed, one standard deviation; a
# robot whose odometry is not calibrated (``calibrate mount``) drifts up to a degree per metre.
ODOMETRY_SD_PER_M = (0.003, 0.003, math.radians(0.3))
UNCALIBRATED_SD_PER_M = (0.01, 0.005, math.radians(1.0))
# The frames share their errors (neighbours see the same corners from nearly the same place): the combined pose is
# no better than this, whatever their number (x, y metres; yaw radians).
FLOOR_SD = (0.0002, 0.0002, math.radians(0.05))
# Chi-square, 3 dof, 99.9 %: a frame's estimate beyond this from the combined one is dropped (a misdetection).
OUTLIER_CHI2 = 16.27
MIN_FRAMES = 10
MIN_BACK_OFF_M = 0.3


@dataclass(frozen=True)
class TeachFrame:
    """One frame of the back-off: its stamp, the DockPose (dock in base_link, x y yaw) and its 3x3 covariance."""

    stamp: float
    pose: tuple[float, float, float]
    covariance: NDArray[np.float64] = field(repr=False)


@dataclass(frozen=True)
class TaughtPose:
    """The charging pose as taught.

    Attributes:
        pose: base_link's pose in the dock frame while charging (x, y, yaw).
        offset: the same against the nominal docked pose, as the docking config takes it.
        sd: the standard deviation of x, y (metres) and yaw (radians).
        frames: frames combined, of ``seen``.
        back_off_m: how far the robot backed off (odometry).
        residuals: each combined frame's estimate of the pose minus the taught one, for plots (N, 4: distance
            backed, x, y, yaw).
        notes: what the user should know.
    """

    pose: Pose2D
    offset: ChargingOffset
    sd: tuple[float, float, float]
    frames: int
    seen: int
    back_off_m: float
    residuals: NDArray[np.float64] = field(repr=False)
    notes: tuple[str, ...] = ()

    def summary(self) -> str:
        o = self.offset
        return "\n".join(
            [
                f"charging pose from {self.frames} frames of a {self.back_off_m:.2f} m back-off ({self.seen} seen):",
                f"  base_link at x {self.pose.x * 1e3:+.1f} ±{self.sd[0] * 1e3:.1f} mm, y {self.pose.y * 1e3:+.1f} "
                f"±{self.sd[1] * 1e3:.1f} mm, yaw {math.degrees(self.pose.theta):+.2f} ±{math.degrees(self.sd[2]):.2f}"
                " deg in the dock frame",
                f"  charging_offset: x {o.x * 1e3:+.1f} mm, y {o.y * 1e3:+.1f} mm, yaw {o.yaw_deg:+.2f} deg against "
                "the nominal docked pose",
                *(f"  {n}" for n in self.notes),
            ]
        )


def teach_charging_pose(
    frames: Sequence[TeachFrame],
    odometry: NDArray[np.float64],
    charged_at: float,
    robot: RobotConfig,
) -> TaughtPose:
    """The charging pose from the back-off's frames and odometry.

    Args:
        frames: the frames after ``charged_at`` with a pose.
        odometry: rows (stamp, x, y, yaw), stamp order; corrected by ``robot.odometry`` here.
        charged_at: the last moment the robot charged (it stood on the contacts then).
        robot: the calibrated robot file (``front_offset`` for the offset, ``odometry`` for the wheels' errors).

    Raises:
        InputError: too few frames, or too short a back-off.
    """
    corrected = odometry.copy()
    corrected[:, 1:] = robot.odometry.corrected(odometry[:, 1:])
    usable = [f for f in frames if corrected[0, 0] <= f.stamp <= corrected[-1, 0] and f.stamp > charged_at]
    if len(usable) < MIN_FRAMES:
        raise InputError(
            f"{len(usable)} frames of the back-off see the dock; teaching needs at least {MIN_FRAMES}: back off "
            "slowly, about a metre, with the camera on"
        )
    home = odometry_at(corrected, [charged_at])[0]
    at = odometry_at(corrected, [f.stamp for f in usable])
    h = Pose2D(float(home[0]), float(home[1]), float(home[2]))
    backed = np.array([h.distance(Pose2D(*q)) for q in at])
    if backed.max() < MIN_BACK_OFF_M:
        raise InputError(
            f"the robot backed off {backed.max():.2f} m after charging; teaching needs at least {MIN_BACK_OFF_M} m "
            "(about a metre, straight)"
        )
    # Each frame's dock pose in the charging base_link frame, and its covariance there.
    means, covs = [], []
    per_m = UNCALIBRATED_SD_PER_M if robot.odometry.identity else ODOMETRY_SD_PER_M
    for f, q, d in zip(usable, at, backed, strict=True):
        rel = Pose2D(float(q[0]), float(q[1]), float(q[2])).relative_to(h)  # base at the frame, in the home frame
        dock = rel.compose(Pose2D(*f.pose))
        c, s = math.cos(rel.theta), math.sin(rel.theta)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        # The frame's covariance turned into the home frame, plus the odometry's: its heading error swings the
        # frame's view of the dock about the frame's base_link by the distance to the dock.
        lever = math.hypot(f.pose[0], f.pose[1])
        odo = np.diag(np.square(np.array(per_m) * max(d, 1e-3)))
        odo[1, 1] += (per_m[2] * d * lever) ** 2
        means.append((dock.x, dock.y, dock.theta))
        covs.append(R @ f.covariance @ R.T + odo)
    z = np.array(means)
    z[:, 2] = np.unwrap(z[:, 2])
    info = np.array([np.linalg.inv(c) for c in covs])
    keep = np.ones(len(z), dtype=bool)
    for _ in range(5):  # robust: drop frames far from the combined estimate and combine again
        W = info[keep].sum(axis=0)
        mean = np.linalg.solve(W, np.einsum("nij,nj->i", info[keep], z[keep]))
        d = z - mean
        chi2 = np.einsum("ni,nij,nj->n", d, info, d)
        new = chi2 < OUTLIER_CHI2
        if new.sum() < MIN_FRAMES or np.array_equal(new, keep):
            break
        keep = new
    W = info[keep].sum(axis=0)
    mean = np.linalg.solve(W, np.einsum("nij,nj->i", info[keep], z[keep]))
    cov_dock = np.linalg.inv(W)
    # The frames' scatter, when it is wider than their covariances say, widens the result (unmodelled errors).
    spread = float(np.mean(chi2[keep])) / 3.0
    cov_dock = cov_dock * max(spread, 1.0) + np.diag(np.square(FLOOR_SD))
    dock = Pose2D(float(mean[0]), float(mean[1]), wrap_angle(float(mean[2])))
    pose = dock.inverse()  # base_link (charging) in the dock frame
    J = _inverse_jacobian(dock)
    cov = J @ cov_dock @ J.T
    sd = tuple(float(v) for v in np.sqrt(np.diag(cov)))
    offset = ChargingOffset(pose.x + robot.front_offset, pose.y, math.degrees(pose.theta))
    residuals = np.column_stack([backed, z - mean])[keep]
    notes = (
        [] if not robot.odometry.identity else ["the odometry is not calibrated (calibrate mount): its drift counted"]
    )
    if (~keep).any():
        notes.append(f"{int((~keep).sum())} frames dropped as outliers")
    if spread > 1.5:
        notes.append(f"the frames scatter {math.sqrt(spread):.1f}x wider than their covariances: the sd is widened")
    return TaughtPose(
        pose, offset, (sd[0], sd[1], sd[2]), int(keep.sum()), len(frames), float(backed.max()), residuals, tuple(notes)
    )


def taught_config_text(taught: TaughtPose, base: DockingConfig | None, source: str) -> str:
    """The docking config with the taught charging offset: the whole ``base`` when given, else only the offset
    (every other key keeps its default); a header says how it was taught."""
    sd = taught.sd
    head = (
        f"# Taught by monodock teach from {source}: {taught.frames} frames of a {taught.back_off_m:.2f} m back-off.\n"
        f"# base_link charges at x {taught.pose.x * 1e3:+.1f} y {taught.pose.y * 1e3:+.1f} mm, yaw "
        f"{math.degrees(taught.pose.theta):+.2f} deg in the dock frame (sd {sd[0] * 1e3:.1f} mm, {sd[1] * 1e3:.1f} mm, "
        f"{math.degrees(sd[2]):.2f} deg).\n"
    )
    offset = {"x": taught.offset.x, "y": taught.offset.y, "yaw_deg": taught.offset.yaw_deg}
    if base is None:
        return head + yaml_text({"charging_offset": offset}, flow=None)
    data = docking_config_to_dict(base)
    data["charging_offset"] = offset
    return head + yaml_text(data, flow=None)


def _inverse_jacobian(p: Pose2D) -> NDArray[np.float64]:
    """d(p⁻¹)/dp for a planar pose p = (x, y, theta): p⁻¹ = (-c x - s y, s x - c y, -theta)."""
    c, s = math.cos(p.theta), math.sin(p.theta)
    return np.array(
        [
            [-c, -s, s * p.x - c * p.y],
            [s, -c, c * p.x + s * p.y],
            [0.0, 0.0, -1.0],
        ]
    )


def teach_from_recording(
    path: str,
    layout: DockLayout,
    robot: RobotConfig,
    *,
    camera: CameraModel | None = None,
    method: str = "fused",
    docked_at_start: bool = False,
) -> TaughtPose:
    """Teach from a recording: the charging moment from its battery state (or its start), then the back-off.

    Args:
        path: the recording (rosbag2 or ROS 1 bag) with images, odometry and, unless ``docked_at_start``, the
            battery state.
        layout, robot: the dock's (surveyed) layout and the (calibrated) robot file.
        camera: the camera, else the recording's CameraInfo.
        method: ``fused`` (the refined corners' planar fit, with its covariance) or ``board``.
        docked_at_start: the recording has no battery state; it starts with the robot on the contacts.

    Raises:
        InputError: no odometry, no charging moment, too few frames (one line saying what to record).
    """
    if method not in ("fused", "board"):
        raise InputError(f"teach uses the fused or the board method, got {method!r}")
    with open_recording(path) as rec:
        cam, odometry = camera_and_odometry(rec, path, camera)
        charging = rec.charging()
        if docked_at_start:
            charged_at = float(odometry[0, 0])
        else:
            if not charging:
                raise InputError(
                    f"{path} has no battery state (sensor_msgs/BatteryState): record it too, or pass "
                    "--docked-at-start if the recording starts with the robot on the contacts"
                )
            on = [t for t, c in charging if c]
            if not on:
                raise InputError(
                    f"{path}: the battery never reports CHARGING: drive or push the robot onto the contacts until it "
                    "charges, then record the back-off"
                )
            charged_at = max(on)
        estimator = make_estimator(method=method, camera=cam, layout=layout, robot=robot)
        frames = []
        for frame in rec.images():
            if frame.image is None or frame.stamp <= charged_at:
                continue
            e = estimator.estimate(frame.name, frame.stamp, frame.image).estimates[method]
            if e.pose is None:
                continue
            cov = e.covariance if e.covariance is not None else _board_covariance(e.pose.x)
            frames.append(TeachFrame(frame.stamp, (e.pose.x, e.pose.y, e.pose.yaw), np.asarray(cov)))
    return teach_charging_pose(frames, odometry, charged_at, robot)


def _board_covariance(depth: float) -> NDArray[np.float64]:
    """Board PnP gives no covariance: a conservative one (1 mm + 0.5 % of the depth; 0.3° + 0.3° per metre)."""
    return np.diag(np.square([0.001 + 0.005 * depth, 0.001 + 0.005 * depth, math.radians(0.3 + 0.3 * depth)]))
