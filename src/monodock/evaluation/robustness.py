"""``monodock evaluate --robustness``: every method against one nuisance at a time, on the simulator's truth.

The picture an engineer needs to choose a method: the same test poses are rendered once per level of each
nuisance, everything else at the defaults (``Nuisances()``), and every method runs on the same image:

- **image** axes change the pixels: sensor noise, defocus, motion blur, exposure, and an occluder that hides a
  set share of one marker (ArUco may then miss it: that is part of the result, see the valid rates).
- **calibration** axes change the files the methods are given, not the images (rendered once, at the
  defaults): a focal length, marker size or camera mount that is off. ``fused`` is then run twice: with its
  tables re-learned from a small LiDAR-labelled calibration set through the same wrong files (what
  ``monodock train`` would have learned on that robot), and with the bundle's tables, learned with the right
  files (``fused (stale tables)``: a calibration that changed after training). The regression is not retrained
  per level: under a wrong focal length its inputs shift, which a regression retrained with the same wrong
  file would absorb.

Errors are against the simulator's truth. Every frame's random draws (noise, exposure jitter, motion-blur
direction, occluder) come from the frame's own seeds and are the same at every level, so the curves differ by
the nuisance alone. Frames are rendered and estimated in worker processes (``monodock.compute.parallel``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from monodock.compute import map_with_state
from monodock.core.camera import CameraModel
from monodock.core.layout import ROLE_NUMBER, ROLES, DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import Mount, RobotConfig
from monodock.core.scan import LaserScan
from monodock.core.settings import to_mapping
from monodock.errors import InputError
from monodock.estimation.bundle import load_bundle
from monodock.estimation.fused import FusionTables
from monodock.estimation.methods import MethodFrame, MethodSetup, PoseMethod, build_methods, run_methods
from monodock.estimation.pnp import PoseEstimate
from monodock.evaluation.robustness_results import (
    METHODS,
    STALE,
    Axis,
    AxisKind,
    AxisResult,
    LevelStats,
    MethodCurve,
    OcclusionStats,
    RobustnessSettings,
    RobustnessSummary,
    headline,
)
from monodock.learning.dataset import Dataset, LabelRun, label_frames
from monodock.learning.fusion import learn_fusion_from
from monodock.perception.detect import Detection, MarkerDetector
from monodock.perception.features import feature_vector, refined_vector
from monodock.perception.refine import refine_detection
from monodock.sim import Nuisances, PoseDistribution, Simulator
from monodock.sim.nuisance import apply_nuisances
from monodock.sim.render import render_radiance
from monodock.sim.world import Surface, World, rectangle

__all__ = [
    "AXES",
    "Calibration",
    "ImageCondition",
    "RobustnessConfig",
    "RobustnessResult",
    "axis_stats",
    "calibration_for",
    "image_condition",
    "occluder_hiding",
    "run_robustness",
]

T = TypeVar("T")
R = TypeVar("R")

# An occluder stands this far in front of the charger face (a cable, a box): parallel to the face, so that
# its shadow on the face is an exact scaled copy and hides exactly the share of the marker it is built for.
OCCLUDER_DISTANCE_M = 0.05
# The occluder reaches past the marker's edge by this share of the marker's side (into the quiet zone; the
# neighbouring markers are a marker width away, so it never reaches them).
OCCLUDER_OVERHANG = 0.3
# The calibration set is rendered as ``monodock train``'s drive is (see SelfTrainConfig.supersample).
CALIBRATION_SUPERSAMPLE = 16
_DEFAULT = Nuisances()


_IMAGE, _CALIBRATION = AxisKind.IMAGE, AxisKind.CALIBRATION
AXES: tuple[Axis, ...] = (
    Axis("noise", "sensor noise (read noise; shot noise scaled alike)", "DN", (0.0, 1.5, 4.0, 8.0), 1.5, _IMAGE),
    Axis("defocus", "defocus blur (Gaussian sigma)", "px", (0.3, 0.6, 1.5, 2.5), _DEFAULT.defocus_px, _IMAGE),
    Axis("motion_blur", "motion blur (streak length)", "px", (0.0, 2.0, 4.0, 6.0), _DEFAULT.motion_blur_px, _IMAGE),
    Axis(
        "exposure", "exposure (gain; 1 = white near 85 % of full scale)", "x", (0.35, 0.6, 1.0, 1.6, 2.5), 1.0, _IMAGE
    ),
    Axis("occlusion", "partial occlusion of one marker", "% of its area", (0.0, 10.0, 25.0, 40.0), 0.0, _IMAGE),
    Axis("focal", "focal length error", "%", (-3.0, -1.5, 0.0, 1.5, 3.0), 0.0, _CALIBRATION),
    Axis(
        "marker_size",
        "marker size error (layout file vs printed)",
        "%",
        (-5.0, -2.5, 0.0, 2.5, 5.0),
        0.0,
        _CALIBRATION,
    ),
    Axis("mount_x", "camera mount x error", "cm", (-1.0, 0.0, 1.0), 0.0, _CALIBRATION),
    Axis("mount_y", "camera mount y error", "cm", (-1.0, 0.0, 1.0), 0.0, _CALIBRATION),
    Axis("mount_z", "camera mount z error", "cm", (-1.0, 0.0, 1.0), 0.0, _CALIBRATION),
    Axis("mount_roll", "camera mount roll error", "°", (-1.0, 0.0, 1.0), 0.0, _CALIBRATION),
    Axis("mount_pitch", "camera mount pitch error", "°", (-1.0, 0.0, 1.0), 0.0, _CALIBRATION),
    Axis("mount_yaw", "camera mount yaw error", "°", (-1.0, 0.0, 1.0), 0.0, _CALIBRATION),
)


def _level_key(axis: Axis, level: float) -> str:
    """The condition a level renders or runs with; every default level is the one "default" condition."""
    return "default" if level == axis.default else f"{axis.key}={level:g}"


# --- what a level changes ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class ImageCondition:
    """How one image level renders: its nuisances and the share of one marker hidden (0: no occluder)."""

    key: str
    nuisances: Nuisances
    occlusion: float = 0.0


@dataclass(frozen=True)
class Calibration:
    """The files the methods are given at one calibration level (the images are the default ones)."""

    key: str
    camera: CameraModel
    layout: DockLayout
    robot: RobotConfig


def image_condition(axis: Axis, level: float, base: Nuisances = _DEFAULT) -> ImageCondition:
    """The nuisances of one level of an image axis, everything else as ``base``.

    Noise: the read noise is the level and the shot noise is scaled by the same factor (a higher sensor gain
    multiplies both); occlusion: the level is the percentage of one marker's area hidden.
    """
    key = _level_key(axis, level)
    if axis.key == "noise":
        k = level / _DEFAULT.read_noise
        return ImageCondition(key, base.updated(read_noise=level, shot_noise=_DEFAULT.shot_noise * k))
    if axis.key == "defocus":
        return ImageCondition(key, base.updated(defocus_px=level))
    if axis.key == "motion_blur":
        return ImageCondition(key, base.updated(motion_blur_px=level))
    if axis.key == "exposure":
        return ImageCondition(key, base.updated(exposure=level))
    if axis.key == "occlusion":
        return ImageCondition(key, base, level / 100.0)
    raise ValueError(f"{axis.key} is not an image axis")


def calibration_for(
    axis: Axis, level: float, camera: CameraModel, layout: DockLayout, robot: RobotConfig
) -> Calibration:
    """The wrong files of one level of a calibration axis (the true ones at level 0)."""
    key = _level_key(axis, level)
    if level == 0.0:
        return Calibration(key, camera, layout, robot)
    if axis.key == "focal":
        return Calibration(key, camera.focal_scaled(1.0 + level / 100.0), layout, robot)
    if axis.key == "marker_size":
        return Calibration(
            key, camera, dataclasses.replace(layout, marker_size=layout.marker_size * (1 + level / 100)), robot
        )
    m = robot.camera_mount
    what = axis.key.removeprefix("mount_")
    change = level / 100.0 if what in ("x", "y", "z") else math.radians(level)
    mount = Mount(
        **{k: getattr(m, k) + (change if k == what else 0.0) for k in ("x", "y", "z", "roll", "pitch", "yaw")}
    )
    return Calibration(key, camera, layout, dataclasses.replace(robot, camera_mount=mount))


def occluder_hiding(
    layout: DockLayout,
    role: str,
    camera_centre: NDArray[np.float64],
    share: float,
    *,
    from_left: bool,
    albedo: float,
) -> Surface:
    """An upright board that hides ``share`` of one marker's area from a camera at ``camera_centre`` (dock frame).

    The board stands OCCLUDER_DISTANCE_M in front of the charger face, parallel to it, and covers the marker's
    full height from one side (``from_left``: the side of larger dock y, the robot's left) to ``share`` of its
    width, reaching OCCLUDER_OVERHANG of a marker past its edge.
    """
    if not 0.0 < share < 1.0:
        raise ValueError(f"an occluder hides a share between 0 and 1 of a marker, got {share}")
    c = np.asarray(camera_centre, dtype=np.float64)
    if c[0] >= -OCCLUDER_DISTANCE_M:
        raise ValueError("the camera must be in front of the occluder")
    m = layout.marker(role)
    s = layout.marker_size
    # What the board must cover on the face (x = 0): y from the marker's edge inwards, z its full height.
    if from_left:
        y_lo, y_hi = m.y + s / 2 - share * s, m.y + s / 2 + OCCLUDER_OVERHANG * s
    else:
        y_lo, y_hi = m.y - s / 2 - OCCLUDER_OVERHANG * s, m.y - s / 2 + share * s
    z_lo, z_hi = m.z - 1.5 * s, m.z + 1.5 * s
    # A ray from the camera through the board plane x = -d reaches the face x = 0 at scale k from the camera.
    k = -c[0] / (-c[0] - OCCLUDER_DISTANCE_M)
    ys = c[1] + (np.array([y_lo, y_hi]) - c[1]) / k
    zs = c[2] + (np.array([z_lo, z_hi]) - c[2]) / k
    # Facing the robot (-x): its right, seen from the front, is -y; its top-left corner the largest y.
    top_left = (-OCCLUDER_DISTANCE_M, float(ys[1]), float(zs[1]))
    return rectangle("occluder", top_left, (0.0, -1.0, 0.0), (0.0, 0.0, -1.0), ys[1] - ys[0], zs[1] - zs[0], albedo)


# --- configuration and the work of the worker processes --------------------------------------------------


@dataclass(frozen=True)
class RobustnessConfig:
    """The size of a robustness run.

    ``supersample`` is the renderer's edge sampling of the test frames (default: ``Nuisances()``'s); the
    calibration set is rendered as the training drive is (CALIBRATION_SUPERSAMPLE), or coarser when asked.
    """

    frames: int = 300
    calibration_frames: int = 300
    seed: int = 0
    jobs: int = 2
    supersample: int = _DEFAULT.supersample
    poses: PoseDistribution = field(default_factory=PoseDistribution)
    axes: tuple[Axis, ...] = AXES


def _pose_row(p: DockPose | None) -> NDArray[np.float64]:
    return np.array([p.x, p.y, p.yaw]) if p is not None else np.full(3, np.nan)


def _row(e: PoseEstimate) -> NDArray[np.float64]:
    return _pose_row(e.pose)


def _camera_key(camera: CameraModel) -> tuple[float, ...]:
    return tuple(camera.K) + tuple(camera.D)


@dataclass
class _CalibrationSetup:
    """What the calibration-set workers need: the simulator and the cameras to measure features with."""

    sim: Simulator
    cameras: list[CameraModel]
    seed: int
    supersample: int


@dataclass
class _CalibrationFrame:
    """One labelled calibration frame: per camera file, the raw features and refined corners; its scan."""

    raw: dict[tuple[float, ...], NDArray[np.float64]]
    refined: dict[tuple[float, ...], NDArray[np.float64]]
    scan: LaserScan
    truth: DockPose


def _calibration_frame(setup: _CalibrationSetup, task: tuple[int, DockPose]) -> _CalibrationFrame:
    """Render one calibration frame (default nuisances) and measure it through every camera file."""

    index, pose = task
    sim = setup.sim
    rng = np.random.default_rng([setup.seed, 0xCA1, index])
    radiance = render_radiance(sim.world, sim.camera, sim.world_T_optical(pose), supersample=setup.supersample)
    image = apply_nuisances(radiance, sim.nuisances, rng)
    scan = sim.scan(pose, rng=rng)
    det = MarkerDetector(sim.layout).detect(image)
    raw, refined = {}, {}
    for cam in setup.cameras:
        raw[_camera_key(cam)] = feature_vector(det, cam)
        refined[_camera_key(cam)] = refined_vector(refine_detection(image, det, cam, modules=sim.layout.modules))
    return _CalibrationFrame(raw, refined, scan, pose)


@dataclass
class _TableSetup:
    """What the table-learning workers need: the bundle, the calibration set, every calibration level."""

    bundle_path: str
    frames: list[_CalibrationFrame]
    calibrations: dict[str, Calibration]


def _learn_tables(setup: _TableSetup, key: str) -> tuple[str, FusionTables, int]:
    """The fusion tables ``monodock train`` would learn with one level's files: label the calibration set with
    the LiDAR through those files, run both methods on it, learn. Returns (key, tables, labelled rows)."""

    cal = setup.calibrations[key]
    ck = _camera_key(cal.camera)
    n = len(setup.frames)
    frames: list[tuple[int, float, NDArray[np.float64] | None, str]] = [
        (i, float(i), f.raw[ck], "") for i, f in enumerate(setup.frames)
    ]
    truth: list[tuple[float, float, float] | None] = [(f.truth.x, f.truth.y, f.truth.yaw_deg) for f in setup.frames]
    run = LabelRun()
    cols = label_frames(
        frames,
        [f.scan for f in setup.frames],
        np.arange(n, dtype=np.int64),
        truth,
        cal.camera,
        cal.robot,
        run,
        refined=[f.refined[ck] for f in setup.frames],
    )
    meta = {"camera": cal.camera.to_ros_dict(), "robot": to_mapping(cal.robot), "layout": to_mapping(cal.layout)}
    ds = Dataset({k: np.asarray(v) for k, v in cols.items()}, meta)
    regression = MethodSetup(cal.camera, cal.layout, cal.robot, load_bundle(Path(setup.bundle_path))).regression
    tables = learn_fusion_from(ds, regression, cal.camera, cal.layout, cal.robot, np.arange(n, dtype=np.int64))
    return key, tables, run.labelled


@dataclass
class _TestSetup:
    """What the test-frame workers need (sent to each once); the loaded models are built there."""

    bundle_path: str
    sim: Simulator
    images: list[ImageCondition]
    calibrations: dict[str, Calibration]
    tables: dict[str, FusionTables]
    seed: int
    supersample: int


@dataclass
class _FrameResult:
    """One test pose: the truth and, per condition and method, the estimate (x, y, yaw; NaN when none)."""

    index: int
    truth: NDArray[np.float64]
    depth: float
    estimates: dict[str, dict[str, NDArray[np.float64]]]
    occluded_role: str = ""
    hidden: dict[str, float] = field(default_factory=dict)  # per occlusion condition, measured on a 9x9 grid
    occluded_seen: dict[str, bool] = field(default_factory=dict)  # per occlusion condition: ArUco found it


class _Runtime:
    """The models a worker loads once: the detector, and per calibration level the methods on those files
    (``estimation.methods``): the regression and the PnP methods, fused with the bundle's tables (``STALE``) and,
    where they were re-learned with those files, fused with those."""

    def __init__(self, setup: _TestSetup) -> None:
        bundle = load_bundle(Path(setup.bundle_path))
        self.detector = MarkerDetector(setup.sim.layout)
        self.methods: dict[str, tuple[Calibration, dict[str, PoseMethod], PoseMethod | None, PoseMethod]] = {}
        for key, cal in setup.calibrations.items():
            files = MethodSetup(cal.camera, cal.layout, cal.robot, bundle)
            plain = build_methods(("regression", "pnp", "board"), files)
            stale = build_methods(("fused",), files)["fused"]
            learned = setup.tables.get(key)
            relearned = dataclasses.replace(files, tables=learned) if learned is not None else None
            fused = build_methods(("fused",), relearned)["fused"] if relearned is not None else None
            self.methods[key] = (cal, plain, fused, stale)


_RUNTIME: list[tuple[_TestSetup, _Runtime]] = []


def _runtime(setup: _TestSetup) -> _Runtime:
    """The worker's models for this setup, built on first use (one setup per worker process)."""
    if not _RUNTIME or _RUNTIME[0][0] is not setup:
        _RUNTIME[:] = [(setup, _Runtime(setup))]
    return _RUNTIME[0][1]


