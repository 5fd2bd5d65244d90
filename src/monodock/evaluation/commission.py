"""Commissioning in a wrong world, measured against the simulator's truth.

One world (``sim.wrong_world``): a dock built with realistic errors and a robot whose camera sits off its drawing
and whose contacts sit off its ``front_offset``. The user has only the nominal files. ``commission_world`` does what
the user would: photographs the dock (handheld survey views), drives a minute before it, backs off the contacts,
and runs the three steps (``calibrate.commission``'s, on the files they write). Then it measures, on fresh frames
of that world and on closed-loop dockings in it:

- the survey: each marker's pose relative to the centre marker's (the survey's gauge) and its side, against the
  world's, with and without the print's overall scale (which images cannot see);
- the mount: each field against the world's, the height as the camera's height over the centre marker's (what a
  drive on a flat floor can measure);
- the estimates, by 25 cm band of depth from the camera, for the fused method (geometry alone: no LiDAR, no
  bundle) and board PnP, with four sets of files: the nominal ones, the commissioned ones, the world's exact ones,
  and the commissioned layout alone (``layout``: the survey's, leaned by the drive, at the world's print scale and
  centre height, with the world's true robot), which parts the layout's error from the ruler's and the mount's;
- docking: the mission with the nominal and with the commissioned files (the taught charging pose included):
  docked, charging at the first seat, and the final error against the physical contacts.

Commissioned estimates are compared in the frame the mission docks in (the taught charging frame), placed in the
world by where the robot truly stood when it was taught; the layout alone in its own dock frame (the face as its
markers show it), placed in the world by its markers; nominal and exact ones in the dock frame.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.stats import binomtest

from monodock.calibrate.mount import calibrate_mount_of, frames_from_recording
from monodock.calibrate.survey import survey_layout
from monodock.calibrate.survey_views import survey_views
from monodock.calibrate.teach import teach_from_recording
from monodock.core import transforms
from monodock.core.frame import Frame
from monodock.core.layout import ROLES, DockLayout
from monodock.core.pose import wrap_angle
from monodock.core.pose2d import Pose2D
from monodock.core.robot import RobotConfig
from monodock.dock.config import ChargingOffset, DockingConfig
from monodock.estimation.factory import make_estimator
from monodock.evaluation.dock_sim import DockSimConfig, run_dock_sim
from monodock.sim.continuous import commissioning_route, record_drive, teach_route, teach_start
from monodock.sim.diffdrive import SimulatedRobot
from monodock.sim.simulator import PoseDistribution, Simulator
from monodock.sim.survey_views import handheld_poses, render_shot
from monodock.sim.wrong_world import WrongWorld, wrong_world

__all__ = [
    "ACCURACY_METHODS",
    "BAND_EDGES_M",
    "FILE_SETS",
    "CommissioningSummary",
    "DockingOutcome",
    "WorldResult",
    "commission_world",
    "summarize_worlds",
    "wilson",
]

FILE_SETS = ("nominal", "commissioned", "layout", "exact")
DOCKING_VARIANTS = ("nominal/board", "commissioned/fused")
ACCURACY_METHODS = ("fused", "board")
BAND_EDGES_M = tuple(0.25 + 0.25 * k for k in range(10))


@dataclass(frozen=True)
class DockingOutcome:
    """One docking run in a world: docked by the mission, charging at the first seat, the final error."""

    docked: bool
    charged_first_seat: bool
    charged: bool
    lateral_mm: float
    gap_mm: float
    heading_deg: float
    reseats: int


@dataclass(frozen=True)
class WorldResult:
    """Everything measured in one world.

    Attributes:
        seed: the world's.
        marker_position_mm, marker_angle_deg, marker_side_mm: per non-centre role, the surveyed pose relative to the
            centre marker against the truth's: the position error (3,), the angle between the orientations, and
            per role (centre included) the side's error.
        marker_position_scaled_mm: the same position error once the print's overall scale is divided out.
        print_scale: the survey's lengths per true length (the print's mean scale, which images cannot see).
        mount_error: per mount field, calibrated minus true (m, rad); ``z`` as the camera's height over the centre
            marker's.
        teach_error: the taught charging pose, through the markers into the world's frame, minus where the robot
            truly stood (x, y m, yaw rad).
        errors: per file set and method, per frame: depth from the camera (m), then the x, y (m) and yaw (rad)
            errors, (N, 4).
        docking: per files and method (``DOCKING_VARIANTS``), the runs.
        odometry_scale: the drive's fitted print-per-odometry length, and the truth's.
        mount_sd: per mount field, the standard deviation the calibration states (m, rad): with ``mount_error``,
            whether its stated uncertainty is honest.
    """

    seed: int
    marker_position_mm: dict[str, tuple[float, float, float]]
    marker_position_scaled_mm: dict[str, tuple[float, float, float]]
    marker_angle_deg: dict[str, float]
    marker_side_mm: dict[str, float]
    print_scale: float
    mount_error: dict[str, float]
    teach_error: tuple[float, float, float]
    errors: dict[str, dict[str, NDArray[np.float64]]] = field(repr=False)
    docking: dict[str, list[DockingOutcome]] = field(default_factory=dict)
    odometry_scale: tuple[float, float] = (math.nan, math.nan)
    mount_sd: dict[str, float] = field(default_factory=dict)


def _relative(layout: DockLayout, role: str) -> NDArray[np.float64]:
    return transforms.invert(layout.dock_T_marker("center")) @ layout.dock_T_marker(role)


def _angle_deg(A: NDArray[np.float64], B: NDArray[np.float64]) -> float:
    c = (np.trace(A[:3, :3].T @ B[:3, :3]) - 1.0) / 2.0
    return math.degrees(math.acos(float(np.clip(c, -1.0, 1.0))))


def _survey_errors(surveyed: DockLayout, truth: DockLayout) -> tuple[dict[str, object], float]:
    """The survey's errors against the truth's, relative to the centre marker; and the print's overall scale."""
    scale = math.exp(np.mean([math.log(surveyed.side(r) / truth.side(r)) for r in ROLES]))
    pos, scaled, ang = {}, {}, {}
    for r in ROLES:
        if r == "center":
            continue
        A, B = _relative(surveyed, r), _relative(truth, r)
        d = (A[:3, 3] - B[:3, 3]) * 1e3
        pos[r] = (float(d[0]), float(d[1]), float(d[2]))
        ds = (A[:3, 3] / scale - B[:3, 3]) * 1e3
        scaled[r] = (float(ds[0]), float(ds[1]), float(ds[2]))
        ang[r] = _angle_deg(A, B)
    sides = {r: (surveyed.side(r) - truth.side(r)) * 1e3 for r in ROLES}
    return {"position": pos, "scaled": scaled, "angle": ang, "side": sides}, float(scale)


