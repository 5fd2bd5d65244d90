"""The dock's pose in the odometry frame, refined by every camera estimate and carried by odometry between them.

The charger does not move, so every frame's DockPose, placed with the odometry pose at the frame's exposure
time, is a measurement of one fixed pose in the odometry frame. Averaging them is what lets the controller
steer on a heading far steadier than one frame's, and coast through the last centimetres where the camera,
too close to the face, no longer sees marker 2. Odometry drifts (wheel slip), so the track's uncertainty grows
with the distance driven and the angle turned, and old frames are slowly forgotten.

Position (x, y) has a 2x2 covariance, the heading its own variance: a frame's heading error is nearly
independent of its position error (the lateral offset comes from marker 2's centre pixel, the angle from
the markers' shapes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.dock.pose2d import Pose2D
from monodock.pose import DockPose, wrap_angle

__all__ = ["DockTrack", "MeasurementNoise", "TrackNoise"]


@dataclass(frozen=True)
class MeasurementNoise:
    """One frame's error, standard deviations as a function of the distance to the dock.

    Defaults are a little above the regression's measured errors (bench/regression_accuracy.py), so that the
    gate does not reject honest frames. Fewer markers seen: the angle is noisier.
    """

    depth_base: float = 0.005
    depth_per_metre: float = 0.01
    lateral_base: float = 0.003
    lateral_per_metre: float = 0.003
    yaw_three_markers_deg: float = 2.5
    yaw_one_marker_deg: float = 8.0

    @classmethod
    def for_method(cls, method: str) -> MeasurementNoise:
        """Defaults for a method, a little above its errors in bench/regression_accuracy.py."""
        if method == "regression":
            return cls()
        if method == "board":
            return cls(0.003, 0.01, 0.002, 0.002, 0.8, 2.0)
        return cls(0.005, 0.015, 0.002, 0.003, 2.5, 3.0)  # one marker's PnP

    def sigmas(self, pose: DockPose, markers: int) -> tuple[float, float, float]:
        """(depth, lateral, yaw) standard deviations for a frame at this pose seeing this many markers."""
        d = max(pose.x, 0.0)
        yaw = self.yaw_three_markers_deg if markers >= 3 else self.yaw_one_marker_deg
        return (
            self.depth_base + self.depth_per_metre * d,
            self.lateral_base + self.lateral_per_metre * d,
            math.radians(yaw),
        )


@dataclass(frozen=True)
class TrackNoise:
    """How fast odometry makes the track uncertain: random-walk drift after one metre driven or one radian turned."""

    position_per_metre: float = 0.01
    heading_per_metre: float = math.radians(2.0)
    heading_per_radian: float = 0.03
    gate_chi2: float = 16.3  # 3 degrees of freedom, 99.9 %
    reset_after_rejections: int = 8


class DockTrack:
    """The dock's pose in the odometry frame with its uncertainty; None until the first frame."""

    def __init__(self, noise: TrackNoise | None = None) -> None:
        self.noise = noise or TrackNoise()
        self.reset()

    def reset(self) -> None:
        """Forget everything (e.g. before a fresh Calculate)."""
        self.mean: Pose2D | None = None
        self.cov_xy: NDArray[np.float64] = np.zeros((2, 2))
        self.var_yaw = 0.0
        self.updates = 0
        self.rejected_in_a_row = 0

    def predict(self, distance: float, rotation: float, lever: float = 0.0) -> None:
        """Grow the uncertainty for ``distance`` metres driven and ``rotation`` radians turned since the last call.

        ``lever`` is the robot's distance to the dock: a heading error of the odometry swings the dock's
        position in the odometry frame by that arm.
        """
        if self.mean is None:
            return
        n = self.noise
        d, r = abs(distance), abs(rotation)
        # A random walk: the variance grows with the distance (not its square), whatever the tick rate.
        var_heading = n.heading_per_metre**2 * d + n.heading_per_radian**2 * r
        self.cov_xy = self.cov_xy + np.eye(2) * (n.position_per_metre**2 * d + lever**2 * var_heading)
        self.var_yaw += var_heading

    def update(self, odom_at_frame: Pose2D, estimate: DockPose, sigmas: tuple[float, float, float]) -> bool:
        """Fold in one frame's estimate, taken with the robot at ``odom_at_frame``; False if gated out."""
        measured = odom_at_frame.compose(Pose2D(estimate.x, estimate.y, estimate.yaw))
        c, s = math.cos(odom_at_frame.theta), math.sin(odom_at_frame.theta)
        rot = np.array([[c, -s], [s, c]])
        r_xy = rot @ np.diag([sigmas[0] ** 2, sigmas[1] ** 2]) @ rot.T
        r_yaw = sigmas[2] ** 2
        if self.mean is None:
            self.mean, self.cov_xy, self.var_yaw = measured, r_xy, r_yaw
            self.updates = 1
            return True
        innov_xy = np.array([measured.x - self.mean.x, measured.y - self.mean.y])
        innov_yaw = wrap_angle(measured.theta - self.mean.theta)
        s_xy = self.cov_xy + r_xy
        s_yaw = self.var_yaw + r_yaw
        mahalanobis = float(innov_xy @ np.linalg.solve(s_xy, innov_xy)) + innov_yaw**2 / s_yaw
        if mahalanobis > self.noise.gate_chi2:
            self.rejected_in_a_row += 1
            if self.rejected_in_a_row >= self.noise.reset_after_rejections:
                # The track, not the frames, is wrong (e.g. it was started from an outlier): start again.
                self.reset()
                return self.update(odom_at_frame, estimate, sigmas)
            return False
        self.rejected_in_a_row = 0
        gain_xy = self.cov_xy @ np.linalg.inv(s_xy)
        xy = np.array([self.mean.x, self.mean.y]) + gain_xy @ innov_xy
        gain_yaw = self.var_yaw / s_yaw
        self.mean = Pose2D(float(xy[0]), float(xy[1]), wrap_angle(self.mean.theta + gain_yaw * innov_yaw))
        self.cov_xy = (np.eye(2) - gain_xy) @ self.cov_xy
        self.var_yaw *= 1.0 - gain_yaw
        self.updates += 1
        return True

    def seed(self, samples: list[tuple[Pose2D, DockPose, tuple[float, float, float]]]) -> None:
        """Start the track from several frames taken standing still: the median of each component.

        ``samples`` are (odometry pose at the frame, the frame's DockPose, its sigmas). The median keeps one
        wild frame (a marker seen small and alone can give a heading tens of degrees off) out of the plan.
        """
        measured = [odom.compose(Pose2D(e.x, e.y, e.yaw)) for odom, e, _ in samples]
        ref = measured[0].theta
        theta = wrap_angle(ref + float(np.median([wrap_angle(m.theta - ref) for m in measured])))
        self.reset()
        self.mean = Pose2D(float(np.median([m.x for m in measured])), float(np.median([m.y for m in measured])), theta)
        # The median of n frames is about as good as the mean of 2n/pi of them.
        shrink = math.sqrt(math.pi / (2 * len(samples)))
        sig = np.median(np.array([s for _, _, s in samples]), axis=0) * shrink
        odom = samples[0][0]
        c, s = math.cos(odom.theta), math.sin(odom.theta)
        rot = np.array([[c, -s], [s, c]])
        self.cov_xy = rot @ np.diag([sig[0] ** 2, sig[1] ** 2]) @ rot.T
        self.var_yaw = float(sig[2] ** 2)
        self.updates = len(samples)

    def robot_in_dock(self, odom: Pose2D) -> Pose2D:
        """The robot's pose in the dock frame, from its odometry pose and the tracked dock."""
        assert self.mean is not None
        return odom.relative_to(self.mean)

    @property
    def sigma_yaw_deg(self) -> float:
        return math.degrees(math.sqrt(self.var_yaw))