def _run_methods(
    rt: _Runtime,
    key: str,
    image: NDArray[np.uint8],
    det: Detection,
    refined_by_camera: dict[tuple[float, ...], Detection],
    *,
    relearned: bool = True,
) -> dict[str, NDArray[np.float64]]:
    """Every method on one image with one calibration level's files (``relearned``: also fused with the
    tables re-learned with those files)."""

    cal, plain, fused, stale = rt.methods[key]
    ck = _camera_key(cal.camera)
    if ck not in refined_by_camera:
        # The refinement straightens the sides through the lens model of the file it is given.
        refined_by_camera[ck] = refine_detection(image, det, cal.camera, modules=cal.layout.modules)
    frame = MethodFrame(det, cal.camera, cal.layout.modules, refined_corners=refined_by_camera[ck])
    out = {name: _row(e) for name, e in run_methods(plain, frame).items()}
    out[STALE] = _row(stale.estimate(frame))
    if relearned and fused is not None:
        out["fused"] = _row(fused.estimate(frame))
    return out


def _test_frame(setup: _TestSetup, task: tuple[int, DockPose]) -> _FrameResult:
    """Render one test pose at every image level and run every method on each (and on the default image with
    every calibration level's files)."""

    index, pose = task
    sim = setup.sim
    rt = _runtime(setup)
    T = sim.world_T_optical(pose)
    radiance = {0.0: render_radiance(sim.world, sim.camera, T, supersample=setup.supersample)}
    # The frame's own draws, the same at every level: the occluder's place, the motion-blur direction, and
    # the generator of the exposure jitter and the sensor noise.
    occ_rng = np.random.default_rng([setup.seed, 0x0CC, index])
    corners = sim.true_corners(pose)
    in_view = [r for r in ROLES if sim.in_view(corners[r], 2.0)]
    role = str(occ_rng.choice(in_view))
    from_left = bool(occ_rng.random() < 0.5)
    albedo = float(occ_rng.uniform(0.1, 0.5))
    blur_angle = float(occ_rng.uniform(0.0, 180.0))
    result = _FrameResult(index, _pose_row(pose), pose.x - sim.robot.camera_mount.x, {}, role)
    worlds: dict[float, World] = {0.0: sim.world}
    visible = sim._visible_fraction(sim.world, pose, role)  # the simulator's own truth
    for cond in setup.images:
        share = cond.occlusion
        if share not in radiance:
            worlds[share] = sim.world.with_surfaces(
                occluder_hiding(sim.layout, role, T[:3, 3], share, from_left=from_left, albedo=albedo)
            )
            radiance[share] = render_radiance(worlds[share], sim.camera, T, supersample=setup.supersample)
        nuisances = cond.nuisances.updated(motion_blur_angle_deg=blur_angle)
        image = apply_nuisances(radiance[share], nuisances, np.random.default_rng([setup.seed, 0x7E57, index]))
        det = rt.detector.detect(image)
        refined: dict[tuple[float, ...], Detection] = {}
        ests = _run_methods(rt, "default", image, det, refined, relearned=False)
        ests["fused"] = ests.pop(STALE)  # on the image axes the bundle's tables are the right ones
        result.estimates[cond.key] = ests
        if share > 0:
            result.hidden[cond.key] = visible - sim._visible_fraction(worlds[share], pose, role)
        if share > 0 or cond.key == "default":
            result.occluded_seen[cond.key] = det.seen(role)
        if cond.key == "default":
            for key in setup.calibrations:
                result.estimates[f"calibration:{key}"] = _run_methods(rt, key, image, det, refined)
    return result


