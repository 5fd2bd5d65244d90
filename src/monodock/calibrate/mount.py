"""The camera mount from a short drive in front of the dock: hand-eye calibration for planar motion.

The robot drives and turns for about a minute with the dock in view, recording its camera and its wheel
odometry (``nav_msgs/Odometry``). Every frame sees the dock from where the robot stood; the odometry says how
the robot moved between frames. The camera mount (base_link → camera) is what makes the two agree: turning in
place moves a camera that sits off the turning axis, and the camera's tilt shows in how the dock's image turns.

One least-squares problem holds it all (a pose graph with the camera in it), robust like the survey:

- unknowns: the mount (x, y, z, roll, pitch, yaw), the dock's lean against the floor (roll, pitch: a layout
  surveyed without robot views does not know which way is up), the layout's scale against the odometry, two
  odometry errors (a rotation scale: the track width's error; a heading drift per metre: unequal wheels), and
  base_link's pose on the floor at every used frame;
- residuals: every refined corner of every used frame, through the mount and the layout; and the odometry's
  motion between consecutive frames, corrected by the two errors and weighted by a random-walk model whose scale
  is re-estimated from the fit (a cheap base's odometry drifts by a degree over a minute; a fit that trusted it
  rigidly would put that drift into the mount).

What a drive on a flat floor cannot tell: the camera's height (every pose has the same one) is measured against
the layout's marker heights: only their difference is seen, so ``z`` is as right as the layout's heights. And
lengths: the camera measures in the print's units, the wheels in theirs, and only their ratio is seen (the
odometry's distance scale, fitted). Either is the ruler (``scale_from``): ``print`` keeps the layout's lengths
(the kit's 10 cm bar checked the printer) and reports how far the odometry is off; ``odometry`` believes the
wheels and scales the layout and the mount to them (as true as the wheels' radius). The rest is excited by
turning (x, y, yaw) at several places and headings (roll, pitch, the dock's lean) and by driving towards and away
from the dock (the scale); the result gives each one's standard deviation and says what to drive more when one
is too uncertain.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from monodock.calibrate.survey_views import survey_views
from monodock.core import transforms
from monodock.core.camera import CameraModel
from monodock.core.frame import Frame
from monodock.core.layout import FACE_R_MARKER, ROLES, DockLayout, MarkerSpec
from monodock.core.robot import Mount, OdometryCalibration, RobotConfig
from monodock.errors import InputError
from monodock.perception.edge_offset import EdgeOffset
from monodock.recording.read import Recording, open_recording

__all__ = [
    "MOUNT_FIELDS",
    "Drive",
    "DriveFrame",
    "MountCalibration",
    "MountLimits",
    "calibrate_mount",
    "calibrate_mount_of",
    "camera_and_odometry",
    "corrected_layout",
    "frames_from_recording",
    "odometry_at",
]

MOUNT_FIELDS = ("x", "y", "z", "roll", "pitch", "yaw")
# The global unknowns, in the parameter vector's order.
_GLOBALS = (*MOUNT_FIELDS, "dock_roll", "dock_pitch", "log_odometry_scale", "rotation_scale", "drift_per_m")
_NG = len(_GLOBALS)
# Every residual is whitened (divided by its standard deviation); the soft-L1 loss counts those within this many
# standard deviations as squares and beyond it as their distance.
LOSS_SCALE_SD = 3.0
# The corners' noise, px, before the fit estimates it.
_CORNER_SD_PX = 0.2
MIN_FRAMES = 30
MAX_FRAMES = 400
# The odometry's random walk, before the fit rescales it: metres and radians per square-root metre of travel
# (and per radian turned, times _TURN_METRES), and floors for the shortest steps.
_ODOM_SD = (0.002, math.radians(0.3))
_ODOM_FLOOR = (0.0003, math.radians(0.02))
_TURN_METRES = 0.2


@dataclass(frozen=True)
class MountLimits:
    """How uncertain (one standard deviation) a calibrated value may be before it is reported as not excited."""

    position_sd: float = 0.0015
    angle_sd: float = math.radians(0.1)
    scale_sd: float = 0.002


@dataclass(frozen=True)
class DriveFrame:
    """One used frame of the drive: its stamp, the refined corners of its markers (4, 2) px, and base_link's
    odometry pose (x, y, yaw) at the stamp."""

    stamp: float
    corners: dict[str, NDArray[np.float64]]
    odometry: tuple[float, float, float]


@dataclass(frozen=True)
class MountCalibration:
    """The calibrated mount and what else the drive measured, each with its standard deviation.

    Attributes:
        mount: the camera body's (camera_link's) pose in base_link.
        prior: the nominal mount the fit started from.
        sd: standard deviation of every solved value (``_GLOBALS`` names: mount fields, dock_roll, dock_pitch,
            log_odometry_scale, rotation_scale, drift_per_m), metres and radians.
        dock_roll, dock_pitch: the dock's lean against the floor, as the layout defines its up, radians.
        odometry_scale: the print's lengths per odometry length (1.007: the wheels report 0.7 % short, or the print
            is 0.7 % small).
        scale: what ``layout`` scales the layout by: 1 with ``scale_from="print"``, 1 / odometry_scale with
            ``"odometry"`` (the mount is scaled so already).
        rotation_scale: the odometry's turning error (true turn = (1 + this) x the odometry's, plus the drift).
        drift_per_m: the odometry's heading error per metre driven, radians per metre.
        rms_px: RMS reprojection error over the used corners.
        frames: frames used, of ``seen`` with two or more markers.
        path: base_link's fitted (x, y, yaw) at each used frame, in the dock's floor frame (for plots).
        residuals_px: each used frame's RMS reprojection error.
        unexcited: the values the drive left more uncertain than the limits, and what to drive to excite them.
        notes: what a user should know (the height's and the scale's source).
    """

    mount: Mount
    prior: Mount
    sd: dict[str, float]
    dock_roll: float
    dock_pitch: float
    odometry_scale: float
    scale: float
    rotation_scale: float
    drift_per_m: float
    rms_px: float
    frames: int
    seen: int
    path: NDArray[np.float64] = field(repr=False)
    residuals_px: NDArray[np.float64] = field(repr=False)
    unexcited: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()
    edge_offset: EdgeOffset | None = None

    def robot(self, nominal: RobotConfig) -> RobotConfig:
        """The robot file with the calibrated camera mount and odometry (everything else as given)."""
        return replace(nominal, camera_mount=self.mount, odometry=self.odometry)

    @property
    def odometry(self) -> OdometryCalibration:
        """The odometry's errors in the ruler's lengths (the print's, or with ``scale_from="odometry"`` its own)."""
        distance = self.odometry_scale * self.scale
        return OdometryCalibration(distance, self.rotation_scale, self.drift_per_m * self.odometry_scale / distance)

    def layout(self, layout: DockLayout) -> DockLayout:
        """The layout as the drive measured it: stood up on the floor (its markers turned by the dock's lean, then
        the origin set below the centre marker again), scaled to the odometry with ``scale_from="odometry"``, and
        with the edge offset of the robot's camera when the drive measured it."""
        out = corrected_layout(layout, self.scale, self.dock_roll, self.dock_pitch)
        # The robot's own camera on this print: its edge offset is the one every frame will have.
        return out if self.edge_offset is None else replace(out, edge_offset=self.edge_offset.offset_px)

    def summary(self) -> str:
        m, sd = self.mount, self.sd
        lines = [
            f"camera mount from {self.frames} frames ({self.seen} with two or more markers), RMS {self.rms_px:.3f} px",
            f"  x {m.x * 1e3:+8.2f} ±{sd['x'] * 1e3:.2f} mm  y {m.y * 1e3:+8.2f} ±{sd['y'] * 1e3:.2f} mm  "
            f"z {m.z * 1e3:+8.2f} ±{sd['z'] * 1e3:.2f} mm",
            f"  roll {math.degrees(m.roll):+.3f} ±{math.degrees(sd['roll']):.3f}  pitch {math.degrees(m.pitch):+.3f} "
            f"±{math.degrees(sd['pitch']):.3f}  yaw {math.degrees(m.yaw):+.3f} ±{math.degrees(sd['yaw']):.3f} deg",
            f"  change from the nominal: x {(m.x - self.prior.x) * 1e3:+.1f} y {(m.y - self.prior.y) * 1e3:+.1f} "
            f"z {(m.z - self.prior.z) * 1e3:+.1f} mm, roll {math.degrees(m.roll - self.prior.roll):+.2f} pitch "
            f"{math.degrees(m.pitch - self.prior.pitch):+.2f} yaw {math.degrees(m.yaw - self.prior.yaw):+.2f} deg",
            f"  dock lean: roll {math.degrees(self.dock_roll):+.3f} ±{math.degrees(sd['dock_roll']):.3f}, pitch "
            f"{math.degrees(self.dock_pitch):+.3f} ±{math.degrees(sd['dock_pitch']):.3f} deg",
            f"  odometry: distances x{self.odometry_scale:.5f} ±{sd['log_odometry_scale'] * self.odometry_scale:.5f} "
            f"(the print's lengths per odometry length), turns x{1 + self.rotation_scale:.5f} "
            f"±{sd['rotation_scale']:.5f}, heading drift {math.degrees(self.drift_per_m):+.3f} "
            f"±{math.degrees(self.sd['drift_per_m']):.3f} deg/m",
        ]
        lines += [f"  not excited: {u}" for u in self.unexcited]
        lines += [f"  {n}" for n in self.notes]
        return "\n".join(lines)


def corrected_layout(layout: DockLayout, scale: float, roll: float, pitch: float) -> DockLayout:
    """The layout scaled by ``scale`` about the dock's origin and turned by the dock's lean (roll, pitch) on the
    floor, then given its origin below the centre marker's centre again."""
    R = transforms.rotation_from_rpy(roll, pitch, 0.0)
    poses = {}
    for r in layout.roles:
        T = layout.dock_T_marker(r)
        T[:3, 3] *= scale
        poses[r] = transforms.transform(R, np.zeros(3)) @ T
    c = poses["center"][:3, 3]
    shift = np.array([c[0], c[1], 0.0])
    specs = []
    for r in layout.roles:
        T = poses[r]
        p = T[:3, 3] - shift
        tilt = transforms.rpy_from_rotation(T[:3, :3] @ FACE_R_MARKER.T)
        m = layout.marker(r)
        specs.append(MarkerSpec(r, m.id, float(p[1]), float(p[2]), float(p[0]), *tilt, size=layout.side(r) * scale))
    return replace(layout, markers=tuple(specs))


# --- the odometry --------------------------------------------------------------------------------------------


def odometry_at(odometry: NDArray[np.float64], stamps: Sequence[float]) -> NDArray[np.float64]:
    """base_link's odometry pose (x, y, yaw) at each stamp, linearly interpolated (yaw unwrapped), (N, 3); NaN
    outside the odometry's time span."""
    t = odometry[:, 0]
    yaw = np.unwrap(odometry[:, 3])
    s = np.asarray(stamps, dtype=np.float64)
    out = np.column_stack([np.interp(s, t, odometry[:, 1]), np.interp(s, t, odometry[:, 2]), np.interp(s, t, yaw)])
    out[(s < t[0]) | (s > t[-1])] = np.nan
    return out


@dataclass
class _Odometry:
    """The drive's odometry: its poses, and the travel (metres, a radian turned counting ``_TURN_METRES``) that its
    random walk grows with."""

    raw: NDArray[np.float64]

    def __post_init__(self) -> None:
        self.t = self.raw[:, 0]
        self.poses = self.raw[:, 1:4].copy()
        self.poses[:, 2] = np.unwrap(self.poses[:, 2])
        step = np.hypot(np.diff(self.poses[:, 0]), np.diff(self.poses[:, 1])) + _TURN_METRES * np.abs(
            np.diff(self.poses[:, 2])
        )
        self.travel = np.concatenate([[0.0], np.cumsum(step)])

    def corrected(self, distance_scale: float, rotation_scale: float, drift: float) -> NDArray[np.float64]:
        """Every sample's pose re-integrated under the three errors (Censi et al.'s wheel radii and track width, as a
        body's distance scale, turn scale and heading drift per metre)."""
        return OdometryCalibration(distance_scale, rotation_scale, drift).corrected(self.poses)

    def at(self, poses: NDArray[np.float64], stamps: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.column_stack([np.interp(stamps, self.t, poses[:, k]) for k in range(3)])


# --- the problem ---------------------------------------------------------------------------------------------


class _Problem:
    def __init__(
        self,
        frames: Sequence[DriveFrame],
        odometry: NDArray[np.float64],
        camera: CameraModel,
        layout: DockLayout,
        prior: Mount,
    ) -> None:
        self.frames, self.camera, self.layout, self.prior = frames, camera, layout, prior
        self.odo = _Odometry(odometry)
        self.stamps = np.array([f.stamp for f in frames])
        self.travel = np.interp(self.stamps, self.odo.t, self.odo.travel)
        self.K, self.dist = camera.matrix, camera.dist
        pts, owner, obs = [], [], []
        for k, f in enumerate(frames):
            for r, c in f.corners.items():
                pts.append(layout.corners_in_dock(r))
                owner += [k] * 4
                obs.append(c)
        self.points = np.concatenate(pts)
        self.owner = np.asarray(owner)
        self.observed = np.concatenate(obs)
        self.n = _NG + 3 * len(frames)
        self.odom_sd = np.array([_ODOM_SD[0], _ODOM_SD[0], _ODOM_SD[1]])
        self.corner_sd = _CORNER_SD_PX

    def start(self, poses: NDArray[np.float64]) -> NDArray[np.float64]:
        p = np.zeros(self.n)
        p[:6] = [getattr(self.prior, k) for k in MOUNT_FIELDS]
        p[_NG:] = poses.ravel()
        return p

    def _optical_T_base(self, g: NDArray[np.float64]) -> NDArray[np.float64]:
        mount = Mount(*(float(v) for v in g[:6]))
        T = mount.matrix()
        T[:3, :3] = T[:3, :3] @ transforms.LINK_R_OPTICAL
        return transforms.invert(T)

    def vision(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        g = p[:_NG]
        poses = p[_NG:].reshape(-1, 3)
        R_lean = transforms.rotation_from_rpy(g[6], g[7], 0.0)
        P_F = self.points @ R_lean.T  # the dock's points in the floor frame
        q = poses[self.owner]
        c, s = np.cos(q[:, 2]), np.sin(q[:, 2])
        dx, dy = P_F[:, 0] - q[:, 0], P_F[:, 1] - q[:, 1]
        P_base = np.column_stack([c * dx + s * dy, -s * dx + c * dy, P_F[:, 2]])
        T = self._optical_T_base(g)
        P_cam = P_base @ T[:3, :3].T + T[:3, 3]
        if np.any(P_cam[:, 2] <= 1e-3):
            return np.full(self.observed.size, 1e3)
        px, _ = cv2.projectPoints(P_cam, np.zeros(3), np.zeros(3), self.K, self.dist)
        return (np.asarray(px).reshape(-1, 2) - self.observed).ravel() / self.corner_sd

    def motion(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        """The frames' poses' motion between consecutive frames against the corrected odometry's, whitened."""
        g = p[:_NG]
        poses = p[_NG:].reshape(-1, 3)
        odom = self.odo.at(self.odo.corrected(math.exp(g[8]), g[9], g[10]), self.stamps)
        return np.asarray((_relative(poses) - _relative(odom)) / self._odom_sigma(), dtype=np.float64)

    def _odom_sigma(self) -> NDArray[np.float64]:
        """The odometry's standard deviation between consecutive frames: a random walk in the travel between them."""
        root = np.sqrt(np.maximum(np.diff(self.travel), 0.0))[:, None]
        return np.asarray(root * self.odom_sd + np.array([_ODOM_FLOOR[0], _ODOM_FLOOR[0], _ODOM_FLOOR[1]]))

    def residuals(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.concatenate([self.vision(p), self.motion(p).ravel()])

    def sparsity(self) -> Any:
        nv = self.observed.size
        nf = len(self.frames)
        S = lil_matrix((nv + 3 * (nf - 1), self.n), dtype=np.int8)
        S[:nv, :8] = 1
        rows = np.arange(nv)
        frame_of_row = self.owner[rows // 2]
        for j in range(3):
            S[rows, _NG + 3 * frame_of_row + j] = 1
        for k in range(nf - 1):
            r = nv + 3 * k
            S[r : r + 3, 8:_NG] = 1
            S[r : r + 3, _NG + 3 * k : _NG + 3 * k + 6] = 1
        return S


def _relative(poses: NDArray[np.float64]) -> NDArray[np.float64]:
    """Consecutive poses' motion (dx, dy in the first's frame, dyaw), (N - 1, 3)."""
    d = np.diff(poses, axis=0)
    c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]]).astype(np.float64)


def _start_poses(
    frames: Sequence[DriveFrame], camera: CameraModel, layout: DockLayout, prior: Mount
) -> NDArray[np.float64]:
    """base_link's pose in the dock frame at each frame, from board PnP through the nominal mount; a frame whose
    PnP fails takes its neighbour's through the odometry."""
    robot = replace(RobotConfig.default(), camera_mount=prior)
    out = np.full((len(frames), 3), np.nan)
    for k, f in enumerate(frames):
        roles = [r for r in ROLES if r in f.corners]
        obj = np.concatenate([layout.corners_in_dock(r) for r in roles])
        img = np.concatenate([f.corners[r] for r in roles])
        # SQPNP: a surveyed dock's markers are not exactly in one plane, which IPPE needs.
        n, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, camera.matrix, camera.dist, flags=cv2.SOLVEPNP_SQPNP)
        if not n:
            continue
        best = int(np.argmin(np.asarray(errs).ravel()))
        optical_T_dock = transforms.transform(cv2.Rodrigues(rvecs[best])[0], np.asarray(tvecs[best]).ravel())
        dock_T_base = transforms.invert(robot.base_T_optical() @ optical_T_dock)
        out[k] = (dock_T_base[0, 3], dock_T_base[1, 3], transforms.yaw_of(dock_T_base))
    bad = ~np.all(np.isfinite(out), axis=1)
    if bad.all():
        raise InputError("no frame of the drive gives a camera pose: check the camera and the layout")
    if bad.any():
        good = np.flatnonzero(~bad)
        for k in np.flatnonzero(bad).tolist():
            out[k] = out[good[int(np.argmin(np.abs(good - k)))]]
    out[:, 2] = np.unwrap(out[:, 2])
    return out


def _solve(problem: _Problem, p0: NDArray[np.float64]) -> Any:
    return least_squares(
        problem.residuals,
        p0,
        jac_sparsity=problem.sparsity(),
        loss="soft_l1",
        f_scale=LOSS_SCALE_SD,
        method="trf",
        x_scale="jac",
        tr_solver="lsmr",
        tr_options={"atol": 1e-14, "btol": 1e-14},  # lsmr's default tolerances leave trf crawling, far from done
        xtol=1e-10,
        ftol=1e-10,
        gtol=1e-10,
        max_nfev=100,
    )


def _variance_factors(result: Any, problem: _Problem) -> NDArray[np.float64]:
    """How much larger each group's variance is than assumed: corners, then the odometry's x, y and yaw (Förstner's
    variance component estimate: a group's weighted residual sum over its redundancy, the rows' count less the share
    of the unknowns they determine, tr(N⁻¹ J_gᵀ J_g)). The robust loss's weights are in scipy's Jacobian; the
    residuals get the same."""
    J = result.jac.tocsr()
    f = result.fun
    z = (f / LOSS_SCALE_SD) ** 2
    w = (1.0 + z) ** -0.25  # sqrt of soft-L1's rho'(z)
    r = f * w
    N_inv = np.linalg.pinv(np.asarray((J.T @ J).todense()), rcond=1e-14, hermitian=True)
    nv = problem.observed.size
    groups = [np.arange(nv)] + [nv + np.arange(j, f.size - nv, 3) for j in range(3)]
    out = []
    for rows in groups:
        Jg = J[rows]
        share = float(np.sum(N_inv * np.asarray((Jg.T @ Jg).todense())))
        redundancy = max(len(rows) - share, 1.0)
        out.append(float(r[rows] @ r[rows]) / redundancy)
    return np.asarray(np.maximum(np.array(out), 1e-4), dtype=np.float64)


def _global_covariance(result: Any) -> NDArray[np.float64]:
    """The globals' covariance: the residuals' scale times the globals' block of (JᵀJ)⁻¹ (the frames' poses
    marginalised)."""
    J = result.jac.tocsc() if hasattr(result.jac, "tocsc") else result.jac
    A = np.asarray((J.T @ J).todense() if hasattr(J, "todense") else J.T @ J)
    m, n = result.fun.size, result.x.size
    s2 = 2.0 * float(result.cost) / max(m - n, 1)
    cov = np.linalg.pinv(A, rcond=1e-14, hermitian=True)
    return np.asarray(s2 * cov[:_NG, :_NG], dtype=np.float64)


def calibrate_mount(
    frames: Sequence[DriveFrame],
    odometry: NDArray[np.float64],
    camera: CameraModel,
    layout: DockLayout,
    nominal: RobotConfig,
    *,
    scale_from: str = "print",
    limits: MountLimits | None = None,
    seen: int | None = None,
    edge_offset: EdgeOffset | None = None,
) -> MountCalibration:
    """The camera mount that makes the frames agree with the odometry, and the dock's lean and scale.

    Args:
        frames: the drive's frames with two or more markers (their odometry poses filled in), in stamp order.
        odometry: every odometry pose of the drive, rows (stamp, x, y, yaw), stamp order.
        camera: the camera's intrinsics.
        layout: the dock's layout (a surveyed one: ``calibrate layout``).
        nominal: the robot file whose camera mount is the start (and whose other fields are kept).
        scale_from: the ruler: "print" (the layout's lengths) or "odometry" (the wheels': the layout and the mount
            scaled to them).
        limits: what counts as not excited.
        seen: how many frames had two or more markers before any were thinned out (for the summary).
        edge_offset: the offset the drive's images measured (its frames are corrected already), for the layout.

    Raises:
        InputError: too few frames, or no odometry over them.
    """
    limits = limits or MountLimits()
    if scale_from not in ("print", "odometry"):
        raise InputError(f"scale_from must be 'print' or 'odometry', got {scale_from!r}")
    if len(frames) < MIN_FRAMES:
        raise InputError(
            f"{len(frames)} frames of the drive show two or more dock markers; the mount needs at least {MIN_FRAMES} "
            "(drive and turn for about a minute with the dock in view)"
        )
    if odometry.shape[0] < 2:
        raise InputError("the drive has no odometry (nav_msgs/Odometry): record the robot's odom topic too")
    prior = nominal.camera_mount
    problem = _Problem(frames, odometry, camera, layout, prior)
    p = problem.start(_start_poses(frames, camera, layout, prior))
    result = None
    for _ in range(5):  # the corners' and the odometry's noise re-estimated from the fit (variance components)
        result = _solve(problem, p)
        p = result.x
        factors = _variance_factors(result, problem)
        problem.corner_sd *= math.sqrt(factors[0])
        problem.odom_sd = problem.odom_sd * np.sqrt(factors[1:])
        if np.all(np.abs(factors - 1.0) < 0.15):
            break
    assert result is not None
    cov = _global_covariance(result)
    sd = dict(zip(_GLOBALS, np.sqrt(np.maximum(np.diag(cov), 0.0)).tolist(), strict=True))
    g = p[:_NG]
    vision = problem.vision(p).reshape(-1, 2) * problem.corner_sd
    per_frame = np.array(
        [np.sqrt(np.mean(np.sum(vision[problem.owner == k] ** 2, axis=1))) for k in range(len(frames))]
    )
    odometry_scale = math.exp(float(g[8]))
    scale = 1.0 / odometry_scale if scale_from == "odometry" else 1.0
    mount = Mount(*(float(v) * (scale if k < 3 else 1.0) for k, v in enumerate(g[:6])))
    for k in ("x", "y", "z"):
        sd[k] *= scale
    return MountCalibration(
        mount=mount,
        prior=prior,
        sd=sd,
        dock_roll=float(g[6]),
        dock_pitch=float(g[7]),
        odometry_scale=odometry_scale,
        scale=scale,
        rotation_scale=float(g[9]),
        drift_per_m=float(g[10]),
        rms_px=float(np.sqrt(np.mean(np.sum(vision**2, axis=1)))),
        frames=len(frames),
        seen=seen if seen is not None else len(frames),
        path=p[_NG:].reshape(-1, 3).copy(),
        residuals_px=per_frame,
        unexcited=_unexcited(sd, limits),
        edge_offset=edge_offset,
        notes=(
            f"z from the layout's heights (the centre marker at {layout.marker('center').z * 1e3:.1f} mm): a drive "
            "on a flat floor cannot measure the camera's height, only its height against the markers'",
            "lengths from the odometry (as true as the wheels' radius): the layout and the mount scaled to it"
            if scale_from == "odometry"
            else "lengths from the print (the kit's scale bar): the odometry's distance error is reported",
        ),
    )


def _unexcited(sd: dict[str, float], limits: MountLimits) -> tuple[str, ...]:
    out = []
    for k, advice in (
        ("x", "turn in place at more places"),
        ("y", "turn in place at more places"),
        ("yaw", "turn in place at more places, and drive sideways across the dock's front"),
    ):
        if sd[k] > (limits.angle_sd if k == "yaw" else limits.position_sd):
            out.append(f"{k} (sd {_shown(k, sd[k])}): {advice}")
    for k in ("roll", "pitch", "dock_roll", "dock_pitch"):
        if sd[k] > limits.angle_sd:
            out.append(f"{k} (sd {_shown(k, sd[k])}): face the dock from more headings (turn further each way)")
    if sd["log_odometry_scale"] > limits.scale_sd:
        out.append(f"scale (sd {sd['log_odometry_scale'] * 100:.2f} %): drive towards and away from the dock")
    return tuple(out)


def _shown(key: str, value: float) -> str:
    return f"{value * 1e3:.2f} mm" if key in ("x", "y", "z") else f"{math.degrees(value):.3f} deg"


@dataclass(frozen=True)
class Drive:
    """A commissioning drive as read: its usable frames, its odometry, the camera, how many frames showed two or
    more markers, and the edge offset its images measure (the robot's camera on this print; None: too small)."""

    frames: list[DriveFrame]
    odometry: NDArray[np.float64] = field(repr=False)
    camera: CameraModel
    seen: int
    edge_offset: EdgeOffset | None = None


def camera_and_odometry(
    rec: Recording, path: str, camera: CameraModel | None
) -> tuple[CameraModel, NDArray[np.float64]]:
    """A drive's camera (``camera``, else the recording's CameraInfo) and its odometry (two samples or more), or
    the one-line InputError that says what the recording lacks."""
    cam = camera or rec.camera()
    if cam is None:
        raise InputError(f"{path} has no CameraInfo: give --camera")
    odometry = rec.odometry()
    if odometry.shape[0] < 2:
        raise InputError(f"{path} has no odometry (nav_msgs/Odometry): record the robot's odom topic too")
    return cam, odometry


def frames_from_recording(
    path: str, layout: DockLayout, *, camera: CameraModel | None = None, image_topic: str | None = None
) -> Drive:
    """The drive's usable frames (two or more refined markers, corrected by the edge offset the drive measures,
    within the odometry's span), its odometry and the camera (``camera``, else the recording's CameraInfo).

    More than ``MAX_FRAMES`` usable frames are thinned evenly: neighbours a fifteenth of a second apart add little.
    """
    with open_recording(path, image_topic=image_topic) as rec:
        cam, odometry = camera_and_odometry(rec, path, camera)
        stamps: dict[str, float] = {}

        def stamped() -> Iterator[Frame]:
            for frame in rec.images():
                stamps[frame.name] = frame.stamp
                yield frame

        views, _, offset = survey_views(stamped(), cam, layout)
    found = [(stamps[v.name], dict(v.corners)) for v in views if len(v.corners) >= 2]
    seen = len(found)
    inside = [(s, c) for s, c in found if odometry[0, 0] <= s <= odometry[-1, 0]]
    if len(inside) > MAX_FRAMES:
        keep = np.unique(np.linspace(0, len(inside) - 1, MAX_FRAMES).round().astype(int))
        inside = [inside[k] for k in keep]
    poses = odometry_at(odometry, [s for s, _ in inside]) if inside else np.zeros((0, 3))
    frames = [
        DriveFrame(s, c, (float(q[0]), float(q[1]), float(q[2]))) for (s, c), q in zip(inside, poses, strict=True)
    ]
    return Drive(frames, odometry, cam, seen, offset)


def calibrate_mount_of(
    drive: Drive,
    layout: DockLayout,
    nominal: RobotConfig,
    *,
    scale_from: str = "print",
    limits: MountLimits | None = None,
) -> MountCalibration:
    """``calibrate_mount`` on a drive as ``frames_from_recording`` read it."""
    return calibrate_mount(
        drive.frames, drive.odometry, drive.camera, layout, nominal, scale_from=scale_from, limits=limits,
        seen=drive.seen, edge_offset=drive.edge_offset,
    )  # fmt: skip