def _frame_of(layout: DockLayout, truth: DockLayout) -> Pose2D:
    """The commissioned dock frame in the world's, on the floor: the rigid fit of the layout's marker corners onto
    the world's (Kabsch), its floor-plane part."""
    a = np.concatenate([layout.corners_in_dock(r) for r in ROLES])
    b = np.concatenate([truth.corners_in_dock(r) for r in ROLES])
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    R = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    t = cb - R @ ca
    return Pose2D(float(t[0]), float(t[1]), math.atan2(R[1, 0], R[0, 0]))


def _at_world_scale(surveyed: DockLayout, truth: DockLayout) -> DockLayout:
    """The commissioned layout with the print's overall scale divided out (about the centre marker) and the centre
    marker at the world's height: its shape and lean alone, what no image can tell set from the truth."""
    scale = math.exp(np.mean([math.log(surveyed.side(r) / truth.side(r)) for r in ROLES]))
    c = surveyed.marker("center")
    z0 = truth.marker("center").z
    markers = tuple(
        dataclasses.replace(
            m,
            x=(m.x - c.x) / scale + c.x,
            y=m.y / scale,
            z=z0 + (m.z - c.z) / scale,
            size=surveyed.side(m.role) / scale,
        )
        for m in surveyed.markers
    )
    return dataclasses.replace(surveyed, markers=markers)


def _mount_error(calibrated: RobotConfig, layout: DockLayout, world: WrongWorld) -> dict[str, float]:
    m, t = calibrated.camera_mount, world.robot.camera_mount
    out = {k: float(getattr(m, k) - getattr(t, k)) for k in ("x", "y", "roll", "pitch", "yaw")}
    out["z"] = float((m.z - layout.marker("center").z) - (t.z - world.layout.marker("center").z))
    return out


def _record(path: Path, robot: SimulatedRobot, legs: list, frame_every: int) -> None:  # type: ignore[type-arg]
    record_drive(path, robot, legs, frame_every=frame_every, progress=False)