def _mapped(
    fn: Callable[[Any, T], R], state: Any, tasks: list[T], *, jobs: int, desc: str, unit: str, progress: bool
) -> list[R]:
    """``fn(state, task)`` over the tasks in ``jobs`` worker processes, in order, with a progress bar."""

    out: list[R] = []
    with tqdm(total=len(tasks), desc=desc, unit=unit, leave=False, disable=None if progress else True) as bar:
        for r in map_with_state(fn, state, tasks, jobs=jobs, chunksize=1):
            out.append(r)
            bar.update()
    return out


# --- the numbers ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RobustnessResult:
    """Per axis, level and method the statistics, every frame's estimates, and what the run was."""

    config: RobustnessConfig
    axes: Mapping[str, AxisResult]
    settings: RobustnessSettings
    occlusion: OcclusionStats | None
    runtime_s: float
    truth: NDArray[np.float64]  # (frames, 3): the true DockPose x m, y m, yaw rad
    estimates: Mapping[str, Mapping[str, NDArray[np.float64]]]  # condition -> method -> (frames, 3), NaN when none

    def summary(self) -> RobustnessSummary:
        """The summary.json contract."""
        return RobustnessSummary(self.settings, self.runtime_s, headline(self.axes), self.axes, self.occlusion)

    def save_frames(self, path: Path) -> None:
        """Every frame's numbers as an .npz: "truth" and one array per "CONDITION|METHOD" (see the report)."""
        arrays = {"truth": self.truth}
        arrays.update({f"{c}|{m}": v for c, per in self.estimates.items() for m, v in per.items()})
        np.savez_compressed(path, **arrays)  # type: ignore[arg-type]


