"""What the mission knows of the dock: each frame's estimate as an ``Observation``, the odometry of the last seconds
that places a frame where the robot was at its exposure, and the dock's pose in the odometry frame (``DockFilter``).

``DockTrack`` is the one interface to these that the mission, dock-sim and the docking node use: the mission feeds it
odometry and frames; the others read the filtered dock pose at a stamp (``dock_at``).
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from monodock.core.pose import DockPose, wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.dock.interface import Odometry
from monodock.dock.pose_filter import DockFilter, FilterConfig, MeasurementNoise
from monodock.estimation.estimator import Estimator
from monodock.perception.predicted import Prior

__all__ = [
    "DockTrack",
    "Observation",
    "OdometryHistory",
    "Perceive",
    "make_perceive",
    "measurement_covariance",
]

Matrix = NDArray[np.float64]


@dataclass(frozen=True)
class Observation:
    """One frame's estimate: the DockPose (None when the estimator had nothing), how many markers it used, and
    its 3x3 covariance (x m, y m, yaw rad; base_link) when the method gives one (else the mission's defaults).
    """

    stamp: float
    pose: DockPose | None
    markers: int = 0
    covariance: Matrix | None = field(default=None, repr=False, compare=False)
    predicted: int = 0  # of the markers used: those the detector missed, found where the track put them


# What turns an image into an observation: the caller's estimator (regression, board PnP, ...).
Perceive = Callable[[float, "np.ndarray"], Observation]


def make_perceive(
    estimator: Estimator, method: str, *, track: Callable[[], DockTrack | None] | None = None
) -> Perceive:
    """Turn the estimator's method into the controller's per-frame observation.

    ``track``: gives the mission's dock track (None before there is one); once it holds the dock, its prediction
    at each frame's stamp is the estimator's prior, which finds the markers the detector missed
    (``perception.predicted``).
    """

    def perceive(stamp: float, image: np.ndarray) -> Observation:
        prior = None
        t = track() if track is not None else None
        if t is not None:
            at = t.dock_prior(stamp)
            if at is not None:
                prior = Prior(at[0], at[1])
        frame = estimator.estimate("", stamp, image, prior=prior)
        e = frame.estimates[method]
        found = frame.detection.recovered if frame.detection is not None else ()
        predicted = sum(1 for role in e.markers_seen if role in found) if e.pose is not None else 0
        return Observation(stamp, e.pose, len(e.markers_seen), e.covariance, predicted)

    return perceive


def _positive_definite(cov: Matrix) -> bool:
    """Symmetric with positive eigenvalues: a covariance the filter can invert."""
    if not np.allclose(cov, cov.T, rtol=1e-6, atol=1e-12):
        return False
    return bool(np.all(np.linalg.eigvalsh(cov) > 0.0))


def measurement_covariance(observation: Observation, defaults: MeasurementNoise) -> Matrix:
    """The frame's own covariance when it has a usable one, else the method's defaults at its pose."""
    assert observation.pose is not None
    cov = observation.covariance
    if cov is not None:
        cov = np.asarray(cov, dtype=np.float64)
        if cov.shape == (3, 3) and np.all(np.isfinite(cov)) and _positive_definite(cov):
            return cov
    return defaults.covariance(observation.pose, observation.markers)


class OdometryHistory:
    """Odometry poses of the last ``horizon`` seconds, to place a frame by where the robot was at its exposure."""

    def __init__(self, horizon: float = 3.0) -> None:
        self.horizon = horizon
        self._t: list[float] = []
        self._poses: list[Pose2D] = []

    def add(self, t: float, pose: Pose2D) -> None:
        self._t.append(t)
        self._poses.append(pose)
        while self._t and self._t[0] < t - self.horizon:
            self._t.pop(0)
            self._poses.pop(0)

    def at(self, t: float) -> Pose2D | None:
        """The pose at time ``t``, interpolated; the newest after the last; None before the first (or when empty)."""
        if not self._t or t < self._t[0]:
            return None
        i = bisect.bisect_right(self._t, t)
        if i >= len(self._t):
            return self._poses[-1]
        t0, t1 = self._t[i - 1], self._t[i]
        p0, p1 = self._poses[i - 1], self._poses[i]
        w = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
        return Pose2D(
            p0.x + w * (p1.x - p0.x),
            p0.y + w * (p1.y - p0.y),
            wrap_angle(p0.theta + w * wrap_angle(p1.theta - p0.theta)),
        )


class DockTrack:
    """The dock's pose in the odometry frame, predicted by the wheel odometry and refined by frames.

    Attributes:
        filter: the extended Kalman filter (``mean`` None until the first frame).
        last_pose: the newest odometry pose (None before the first), and ``last_stamp`` its time.
    """

    def __init__(self, config: FilterConfig, noise: MeasurementNoise, target: Pose2D | None = None) -> None:
        self.filter = DockFilter(config)
        self.noise = noise
        # The frame the mission docks in, in the dock frame (a taught charging pose); None: the dock frame itself.
        self.target = None if target is None or target == Pose2D(0.0, 0.0, 0.0) else target
        self._history = OdometryHistory()
        self.last_pose: Pose2D | None = None
        self.last_stamp = 0.0

    # --- fed by the mission ------------------------------------------------------------------------

    def move(self, odom: Odometry) -> None:
        """A new odometry reading: the dock stays put, its uncertainty in the odometry frame grows with the wheels'
        drift; the reading is kept to place later frames."""
        if self.last_pose is not None:
            self.filter.predict(self.last_pose, odom.pose, odom.stamp - self.last_stamp)
        self.last_pose, self.last_stamp = odom.pose, odom.stamp
        self._history.add(odom.stamp, odom.pose)

    def place(self, observation: Observation) -> tuple[Pose2D, DockPose, Matrix] | None:
        """Where the robot was (odometry) at the frame's exposure, the frame's estimate of the frame the mission
        docks in (``target``: the taught charging pose; the dock's own without one) and its covariance; None when
        the frame has no pose or is older than the history.

        The covariance is the dock's: the target sits millimetres from the dock's origin, and its lever arm
        changes the covariance by far less than the covariance is known to.
        """
        if observation.pose is None:
            return None
        at = self._history.at(observation.stamp)
        if at is None:
            return None
        pose = observation.pose
        if self.target is not None:
            seen = Pose2D(pose.x, pose.y, pose.yaw).compose(self.target)
            pose = DockPose(seen.x, seen.y, seen.theta)
        return at, pose, measurement_covariance(observation, self.noise)

    def update(self, at: Pose2D, estimate: DockPose, covariance: Matrix) -> bool:
        """Fold one placed frame in; False when the gate refused it."""
        return self.filter.update(at, estimate, covariance)

    def seed(self, samples: Sequence[tuple[Pose2D, DockPose, Matrix]]) -> None:
        """Start afresh from the samples a Calculate took."""
        self.filter.seed(samples)

    def reset(self) -> None:
        """Forget the dock (not the odometry)."""
        self.filter.reset()

    # --- read by the mission, dock-sim and the docking node -----------------------------------------

    def dock_prior(self, stamp: float) -> tuple[DockPose, Matrix] | None:
        """The filtered pose of the dock itself (not the taught ``target``) in base_link at ``stamp`` and its
        covariance: where the next frame's markers must be (``perception.predicted``); None as ``dock_at``."""
        odom = self._history.at(stamp)
        if self.filter.mean is None or odom is None:
            return None
        pose, cov = self.filter.dock_pose(odom)
        if self.target is not None:
            own = Pose2D(pose.x, pose.y, pose.yaw).compose(self.target.inverse())
            pose = DockPose(own.x, own.y, own.theta)
        return pose, cov

    @property
    def mean(self) -> Pose2D | None:
        """The dock's pose in the odometry frame; None until a frame gave one."""
        return self.filter.mean

    def robot_in_dock(self, odom: Pose2D) -> Pose2D:
        """The robot at odometry pose ``odom`` in the dock frame (needs ``mean``)."""
        return self.filter.robot_in_dock(odom)

    def dock_at(self, stamp: float) -> tuple[DockPose, Matrix] | None:
        """The filtered dock pose in base_link where the robot was at ``stamp`` (the newest odometry for a later
        stamp), and its 3x3 covariance; None before the first frame or for a stamp older than the history. With a
        taught charging pose (``target``) it is the pose of the frame the mission docks in."""
        odom = self._history.at(stamp)
        if self.filter.mean is None or odom is None:
            return None
        return self.filter.dock_pose(odom)