def commission_world(
    seed: int,
    *,
    frames: int = 60,
    docking_trials: int = 1,
    views: int = 24,
    scale_from: str = "odometry",
    work: Path | None = None,
) -> WorldResult:
    """Build the world of ``seed``, commission it as a user would, and measure (the module's docstring)."""
    world = wrong_world(seed)
    sim = Simulator(layout=world.layout, robot=world.robot, seed=seed)
    rng = np.random.default_rng([seed, 40])
    # 1. The survey: a person's photographs of the dock.
    shots = [render_shot(sim, f"view_{k:03d}", T, rng) for k, T in enumerate(handheld_poses(sim, views, rng))]
    sv, skipped, offset = survey_views(
        [Frame(s.name, math.nan, s.image) for s in shots], sim.camera, world.nominal_layout
    )
    survey = survey_layout(sv, sim.camera, world.nominal_layout, skipped=skipped, edge_offset=offset)
    with tempfile.TemporaryDirectory(dir=work) as tmp:
        # 2. The mount: a minute's drive, recorded as a robot records it.
        start, legs = commissioning_route(np.random.default_rng([seed, 41]))
        drive = SimulatedRobot(sim, start, rng=np.random.default_rng([seed, 42]), wheel_scale=world.wheel_scale)
        _record(Path(tmp) / "drive", drive, legs, 3)
        drive_read = frames_from_recording(str(Path(tmp) / "drive"), survey.layout, camera=sim.camera)
        mount = calibrate_mount_of(drive_read, survey.layout, world.nominal_robot, scale_from=scale_from)
        layout, robot = mount.layout(survey.layout), mount.robot(world.nominal_robot)
        # 3. The charging pose: pushed onto the contacts, then backing off.
        home = teach_start(world.robot.front_offset, np.random.default_rng([seed, 43]))
        backer = SimulatedRobot(sim, home, rng=np.random.default_rng([seed, 44]), wheel_scale=world.wheel_scale)
        _record(Path(tmp) / "teach", backer, teach_route(), 1)
        taught = teach_from_recording(str(Path(tmp) / "teach"), layout, robot, camera=sim.camera)
    survey_err, print_scale = _survey_errors(survey.layout, world.layout)
    # The taught pose in the world's dock frame, through the markers: the commissioned frame is the survey's (the
    # face as its markers show it), a few millimetres from the world's (the face itself, which no image shows).
    seen = _frame_of(layout, world.layout).compose(taught.pose)
    teach_err = (seen.x - home.x, seen.y - home.y, wrap_angle(seen.theta - home.theta))
    dock_T_target = taught.offset.dock_T_target(robot.front_offset)
    true_target = home.compose(Pose2D(robot.front_offset, 0.0, 0.0))
    errors = _accuracy(sim, world, (layout, robot), (dock_T_target, true_target), frames, seed)
    w = world.wheel_scale
    result = WorldResult(
        seed=seed,
        marker_position_mm=survey_err["position"],  # type: ignore[arg-type]
        marker_position_scaled_mm=survey_err["scaled"],  # type: ignore[arg-type]
        marker_angle_deg=survey_err["angle"],  # type: ignore[arg-type]
        marker_side_mm=survey_err["side"],  # type: ignore[arg-type]
        print_scale=print_scale,
        mount_error=_mount_error(robot, layout, world),
        teach_error=(float(teach_err[0]), float(teach_err[1]), float(teach_err[2])),
        errors=errors,
        odometry_scale=(mount.odometry_scale, float(np.mean(w)) * print_scale),
        mount_sd={k: float(mount.sd[k]) for k in ("x", "y", "z", "roll", "pitch", "yaw")},
    )
    if docking_trials:
        result = dataclasses.replace(
            result,
            docking={
                # The nominal files with board PnP, the best a robot that was not commissioned has (the planar fit
                # trusts the mount, and a mount 1.5° off sends it metres astray: see the estimates).
                "nominal/board": _dock(
                    world, world.nominal_layout, world.nominal_robot, ChargingOffset(), docking_trials, "board"
                ),
                "commissioned/fused": _dock(world, layout, robot, taught.offset, docking_trials, "fused"),
            },
        )
    return result