def _stats(errors: NDArray[np.float64], depth: NDArray[np.float64]) -> LevelStats:
    """Valid rate, MAE (cm, cm, deg) over the valid frames and the mean depth error relative to depth (%)."""
    ok = np.isfinite(errors[:, 0])
    n = len(errors)
    if not ok.any():
        return LevelStats(0.0, math.nan, math.nan, math.nan, math.nan)
    e = errors[ok]
    return LevelStats(
        valid_rate=float(ok.sum()) / n,
        depth_mae_cm=float(np.mean(np.abs(e[:, 0]))) * 100,
        lateral_mae_cm=float(np.mean(np.abs(e[:, 1]))) * 100,
        yaw_mae_deg=math.degrees(float(np.mean(np.abs(e[:, 2])))),
        depth_bias_pct=float(np.mean(e[:, 0] / depth[ok])) * 100,
    )


def _errors(poses: NDArray[np.float64], truth: NDArray[np.float64]) -> NDArray[np.float64]:
    """Signed errors (estimate - truth), yaw wrapped; NaN rows where a method gave no estimate."""
    e: NDArray[np.float64] = poses - truth
    e[:, 2] = np.remainder(e[:, 2] + np.pi, 2 * np.pi) - np.pi
    return e


def axis_stats(
    axis: Axis,
    estimates: Mapping[str, Mapping[str, NDArray[np.float64]]],
    truth: NDArray[np.float64],
    depth: NDArray[np.float64],
) -> AxisResult:
    """One axis: per method, per level (in order) the statistics of ``LevelStats``.

    Args:
        axis: the axis.
        estimates: per condition and method the estimates (frames, 3), x m, y m, yaw rad; NaN when none.
        truth: the true poses (frames, 3).
        depth: each frame's true depth from the camera, m.
    """
    methods = METHODS + ((STALE,) if axis.kind is AxisKind.CALIBRATION else ())
    curves = {}
    for m in methods:
        per_level = []
        for level in axis.levels:
            key = _level_key(axis, level)
            cond = key if axis.kind is AxisKind.IMAGE else f"calibration:{key}"
            per_level.append(_stats(_errors(estimates[cond][m], truth), depth))
        curves[m] = MethodCurve.of(per_level)
    return AxisResult(axis, len(truth), curves)


