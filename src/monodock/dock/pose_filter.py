"""The dock's pose in the odometry frame: an extended Kalman filter over camera frames and wheel odometry.

The charger does not move, so every frame's DockPose, placed with the odometry pose at the frame's exposure
time, measures one fixed pose in the odometry frame. Filtering those measurements is what lets the controller
steer on a heading far steadier than one frame's, and coast through the last centimetres where the camera,
too close to the face, no longer sees marker 2.

State: s = (X, Y, Θ), the dock's pose in the odometry frame, with a full 3x3 covariance P.

Predict. Odometry is the integral of the wheel encoders; the robot really moved by the odometry increment u
followed by a small error e = (e_x, e_y, e_θ) in the robot's frame after the step (true step = u ∘ e). Writing
the dock in the odometry frame as odom ∘ truth⁻¹ ∘ dock, one step maps it to

    s' = r' ∘ e⁻¹ ∘ r'⁻¹ ∘ s,        r' = the robot's odometry pose after the step,

so the mean stays where it is (e has zero mean: F = I) and P grows by Q = G Σ_e Gᵀ with, to first order in e
and with q = r'⁻¹ ∘ s the dock in the robot's frame,

    G = ∂s'/∂e = diag(R(θ_r'), 1) · [[-1, 0,  q_y],
                                       [ 0, -1, -q_x],
                                       [ 0, 0,  -1 ]].

The third column is the lever arm: a heading error e_θ of the odometry swings the dock, |q| away, sideways
by |q| e_θ, and turns its heading by the same e_θ (so position and heading become correlated).
Σ_e comes from the wheels (OdometryNoise): each wheel's ground distance is its encoder distance d_i times a
per-run scale (1 + N(0, σ_s²)) and per-step noise (1 + N(0, σ_n²)), as in ``monodock.sim.diffdrive``. The
translation error is δd = (δ_l + δ_r)/2, the heading error δθ = (δ_r - δ_l)/b (b: track width), and the
lateral error of an arc of length d is d·δθ/2, so distance driven and angle turned (which rolls the wheels
by ±bΔθ/2) both feed it.

Update. A frame's DockPose is z = h(s, r) = r⁻¹ ∘ s (the dock in base_link, r the odometry pose at the
exposure), with Jacobian H = ∂h/∂s = diag(R(-θ_r), 1) and the frame's own 3x3 covariance (x, y, yaw in
base_link). The innovation's angle is wrapped; frames whose Mahalanobis distance exceeds the chi-square
gate (3 degrees of freedom) are rejected, and after a run of rejections the filter starts again from the
frame (the filter, not the frames, is then what is wrong, e.g. started from an outlier).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from monodock.core.pose import DockPose, wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.settings import section, setting

__all__ = [
    "GATE_CHI2_3DOF",
    "DockFilter",
    "FilterConfig",
    "MeasurementNoise",
    "OdometryNoise",
    "measurement_model",
    "process_jacobian",
]

Matrix = NDArray[np.float64]

# The chi-square quantile of 3 degrees of freedom at 99.9 %: an honest frame is gated out once in 1,000.
GATE_CHI2_3DOF = 16.27


# The geometric methods' noise (MeasurementNoise.for_method): board PnP, and one marker's PnP (IPPE; its two-fold
# yaw ambiguity past 2 m is left to the gate).
_GEOMETRIC_FIELDS = (
    "lateral_base",
    "yaw_three_markers_deg",
    "yaw_one_marker_deg",
    "depth_per_metre3",
    "lateral_per_metre3",
    "yaw_per_metre3_deg",
)
_GEOMETRIC = {
    "board": (0.0005, 0.1, 1.0, 0.0025, 0.0005, 0.2),
    "pnp": (0.0003, 0.15, 0.15, 0.004, 0.0006, 0.5),
}


@dataclass(frozen=True)
class MeasurementNoise:
    """One frame's error, standard deviations growing with the distance d to the dock (DockPose.x, metres).

    The default covariance of a method that gives none of its own: sd = base + per_metre·d + per_metre3·d³
    for depth and lateral, base + per_metre3·d³ for yaw (a marker's image shrinks as 1/d, and PnP's errors
    grow about as d² to d³). Fewer than three markers seen: the yaw's base is the one-marker one.
    """

    depth_base: float = setting(
        0.005, unit="m", positive=True, help="a frame without its own covariance: depth sd at 0 m"
    )
    depth_per_metre: float = setting(0.004, unit="m/m", non_negative=True, help="… growing per metre of distance")
    lateral_base: float = setting(0.0012, unit="m", positive=True, help="lateral sd at 0 m")
    lateral_per_metre: float = setting(0.0006, unit="m/m", non_negative=True, help="… growing per metre")
    yaw_three_markers_deg: float = setting(2.5, unit="°", positive=True, help="yaw sd with three markers seen")
    yaw_one_marker_deg: float = setting(8.0, unit="°", positive=True, help="yaw sd with fewer")
    depth_per_metre3: float = setting(0.0, unit="m/m³", non_negative=True, help="… and per cubic metre")
    lateral_per_metre3: float = setting(0.0, unit="m/m³", non_negative=True, help="… and per cubic metre")
    yaw_per_metre3_deg: float = setting(0.0, unit="°/m³", non_negative=True, help="yaw sd growing per cubic metre")

    @classmethod
    def for_method(cls, method: str) -> MeasurementNoise:
        """Defaults for a method, about 1.25 times its errors' p95/1.96 by depth band in bench/README.md.

        The geometric methods' cubic terms are fitted to the held-out SolvePnP bands (25-250 cm) of
        bench/regression_accuracy.py, with a floor of a millimetre; the regression's errors hardly grow with
        depth (0.3-1.0 cm depth, 0.06-0.18 cm lateral, 1.2-2.4° yaw MAE), so its noise grows linearly, slowly.
        """
        if method == "regression":
            return cls()
        # The geometric methods: a millimetre of depth, no linear growth, the rest theirs (_GEOMETRIC).
        fitted = dict(zip(_GEOMETRIC_FIELDS, _GEOMETRIC["board" if method == "board" else "pnp"], strict=True))
        return cls(depth_base=0.001, depth_per_metre=0.0, lateral_per_metre=0.0, **fitted)

    def sigmas(self, pose: DockPose, markers: int) -> tuple[float, float, float]:
        """(depth, lateral, yaw) standard deviations for a frame at this pose seeing this many markers."""
        d = max(pose.x, 0.0)
        yaw = self.yaw_three_markers_deg if markers >= 3 else self.yaw_one_marker_deg
        return (
            self.depth_base + self.depth_per_metre * d + self.depth_per_metre3 * d**3,
            self.lateral_base + self.lateral_per_metre * d + self.lateral_per_metre3 * d**3,
            math.radians(yaw + self.yaw_per_metre3_deg * d**3),
        )

    def covariance(self, pose: DockPose, markers: int) -> Matrix:
        """The 3x3 covariance (x m, y m, yaw rad; base_link) of a frame: the sigmas, uncorrelated."""
        return np.diag(np.square(self.sigmas(pose, markers)))


@dataclass(frozen=True)
class OdometryNoise:
    """How wrong wheel odometry is, in the terms of the simulated base (``monodock.sim.diffdrive``).

    Attributes:
        track_width: distance between the wheels, metres (b).
        wheel_scale_sd: per-run relative error of each wheel's ground distance against its encoder.
        scale_correlation: metres over which the per-run scale error is treated as one random-walk step. The
            scale error is a bias, its error growing with the distance d (variance σ_s² d²), which a Kalman
            filter cannot carry in a 3-state model; a random walk of variance σ_s² L d matches it at d = L
            and over-states it below L, where the filter works (frames come every few millimetres driven).
        wheel_noise_sd: per-step relative noise of each wheel's ground speed.
        noise_period: seconds between the per-step noise draws (the simulator's physics step).
        floor_per_metre: unmodelled drift (timing of the frames against odometry, floor unevenness), as the
            standard deviation of each wheel's distance after one metre of random walk.
    """

    track_width: float = setting(0.40, unit="m", positive=True, help="the base's wheel track, for the odometry noise")
    wheel_scale_sd: float = setting(0.005, non_negative=True, help="per-run relative error of a wheel's distance")
    scale_correlation: float = setting(
        1.0, unit="m", positive=True, help="distance over which that error is one random-walk step"
    )
    wheel_noise_sd: float = setting(0.05, non_negative=True, help="per-step relative noise of a wheel's speed")
    noise_period: float = setting(0.005, unit="s", positive=True, help="seconds between those noise draws")
    floor_per_metre: float = setting(
        0.001, unit="m", non_negative=True, help="unmodelled drift per metre driven, per wheel"
    )

    def wheel_variance(self, distance: float, dt: float) -> float:
        """Variance (m²) of one wheel's ground distance after it rolled ``distance`` metres in ``dt`` seconds.

        Per-step noise: n = dt / noise_period independent draws over steps of distance/n each, so its
        variance is σ_n² distance² / n (all of it in one draw when dt is unknown or shorter than a step).
        """
        d = abs(distance)
        draws = max(1.0, dt / self.noise_period) if dt > 0 else 1.0
        return (
            self.wheel_scale_sd**2 * self.scale_correlation + self.floor_per_metre**2
        ) * d + self.wheel_noise_sd**2 * d * d / draws

    def increment_covariance(self, distance: float, rotation: float, dt: float = 0.0) -> Matrix:
        """Σ_e: the 3x3 covariance of the odometry error (x, y, θ in the robot's frame after the step).

        Args:
            distance: signed distance driven along the step's mid heading, metres.
            rotation: angle turned, radians.
            dt: the step's duration, seconds (0: unknown, the conservative single-draw noise).
        """
        b = self.track_width
        left, right = distance - 0.5 * b * rotation, distance + 0.5 * b * rotation
        wheels = np.diag([self.wheel_variance(left, dt), self.wheel_variance(right, dt)])
        J = np.array([[0.5, 0.5], [-1.0 / b, 1.0 / b]])  # (δl, δr) -> (δd, δθ)
        c, s = math.cos(-0.5 * rotation), math.sin(-0.5 * rotation)
        # (δd, δθ) -> e: along the mid heading and, over an arc of length d, d·δθ/2 sideways; in the end frame.
        A = np.array([[c, -s * 0.5 * distance], [s, c * 0.5 * distance], [0.0, 1.0]])
        M = A @ J
        out: Matrix = M @ wheels @ M.T
        return out


@dataclass(frozen=True)
class FilterConfig:
    """The dock filter's odometry noise, outlier gate and reset rule."""

    odometry: OdometryNoise = section(OdometryNoise, help="the odometry noise of the dock filter")
    gate_chi2: float = setting(GATE_CHI2_3DOF, positive=True, help="the dock track's outlier gate (χ², 3 dof)")
    reset_after_rejections: int = setting(8, unit="frames", help="that many gated frames in a row reset the track")


def _frame_rotation(theta: float) -> Matrix:
    """diag(R(θ), 1): rotates an (x, y, angle) error from a frame at heading θ into its parent."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def measurement_model(dock: Pose2D, odom: Pose2D) -> tuple[Matrix, Matrix]:
    """h(s, r) = r⁻¹ ∘ s and its Jacobian ∂h/∂s.

    Args:
        dock: the state s, the dock's pose in the odometry frame.
        odom: r, the robot's odometry pose at the frame's exposure.

    Returns:
        (z, H): the predicted DockPose as an array (x, y, yaw; base_link), shape (3,), and H, shape (3, 3).
    """
    z = dock.relative_to(odom)
    return np.array(z, dtype=np.float64), _frame_rotation(-odom.theta)


def process_jacobian(dock: Pose2D, odom: Pose2D) -> Matrix:
    """G = ∂s'/∂e: how an odometry error e (robot frame at ``odom``) moves the dock's pose in the odometry frame."""
    q = dock.relative_to(odom)
    lever = np.array([[-1.0, 0.0, q.y], [0.0, -1.0, -q.x], [0.0, 0.0, -1.0]])
    out: Matrix = _frame_rotation(odom.theta) @ lever
    return out


def _odom_covariance(odom: Pose2D, covariance: Matrix) -> Matrix:
    """A base_link covariance of the DockPose as the covariance of the dock's pose in the odometry frame."""
    R = _frame_rotation(odom.theta)
    out: Matrix = R @ covariance @ R.T
    return out


class DockFilter:
    """The dock's pose in the odometry frame with its 3x3 covariance; ``mean`` is None until the first frame.

    Attributes:
        mean: the state (X, Y, Θ) or None.
        cov: its covariance, shape (3, 3), (m², m rad, rad²).
        updates: frames folded in since the last reset (seed counts its samples).
        rejected_in_a_row: consecutive frames gated out.
        last_distance: the squared Mahalanobis distance of the last frame offered to ``update``.
    """

    def __init__(self, config: FilterConfig | None = None) -> None:
        self.config = config or FilterConfig()
        self.reset()

    def reset(self) -> None:
        """Forget everything (e.g. before a fresh Calculate)."""
        self.mean: Pose2D | None = None
        self.cov: Matrix = np.zeros((3, 3))
        self.updates = 0
        self.rejected_in_a_row = 0
        self.last_distance = math.nan

    def initialise(self, odom_at_frame: Pose2D, estimate: DockPose, covariance: Matrix) -> None:
        """Start from one frame: the dock where it says, with its covariance carried into the odometry frame."""
        self.reset()
        self.mean = odom_at_frame.compose(Pose2D(estimate.x, estimate.y, estimate.yaw))
        self.cov = _odom_covariance(odom_at_frame, covariance)
        self.updates = 1

    def predict(self, before: Pose2D, after: Pose2D, dt: float = 0.0) -> None:
        """Grow the covariance for the odometry step ``before`` → ``after`` (odometry poses) taking ``dt`` s."""
        if self.mean is None:
            return
        u = after.relative_to(before)
        mid = 0.5 * u.theta
        distance = u.x * math.cos(mid) + u.y * math.sin(mid)
        if distance == 0.0 and u.theta == 0.0:
            return
        sigma_e = self.config.odometry.increment_covariance(distance, u.theta, dt)
        G = process_jacobian(self.mean, after)
        self.cov = _symmetric(self.cov + G @ sigma_e @ G.T)

    def innovation(
        self, odom_at_frame: Pose2D, estimate: DockPose, covariance: Matrix
    ) -> tuple[Matrix, Matrix, Matrix]:
        """(ν, S, H) of a frame: innovation (angle wrapped), its covariance and the measurement Jacobian."""
        assert self.mean is not None
        z_hat, H = measurement_model(self.mean, odom_at_frame)
        nu = np.array([estimate.x, estimate.y, estimate.yaw]) - z_hat
        nu[2] = wrap_angle(float(nu[2]))
        S = H @ self.cov @ H.T + covariance
        return nu, S, H

    def update(self, odom_at_frame: Pose2D, estimate: DockPose, covariance: Matrix) -> bool:
        """Fold in one frame's DockPose, taken with the robot at ``odom_at_frame``; False if gated out.

        Args:
            odom_at_frame: the odometry pose at the frame's exposure.
            estimate: the frame's DockPose (base_link).
            covariance: its 3x3 covariance (x m, y m, yaw rad; base_link).
        """
        if self.mean is None:
            self.initialise(odom_at_frame, estimate, covariance)
            return True
        nu, S, H = self.innovation(odom_at_frame, estimate, covariance)
        S_inv = np.linalg.inv(S)
        self.last_distance = float(nu @ S_inv @ nu)
        if not self.last_distance <= self.config.gate_chi2:  # NaN counts as an outlier
            self.rejected_in_a_row += 1
            if self.rejected_in_a_row >= self.config.reset_after_rejections:
                self.initialise(odom_at_frame, estimate, covariance)
                return True
            return False
        self.rejected_in_a_row = 0
        K = self.cov @ H.T @ S_inv
        step = K @ nu
        self.mean = Pose2D(
            self.mean.x + float(step[0]), self.mean.y + float(step[1]), wrap_angle(self.mean.theta + float(step[2]))
        )
        # Joseph form: stays symmetric positive definite whatever the rounding.
        I_KH = np.eye(3) - K @ H
        self.cov = _symmetric(I_KH @ self.cov @ I_KH.T + K @ covariance @ K.T)
        self.updates += 1
        return True

    def seed(self, samples: Sequence[tuple[Pose2D, DockPose, Matrix]]) -> None:
        """Start from several frames taken standing still: the median of each component.

        ``samples`` are (odometry pose at the frame, the frame's DockPose, its 3x3 covariance). The median
        keeps one wild frame (a marker seen small and alone can give a heading tens of degrees off) out of
        the plan; it is about as good as the mean of 2n/π frames, hence the covariance.
        """
        if not samples:
            raise ValueError("seed needs at least one frame")
        measured = [odom.compose(Pose2D(e.x, e.y, e.yaw)) for odom, e, _ in samples]
        ref = measured[0].theta
        theta = wrap_angle(ref + float(np.median([wrap_angle(m.theta - ref) for m in measured])))
        mean_cov = np.mean([_odom_covariance(odom, c) for odom, _, c in samples], axis=0)
        self.reset()
        self.mean = Pose2D(float(np.median([m.x for m in measured])), float(np.median([m.y for m in measured])), theta)
        self.cov = _symmetric(mean_cov * (math.pi / (2 * len(samples))))
        self.updates = len(samples)

    def robot_in_dock(self, odom: Pose2D) -> Pose2D:
        """The robot's pose in the dock frame, from its odometry pose and the filtered dock."""
        assert self.mean is not None
        return odom.relative_to(self.mean)

    def dock_pose(self, odom: Pose2D) -> tuple[DockPose, Matrix]:
        """The filtered DockPose of a robot at odometry pose ``odom``, and its 3x3 covariance in base_link."""
        assert self.mean is not None
        z, H = measurement_model(self.mean, odom)
        cov: Matrix = H @ self.cov @ H.T
        return DockPose(float(z[0]), float(z[1]), float(z[2])), cov

    @property
    def sigma_yaw_deg(self) -> float:
        return math.degrees(math.sqrt(max(float(self.cov[2, 2]), 0.0)))


def _symmetric(a: Matrix) -> Matrix:
    out: Matrix = 0.5 * (a + a.T)
    return out