def _accuracy(
    sim: Simulator,
    world: WrongWorld,
    commissioned: tuple[DockLayout, RobotConfig],
    targets: tuple[Pose2D, Pose2D],
    frames: int,
    seed: int,
) -> dict[str, dict[str, NDArray[np.float64]]]:
    """Per file set and method, each frame's depth and error (module docstring: which frame each is judged in).

    ``targets``: the taught target in the commissioned dock frame, and where it truly is in the world's."""
    dock_T_target, true_target = targets
    shape = _at_world_scale(commissioned[0], world.layout)
    world_T_shape = _frame_of(shape, world.layout)
    files = {
        "nominal": (world.nominal_layout, world.nominal_robot),
        "commissioned": commissioned,
        "layout": (shape, world.robot),
        "exact": (world.layout, world.robot),
    }
    estimators = {
        k: make_estimator(methods=ACCURACY_METHODS, camera=sim.camera, layout=lay, robot=rob)
        for k, (lay, rob) in files.items()
    }
    rng = np.random.default_rng([seed, 45])
    dist = PoseDistribution(depth=(0.25, 2.5), lateral=(-0.4, 0.4), yaw_deg=(-30.0, 30.0))
    rows: dict[str, dict[str, list[list[float]]]] = {k: {m: [] for m in ACCURACY_METHODS} for k in files}
    for _ in range(frames):
        truth = sim.sample_pose(dist, rng=rng)
        image = sim.render(truth, rng=rng)
        depth = truth.x - world.robot.camera_mount.x
        for k, estimator in estimators.items():
            result = estimator.estimate("", 0.0, image)
            for m in ACCURACY_METHODS:
                e = result.estimates[m].pose
                if e is None:
                    continue
                if k == "commissioned":
                    est = Pose2D(e.x, e.y, e.yaw).compose(dock_T_target)
                    ref = Pose2D(truth.x, truth.y, truth.yaw).compose(true_target)
                elif k == "layout":
                    est = Pose2D(e.x, e.y, e.yaw)
                    ref = Pose2D(truth.x, truth.y, truth.yaw).compose(world_T_shape)
                else:
                    est, ref = Pose2D(e.x, e.y, e.yaw), Pose2D(truth.x, truth.y, truth.yaw)
                rows[k][m].append([depth, est.x - ref.x, est.y - ref.y, wrap_angle(est.theta - ref.theta)])
    return {k: {m: np.asarray(v, dtype=np.float64).reshape(-1, 4) for m, v in per.items()} for k, per in rows.items()}


def _dock(
    world: WrongWorld, layout: DockLayout, robot: RobotConfig, offset: ChargingOffset, trials: int, method: str
) -> list[DockingOutcome]:
    """Closed-loop dockings in the world with the files the robot has: every case, ``trials`` starts each."""
    config = DockSimConfig(
        trials=trials,
        methods=(method,),
        seed=world.seed,
        jobs=1,
        layout=world.layout,
        robot=world.robot,
        believed_layout=layout,
        believed_robot=robot,
        wheel_scale=world.wheel_scale,
        mission=DockingConfig(charging_offset=offset),
    )
    out = []
    for r in run_dock_sim(config, progress=False):
        charged = bool(r.charging)
        out.append(
            DockingOutcome(
                docked=r.success,
                charged_first_seat=charged and r.reseats == 0,
                charged=charged,
                lateral_mm=r.lateral_cm * 10,
                gap_mm=r.longitudinal_cm * 10,
                heading_deg=r.heading_deg,
                reseats=r.reseats,
            )
        )
    return out


# --- the summary -------------------------------------------------------------------------------------------------


def wilson(successes: int, n: int) -> tuple[float, float]:
    """The Wilson 95 % interval of a success rate (scipy's binomtest)."""
    if n == 0:
        return (math.nan, math.nan)
    ci = binomtest(successes, n).proportion_ci(confidence_level=0.95, method="wilson")
    return float(ci.low), float(ci.high)


@dataclass(frozen=True)
class CommissioningSummary:
    """The worlds' figures: MAE by band per file set and method, the survey's and mount's errors, the dockings."""

    worlds: int
    bands: tuple[str, ...]
    mae: dict[str, dict[str, dict[str, list[float]]]]  # file set -> method -> x_mm/y_mm/yaw_deg -> per band
    overall: dict[str, dict[str, dict[str, float]]]  # file set -> method -> x_mm/y_mm/yaw_deg
    marker: dict[str, float]  # max and mean |error| of the survey's positions (mm) and angles (deg)
    mount: dict[str, float]  # max |error| per field (mm, deg)
    teach: dict[str, float]
    docking: dict[str, dict[str, object]]