def _occlusion_stats(config: RobustnessConfig, frames: Sequence[_FrameResult]) -> OcclusionStats | None:
    """Per occlusion level: the share of the marker the simulator finds hidden, and how often ArUco found it."""
    axis = next((a for a in config.axes if a.key == "occlusion"), None)
    if axis is None:
        return None
    hidden, detected = [], []
    for level in axis.levels:
        key = _level_key(axis, level)
        hidden.append(100.0 * float(np.mean([f.hidden.get(key, 0.0) for f in frames])))
        detected.append(100.0 * float(np.mean([f.occluded_seen[key] for f in frames])))
    return OcclusionStats(
        levels=tuple(axis.levels),
        hidden_measured_pct=tuple(hidden),
        occluded_marker_detected_pct=tuple(detected),
        occluded_marker={f"m{ROLE_NUMBER[r]}": sum(f.occluded_role == r for f in frames) for r in ROLES},
    )


# --- the run: one function per stage ---------------------------------------------------------------------


def _sample_poses(sim: Simulator, dist: PoseDistribution, count: int, rng: np.random.Generator) -> list[DockPose]:
    return [sim.sample_pose(dist, rng=rng) for _ in range(count)]


def _check(bundle_path: Path, config: RobustnessConfig) -> None:
    """One clear line for a run that cannot be done: too few frames or processes, a bundle without fusion tables."""
    if config.frames < 1:
        raise InputError(f"--frames must be at least 1, got {config.frames}")
    if config.calibration_frames < 50:
        raise InputError(
            f"--calibration-frames must be at least 50 to learn the fusion tables from, got {config.calibration_frames}"
        )
    if config.jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {config.jobs}")
    load_bundle(bundle_path).fusion_tables()


def _conditions(
    config: RobustnessConfig, camera: CameraModel, layout: DockLayout, robot: RobotConfig
) -> tuple[dict[str, ImageCondition], dict[str, Calibration]]:
    """Every distinct image condition and calibration level of the run's axes (each default is one "default")."""
    images: dict[str, ImageCondition] = {"default": ImageCondition("default", _DEFAULT)}
    calibrations: dict[str, Calibration] = {}
    for axis in config.axes:
        for level in axis.levels:
            if axis.kind is AxisKind.IMAGE:
                cond = image_condition(axis, level)
                images.setdefault(cond.key, cond)
            else:
                cal = calibration_for(axis, level, camera, layout, robot)
                calibrations.setdefault(cal.key, cal)
    calibrations.setdefault("default", Calibration("default", camera, layout, robot))
    return images, calibrations


def _learn_calibration_tables(
    bundle_path: Path,
    sim: Simulator,
    calibrations: Mapping[str, Calibration],
    config: RobustnessConfig,
    *,
    progress: bool,
) -> tuple[dict[str, FusionTables], dict[str, int]]:
    """The calibration set measured through every camera file, and per level its fusion tables and labelled rows."""
    cal_poses = _sample_poses(sim, config.poses, config.calibration_frames, np.random.default_rng([config.seed, 0xCA1]))
    cameras = list({_camera_key(c.camera): c.camera for c in calibrations.values()}.values())
    cal_frames = _mapped(
        _calibration_frame,
        _CalibrationSetup(sim, cameras, config.seed, min(CALIBRATION_SUPERSAMPLE, config.supersample)),
        list(enumerate(cal_poses)),
        jobs=config.jobs,
        desc="calibration set",
        unit="frame",
        progress=progress,
    )
    learned = _mapped(
        _learn_tables,
        _TableSetup(str(bundle_path), cal_frames, dict(calibrations)),
        list(calibrations),
        jobs=min(config.jobs, len(calibrations)),
        desc="fusion tables",
        unit="level",
        progress=progress,
    )
    return {k: t for k, t, _ in learned}, {k: n for k, _, n in learned}