def _band_labels() -> tuple[str, ...]:
    e = BAND_EDGES_M
    return tuple(f"{e[k] * 100:.0f}-{e[k + 1] * 100:.0f}" for k in range(len(e) - 1))


def _mae(rows: NDArray[np.float64]) -> dict[str, float]:
    if rows.size == 0:
        return {"x_mm": math.nan, "y_mm": math.nan, "yaw_deg": math.nan, "n": 0}
    a = np.abs(rows[:, 1:])
    return {
        "x_mm": float(a[:, 0].mean() * 1e3),
        "y_mm": float(a[:, 1].mean() * 1e3),
        "yaw_deg": float(np.degrees(a[:, 2].mean())),
        "n": int(len(rows)),
    }


def summarize_worlds(results: Sequence[WorldResult]) -> CommissioningSummary:
    """The figures over every world."""
    bands = _band_labels()
    mae: dict[str, dict[str, dict[str, list[float]]]] = {}
    overall: dict[str, dict[str, dict[str, float]]] = {}
    for k in FILE_SETS:
        mae[k], overall[k] = {}, {}
        for m in ACCURACY_METHODS:
            rows = np.concatenate([r.errors[k][m] for r in results]) if results else np.zeros((0, 4))
            overall[k][m] = _mae(rows)
            per: dict[str, list[float]] = {"x_mm": [], "y_mm": [], "yaw_deg": [], "n": []}
            for b in range(len(bands)):
                lo, hi = BAND_EDGES_M[b], BAND_EDGES_M[b + 1]
                sel = rows[(rows[:, 0] >= lo) & (rows[:, 0] < hi)] if rows.size else rows
                for key, value in _mae(sel).items():
                    per[key].append(float(value))
            mae[k][m] = per
    pos = [abs(v) for r in results for p in r.marker_position_mm.values() for v in p]
    scaled = [abs(v) for r in results for p in r.marker_position_scaled_mm.values() for v in p]
    ang = [a for r in results for a in r.marker_angle_deg.values()]
    side = [abs(v) for r in results for v in r.marker_side_mm.values()]
    marker = {
        "position_max_mm": max(pos, default=math.nan),
        "position_mean_mm": float(np.mean(pos)) if pos else math.nan,
        "position_scaled_max_mm": max(scaled, default=math.nan),
        "angle_max_deg": max(ang, default=math.nan),
        "angle_mean_deg": float(np.mean(ang)) if ang else math.nan,
        "side_max_mm": max(side, default=math.nan),
        "print_scale_max_error": max((abs(r.print_scale - 1.0) for r in results), default=math.nan),
    }
    mount = {}
    for k in ("x", "y", "z"):
        mount[f"{k}_max_mm"] = max((abs(r.mount_error[k]) * 1e3 for r in results), default=math.nan)
    for k in ("roll", "pitch", "yaw"):
        mount[f"{k}_max_deg"] = max((math.degrees(abs(r.mount_error[k])) for r in results), default=math.nan)
    for k in ("x", "y", "roll", "pitch", "yaw"):
        mount[f"{k}_max_error_per_sd"] = max(
            (abs(r.mount_error[k]) / r.mount_sd[k] for r in results if r.mount_sd.get(k, 0.0) > 0.0), default=math.nan
        )
    teach = {
        "x_max_mm": max((abs(r.teach_error[0]) * 1e3 for r in results), default=math.nan),
        "y_max_mm": max((abs(r.teach_error[1]) * 1e3 for r in results), default=math.nan),
        "yaw_max_deg": max((math.degrees(abs(r.teach_error[2])) for r in results), default=math.nan),
    }
    docking: dict[str, dict[str, object]] = {}
    for k in DOCKING_VARIANTS:
        runs = [d for r in results for d in r.docking.get(k, [])]
        n = len(runs)
        first = sum(d.charged_first_seat for d in runs)
        docking[k] = {
            "runs": n,
            "docked": sum(d.docked for d in runs),
            "charging": sum(d.charged for d in runs),
            "charging_first_seat": first,
            "charging_first_seat_wilson95": wilson(first, n),
            "lateral_mm_median": float(np.median([abs(d.lateral_mm) for d in runs])) if runs else math.nan,
            "gap_mm_median": float(np.median([d.gap_mm for d in runs])) if runs else math.nan,
            "heading_deg_median": float(np.median([abs(d.heading_deg) for d in runs])) if runs else math.nan,
        }
    return CommissioningSummary(len(results), bands, mae, overall, marker, mount, teach, docking)