def _run_test_frames(
    bundle_path: Path,
    sim: Simulator,
    images: Mapping[str, ImageCondition],
    calibrations: Mapping[str, Calibration],
    tables: Mapping[str, FusionTables],
    config: RobustnessConfig,
    *,
    progress: bool,
) -> list[_FrameResult]:
    """Render the test poses (the same for every level) at every image level and run every method on each."""
    poses = _sample_poses(sim, config.poses, config.frames, np.random.default_rng([config.seed, 0x7E57]))
    setup = _TestSetup(
        str(bundle_path), sim, list(images.values()), dict(calibrations), dict(tables), config.seed, config.supersample
    )
    tasks = list(enumerate(poses))
    return _mapped(_test_frame, setup, tasks, jobs=config.jobs, desc="test frames", unit="frame", progress=progress)


def _settings(
    bundle_path: Path, config: RobustnessConfig, labelled: Mapping[str, int], stage: Mapping[str, float], runtime: float
) -> RobustnessSettings:
    """The run's settings for people: sizes, the pose distribution, the calibration set, the time per stage."""
    return RobustnessSettings(
        bundle=str(bundle_path),
        test_frames=config.frames,
        seed=config.seed,
        pose_distribution=(
            f"depth {config.poses.depth[0] * 100:g}-{config.poses.depth[1] * 100:g} cm from the camera, lateral "
            f"{config.poses.lateral[0] * 100:+g}..{config.poses.lateral[1] * 100:+g} cm, yaw "
            f"{config.poses.yaw_deg[0]:+g}..{config.poses.yaw_deg[1]:+g}°, marker 2 in view"
        ),
        test_frame_rendering=f"Nuisances() defaults, supersample {config.supersample}",
        calibration_set=(
            f"{config.calibration_frames} frames, default nuisances, supersample "
            f"{min(CALIBRATION_SUPERSAMPLE, config.supersample)}, other poses and seeds; LiDAR labels valid: "
            f"{min(labelled.values())}-{max(labelled.values())} per level"
        ),
        processes=config.jobs,
        runtime=f"{runtime:.0f} s ({', '.join(f'{k} {v:.0f} s' for k, v in stage.items())})",
    )


def _score(
    config: RobustnessConfig, frames: Sequence[_FrameResult], settings: RobustnessSettings, runtime: float
) -> RobustnessResult:
    """Every axis's statistics against the truth, from the test frames' estimates."""
    truth = np.array([f.truth for f in frames], dtype=np.float64).reshape(-1, 3)
    depth = np.array([f.depth for f in frames], dtype=np.float64)
    estimates = {
        cond: {m: np.array([f.estimates[cond][m] for f in frames], dtype=np.float64).reshape(-1, 3) for m in methods}
        for cond, methods in frames[0].estimates.items()
    }
    axes = {axis.key: axis_stats(axis, estimates, truth, depth) for axis in config.axes}
    return RobustnessResult(config, axes, settings, _occlusion_stats(config, frames), runtime, truth, estimates)


def run_robustness(
    bundle_path: Path,
    camera: CameraModel,
    layout: DockLayout,
    robot: RobotConfig,
    config: RobustnessConfig,
    *,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> RobustnessResult:
    """Render the test poses at every level of every axis, run every method, and score them against truth.

    ``camera``, ``layout`` and ``robot`` are the robot's true calibration (the simulator's and the right files).
    """
    _check(bundle_path, config)
    started = time.perf_counter()
    sim = Simulator(layout=layout, camera=camera, robot=robot, nuisances=_DEFAULT, seed=config.seed)
    images, calibrations = _conditions(config, camera, layout, robot)
    log(
        f"robustness: {config.frames} test poses x {len(images)} image levels, {len(calibrations)} calibration "
        f"levels; calibration set of {config.calibration_frames} frames ({config.jobs} processes)"
    )
    tables, labelled = _learn_calibration_tables(bundle_path, sim, calibrations, config, progress=progress)
    stage = {"calibration set and tables": time.perf_counter() - started}
    frames = _run_test_frames(bundle_path, sim, images, calibrations, tables, config, progress=progress)
    runtime = time.perf_counter() - started
    stage["test frames"] = runtime - stage["calibration set and tables"]
    return _score(config, frames, _settings(bundle_path, config, labelled, stage, runtime), runtime)
