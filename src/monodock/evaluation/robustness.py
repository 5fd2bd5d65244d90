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
the nuisance alone. Frames are rendered and estimated in worker processes (``monodock.core.parallel``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib import ticker
from numpy.typing import NDArray

from monodock.core.camera import CameraModel
from monodock.core.layout import ROLE_NUMBER, ROLES, DockLayout
from monodock.core.pose import DockPose
from monodock.core.robot import Mount, RobotConfig
from monodock.errors import InputError
from monodock.estimation.pnp import PoseEstimate
from monodock.report.html import HtmlReport
from monodock.sim import Nuisances, PoseDistribution, Simulator
from monodock.sim.world import Surface, World, rectangle

__all__ = [
    "AXES",
    "METHODS",
    "STALE",
    "Axis",
    "Calibration",
    "ImageCondition",
    "RobustnessConfig",
    "RobustnessResult",
    "axis_stats",
    "calibration_for",
    "image_condition",
    "occluder_hiding",
    "run_robustness",
    "write_robustness_report",
]

T = TypeVar("T")
R = TypeVar("R")

METHODS = ("regression", "pnp", "board", "fused")
STALE = "fused (stale tables)"
_COLOURS = {
    "regression": "tab:red",
    "pnp": "tab:green",
    "board": "tab:purple",
    "fused": "tab:orange",
    STALE: "tab:orange",
}
_LABELS = {
    "regression": "regression (papers)",
    "pnp": "SolvePnP, marker 2",
    "board": "board PnP",
    "fused": "fused",
    STALE: "fused (stale tables)",
}
# The bound the headline checks: within it a method is good enough to dock on (depth cm, lateral cm, yaw deg).
GOOD_ENOUGH = (1.0, 1.0, 1.0)
# An occluder stands this far in front of the charger face (a cable, a box): parallel to the face, so that
# its shadow on the face is an exact scaled copy and hides exactly the share of the marker it is built for.
OCCLUDER_DISTANCE_M = 0.05
# The occluder reaches past the marker's edge by this share of the marker's side (into the quiet zone; the
# neighbouring markers are a marker width away, so it never reaches them).
OCCLUDER_OVERHANG = 0.3
# The calibration set is rendered as ``monodock train``'s drive is (see SelfTrainConfig.supersample).
CALIBRATION_SUPERSAMPLE = 4
_DEFAULT = Nuisances()


@dataclass(frozen=True)
class Axis:
    """One nuisance swept on its own: its levels (in ``unit``) and the default level."""

    key: str
    title: str
    unit: str
    levels: tuple[float, ...]
    default: float
    kind: str  # "image": the pixels change; "calibration": the files the methods are given change


AXES: tuple[Axis, ...] = (
    Axis("noise", "sensor noise (read noise; shot noise scaled alike)", "DN", (0.0, 1.5, 4.0, 8.0), 1.5, "image"),
    Axis("defocus", "defocus blur (Gaussian sigma)", "px", (0.3, 0.6, 1.5, 2.5), _DEFAULT.defocus_px, "image"),
    Axis("motion_blur", "motion blur (streak length)", "px", (0.0, 2.0, 4.0, 6.0), _DEFAULT.motion_blur_px, "image"),
    Axis(
        "exposure", "exposure (gain; 1 = white near 85 % of full scale)", "x", (0.35, 0.6, 1.0, 1.6, 2.5), 1.0, "image"
    ),
    Axis("occlusion", "partial occlusion of one marker", "% of its area", (0.0, 10.0, 25.0, 40.0), 0.0, "image"),
    Axis("focal", "focal length error", "%", (-3.0, -1.5, 0.0, 1.5, 3.0), 0.0, "calibration"),
    Axis(
        "marker_size",
        "marker size error (layout file vs printed)",
        "%",
        (-5.0, -2.5, 0.0, 2.5, 5.0),
        0.0,
        "calibration",
    ),
    Axis("mount_x", "camera mount x error", "cm", (-1.0, 0.0, 1.0), 0.0, "calibration"),
    Axis("mount_y", "camera mount y error", "cm", (-1.0, 0.0, 1.0), 0.0, "calibration"),
    Axis("mount_z", "camera mount z error", "cm", (-1.0, 0.0, 1.0), 0.0, "calibration"),
    Axis("mount_roll", "camera mount roll error", "°", (-1.0, 0.0, 1.0), 0.0, "calibration"),
    Axis("mount_pitch", "camera mount pitch error", "°", (-1.0, 0.0, 1.0), 0.0, "calibration"),
    Axis("mount_yaw", "camera mount yaw error", "°", (-1.0, 0.0, 1.0), 0.0, "calibration"),
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
        K = list(camera.K)
        K[0] *= 1.0 + level / 100.0
        K[4] *= 1.0 + level / 100.0
        return Calibration(key, dataclasses.replace(camera, K=tuple(K)), layout, robot)
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
    scan: Any
    truth: DockPose


def _calibration_frame(setup: _CalibrationSetup, task: tuple[int, DockPose]) -> _CalibrationFrame:
    """Render one calibration frame (default nuisances) and measure it through every camera file."""
    from monodock.perception.detect import MarkerDetector
    from monodock.perception.features import feature_vector, refined_vector
    from monodock.perception.refine import refine_detection
    from monodock.sim.nuisance import apply_nuisances
    from monodock.sim.render import render_radiance

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


def _learn_tables(setup: _TableSetup, key: str) -> tuple[str, Any, int]:
    """The fusion tables ``monodock train`` would learn with one level's files: label the calibration set with
    the LiDAR through those files, run both methods on it, learn. Returns (key, tables, labelled rows)."""
    from monodock.estimation.bundle import load_bundle
    from monodock.estimation.regression import RegressionEstimator
    from monodock.learning.dataset import Dataset, LabelRun, label_frames
    from monodock.learning.fusion import learn_fusion_from

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
    meta = {"camera": cal.camera.to_ros_dict(), "robot": cal.robot.to_dict(), "layout": cal.layout.to_dict()}
    ds = Dataset({k: np.asarray(v) for k, v in cols.items()}, meta)
    regression = RegressionEstimator(load_bundle(Path(setup.bundle_path)), cal.camera, cal.robot)
    tables = learn_fusion_from(ds, regression, cal.camera, cal.layout, cal.robot, np.arange(n, dtype=np.int64))
    return key, tables, run.labelled


@dataclass
class _TestSetup:
    """What the test-frame workers need (sent to each once); the loaded models are built there."""

    bundle_path: str
    sim: Simulator
    images: list[ImageCondition]
    calibrations: dict[str, Calibration]
    tables: dict[str, Any]
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
    """The models a worker loads once: the detector, and per calibration level the methods on those files."""

    def __init__(self, setup: _TestSetup) -> None:
        from monodock.estimation.bundle import load_bundle
        from monodock.estimation.fused import FusedEstimator
        from monodock.estimation.regression import RegressionEstimator
        from monodock.perception.detect import MarkerDetector

        bundle = load_bundle(Path(setup.bundle_path))
        stale = bundle.fusion_tables()
        self.detector = MarkerDetector(setup.sim.layout)
        self.methods: dict[str, tuple[Calibration, Any, Any, Any]] = {}
        for key, cal in setup.calibrations.items():
            reg = RegressionEstimator(bundle, cal.camera, cal.robot)
            learned = setup.tables.get(key)
            fused = FusedEstimator(cal.camera, cal.layout, cal.robot, learned, reg) if learned is not None else None
            self.methods[key] = (cal, reg, fused, FusedEstimator(cal.camera, cal.layout, cal.robot, stale, reg))


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
    det: Any,
    refined_by_camera: dict[tuple[float, ...], Any],
    *,
    relearned: bool = True,
) -> dict[str, NDArray[np.float64]]:
    """Every method on one image with one calibration level's files (``relearned``: also fused with the
    tables re-learned with those files)."""
    from monodock.estimation.pnp import estimate_board, estimate_single_marker
    from monodock.perception.refine import refine_detection

    cal, reg_method, fused, stale = rt.methods[key]
    ck = _camera_key(cal.camera)
    if ck not in refined_by_camera:
        # The refinement straightens the sides through the lens model of the file it is given.
        refined_by_camera[ck] = refine_detection(image, det, cal.camera, modules=cal.layout.modules)
    refined = refined_by_camera[ck]
    reg = reg_method.estimate(det)
    out = {
        "regression": _row(reg),
        "pnp": _row(estimate_single_marker(det, cal.camera, cal.layout, cal.robot)),
        "board": _row(estimate_board(det, cal.camera, cal.layout, cal.robot)),
        STALE: _row(stale.estimate(det, refined, reg)),
    }
    if relearned and fused is not None:
        out["fused"] = _row(fused.estimate(det, refined, reg))
    return out


def _test_frame(setup: _TestSetup, task: tuple[int, DockPose]) -> _FrameResult:
    """Render one test pose at every image level and run every method on each (and on the default image with
    every calibration level's files)."""
    from monodock.sim.nuisance import apply_nuisances
    from monodock.sim.render import render_radiance

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
        refined: dict[tuple[float, ...], Any] = {}
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
    from tqdm import tqdm

    from monodock.core.parallel import map_with_state

    out: list[R] = []
    with tqdm(total=len(tasks), desc=desc, unit=unit, leave=False, disable=None if progress else True) as bar:
        for r in map_with_state(fn, state, tasks, jobs=jobs, chunksize=1):
            out.append(r)
            bar.update()
    return out


# --- the run ----------------------------------------------------------------------------------------------


@dataclass
class RobustnessResult:
    """Per axis, level and method the statistics (``axis_stats``), and what the run was."""

    config: RobustnessConfig
    axes: dict[str, dict[str, Any]]
    settings: dict[str, Any]
    occlusion: dict[str, Any]
    runtime_s: float
    truth: NDArray[np.float64]  # (frames, 3): the true DockPose x m, y m, yaw rad
    estimates: dict[str, dict[str, NDArray[np.float64]]]  # condition -> method -> (frames, 3), NaN when none


def _sample_poses(sim: Simulator, dist: PoseDistribution, count: int, rng: np.random.Generator) -> list[DockPose]:
    return [sim.sample_pose(dist, rng=rng) for _ in range(count)]


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

    from monodock.estimation.bundle import load_bundle

    if config.frames < 1:
        raise InputError(f"--frames must be at least 1, got {config.frames}")
    if config.calibration_frames < 50:
        raise InputError(
            f"--calibration-frames must be at least 50 to learn the fusion tables from, got {config.calibration_frames}"
        )
    if config.jobs < 1:
        raise InputError(f"--jobs must be at least 1, got {config.jobs}")
    load_bundle(bundle_path).fusion_tables()  # one clear line now for a bundle without fusion tables
    started = time.perf_counter()
    sim = Simulator(layout=layout, camera=camera, robot=robot, nuisances=_DEFAULT, seed=config.seed)
    images: dict[str, ImageCondition] = {"default": ImageCondition("default", _DEFAULT)}
    calibrations: dict[str, Calibration] = {}
    for axis in config.axes:
        for level in axis.levels:
            if axis.kind == "image":
                cond = image_condition(axis, level)
                images.setdefault(cond.key, cond)
            else:
                cal = calibration_for(axis, level, camera, layout, robot)
                calibrations.setdefault(cal.key, cal)
    calibrations.setdefault("default", Calibration("default", camera, layout, robot))

    # 1. The calibration set, measured through every camera file; 2. the tables each level's files learn.
    cal_poses = _sample_poses(sim, config.poses, config.calibration_frames, np.random.default_rng([config.seed, 0xCA1]))
    cameras = list({_camera_key(c.camera): c.camera for c in calibrations.values()}.values())
    cal_supersample = min(CALIBRATION_SUPERSAMPLE, config.supersample)
    log(
        f"robustness: {config.frames} test poses x {len(images)} image levels, {len(calibrations)} calibration "
        f"levels; calibration set of {config.calibration_frames} frames ({config.jobs} processes)"
    )
    cal_frames = _mapped(
        _calibration_frame,
        _CalibrationSetup(sim, cameras, config.seed, cal_supersample),
        list(enumerate(cal_poses)),
        jobs=config.jobs,
        desc="calibration set",
        unit="frame",
        progress=progress,
    )
    learned = _mapped(
        _learn_tables,
        _TableSetup(str(bundle_path), cal_frames, calibrations),
        list(calibrations),
        jobs=min(config.jobs, len(calibrations)),
        desc="fusion tables",
        unit="level",
        progress=progress,
    )
    stage = {"calibration set and tables": time.perf_counter() - started}
    tables = {k: t for k, t, _ in learned}
    labelled = {k: n for k, _, n in learned}

    # 3. The test poses, the same for every level.
    poses = _sample_poses(sim, config.poses, config.frames, np.random.default_rng([config.seed, 0x7E57]))
    setup = _TestSetup(
        str(bundle_path), sim, list(images.values()), calibrations, tables, config.seed, config.supersample
    )
    frames = _mapped(
        _test_frame,
        setup,
        list(enumerate(poses)),
        jobs=config.jobs,
        desc="test frames",
        unit="frame",
        progress=progress,
    )
    runtime = time.perf_counter() - started
    stage["test frames"] = runtime - stage["calibration set and tables"]
    truth = np.array([f.truth for f in frames], dtype=np.float64).reshape(-1, 3)
    depth = np.array([f.depth for f in frames], dtype=np.float64)
    estimates = {
        cond: {m: np.array([f.estimates[cond][m] for f in frames], dtype=np.float64).reshape(-1, 3) for m in methods}
        for cond, methods in frames[0].estimates.items()
    }
    axes = {axis.key: axis_stats(axis, estimates, truth, depth) for axis in config.axes}
    occ = _occlusion_stats(config, frames)
    settings = {
        "bundle": str(bundle_path),
        "test frames": config.frames,
        "seed": config.seed,
        "pose distribution": (
            f"depth {config.poses.depth[0] * 100:g}-{config.poses.depth[1] * 100:g} cm from the camera, lateral "
            f"{config.poses.lateral[0] * 100:+g}..{config.poses.lateral[1] * 100:+g} cm, yaw "
            f"{config.poses.yaw_deg[0]:+g}..{config.poses.yaw_deg[1]:+g}°, marker 2 in view"
        ),
        "test frame rendering": f"Nuisances() defaults, supersample {config.supersample}",
        "calibration set": (
            f"{config.calibration_frames} frames, default nuisances, supersample {cal_supersample}, other "
            f"poses and seeds; LiDAR labels valid: {min(labelled.values())}-{max(labelled.values())} per level"
        ),
        "processes": config.jobs,
        "runtime": f"{runtime:.0f} s ({', '.join(f'{k} {v:.0f} s' for k, v in stage.items())})",
    }
    return RobustnessResult(config, axes, settings, occ, runtime, truth, estimates)


def _stats(errors: NDArray[np.float64], depth: NDArray[np.float64]) -> dict[str, float]:
    """Valid rate, MAE (cm, cm, deg) over the valid frames and the mean depth error relative to depth (%)."""
    ok = np.isfinite(errors[:, 0])
    n = len(errors)
    if not ok.any():
        return {
            "valid_rate": 0.0,
            "depth_mae_cm": math.nan,
            "lateral_mae_cm": math.nan,
            "yaw_mae_deg": math.nan,
            "depth_bias_pct": math.nan,
        }
    e = errors[ok]
    return {
        "valid_rate": float(ok.sum()) / n,
        "depth_mae_cm": float(np.mean(np.abs(e[:, 0]))) * 100,
        "lateral_mae_cm": float(np.mean(np.abs(e[:, 1]))) * 100,
        "yaw_mae_deg": math.degrees(float(np.mean(np.abs(e[:, 2])))),
        "depth_bias_pct": float(np.mean(e[:, 0] / depth[ok])) * 100,
    }


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
) -> dict[str, Any]:
    """One axis: per method, per level (in order) the statistics of ``_stats``, as lists.

    Args:
        axis: the axis.
        estimates: per condition and method the estimates (frames, 3), x m, y m, yaw rad; NaN when none.
        truth: the true poses (frames, 3).
        depth: each frame's true depth from the camera, m.
    """
    methods = METHODS + ((STALE,) if axis.kind == "calibration" else ())
    out: dict[str, Any] = {
        "title": axis.title,
        "unit": axis.unit,
        "kind": axis.kind,
        "default": axis.default,
        "levels": list(axis.levels),
        "frames": len(truth),
        "methods": {},
    }
    for m in methods:
        per_level = []
        for level in axis.levels:
            key = _level_key(axis, level)
            cond = key if axis.kind == "image" else f"calibration:{key}"
            per_level.append(_stats(_errors(estimates[cond][m], truth), depth))
        out["methods"][m] = {k: [s[k] for s in per_level] for k in per_level[0]}
    return out


def _occlusion_stats(config: RobustnessConfig, frames: Sequence[_FrameResult]) -> dict[str, Any]:
    """Per occlusion level: the share of the marker the simulator finds hidden, and how often ArUco found it."""
    axis = next((a for a in config.axes if a.key == "occlusion"), None)
    if axis is None:
        return {}
    out: dict[str, Any] = {"levels": [], "hidden_measured_pct": [], "occluded_marker_detected_pct": []}
    for level in axis.levels:
        key = _level_key(axis, level)
        out["levels"].append(level)
        out["hidden_measured_pct"].append(100.0 * float(np.mean([f.hidden.get(key, 0.0) for f in frames])))
        out["occluded_marker_detected_pct"].append(100.0 * float(np.mean([f.occluded_seen[key] for f in frames])))
    out["occluded_marker"] = {f"m{ROLE_NUMBER[r]}": sum(f.occluded_role == r for f in frames) for r in ROLES}
    return out


# --- the report -------------------------------------------------------------------------------------------


def _fmt(v: float, digits: int = 2) -> str:
    return "—" if not math.isfinite(v) else f"{v:.{digits}f}"


def _worst(values: Iterable[float]) -> float:
    """The largest value; infinite when a level has no estimate at all (NaN)."""
    vals = list(values)
    return max((math.inf if not math.isfinite(v) else v) for v in vals) if vals else math.nan


def _within(stats: Mapping[str, list[float]]) -> bool:
    return all(
        _worst(stats[k]) <= bound
        for k, bound in zip(("depth_mae_cm", "lateral_mae_cm", "yaw_mae_deg"), GOOD_ENOUGH, strict=True)
    )


_SHORT = {"regression": "regression", "pnp": "pnp", "board": "board", "fused": "fused", STALE: "fused, stale"}


def headline(axes: Mapping[str, Mapping[str, Any]]) -> tuple[str, list[dict[str, Any]]]:
    """Per axis the worst level's MAE per method, and whether fused stays within GOOD_ENOUGH where board does not.

    Returns the markdown table (cells "depth / lateral / yaw", the lowest valid rate when below 100 %) and
    the same numbers as rows for summary.json.
    """
    methods = (*METHODS, STALE)
    head = "| axis | " + " | ".join(_SHORT[m] for m in methods) + " | fused within | board within |\n"
    head += "|---|" + "---:|" * len(methods) + "---|---|\n"
    lines, rows = [], []
    for key, a in axes.items():
        cells = []
        row: dict[str, Any] = {"axis": key}
        for m in methods:
            s = a["methods"].get(m)
            if s is None:
                cells.append("")
                continue
            worst = [_worst(s[k]) for k in ("depth_mae_cm", "lateral_mae_cm", "yaw_mae_deg")]
            valid = min(s["valid_rate"])
            row[m] = {
                "depth_mae_cm": worst[0],
                "lateral_mae_cm": worst[1],
                "yaw_mae_deg": worst[2],
                "valid_rate": valid,
            }
            rate = f" ({math.floor(valid * 100)} %)" if valid < 1.0 else ""
            cells.append(f"{_fmt(worst[0])} / {_fmt(worst[1])} / {_fmt(worst[2])}{rate}")
        fused_ok, board_ok = _within(a["methods"]["fused"]), _within(a["methods"]["board"])
        row["fused_within"], row["board_within"] = fused_ok, board_ok
        verdict = ("yes, board not" if not board_ok else "yes") if fused_ok else "no"
        name = key.replace("_", " ")
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {verdict} | {'yes' if board_ok else 'no'} |")
        rows.append(row)
    return head + "\n".join(lines) + "\n", rows


def axis_table(a: Mapping[str, Any]) -> str:
    """One axis as a markdown table: a row per level and method."""
    head = (
        f"| level ({a['unit']}) | method | valid % | depth MAE cm | lateral MAE cm | yaw MAE ° | depth bias % |\n"
        "|---:|---|---:|---:|---:|---:|---:|\n"
    )
    lines = []
    for i, level in enumerate(a["levels"]):
        mark = " (default)" if level == a["default"] else ""
        for m, s in a["methods"].items():
            lines.append(
                f"| {level:g}{mark} | {_LABELS[m]} | {s['valid_rate'][i] * 100:.0f} | {_fmt(s['depth_mae_cm'][i])} "
                f"| {_fmt(s['lateral_mae_cm'][i])} | {_fmt(s['yaw_mae_deg'][i])} | {_fmt(s['depth_bias_pct'][i], 1)} |"
            )
    return head + "\n".join(lines) + "\n"


def axis_plot(key: str, a: Mapping[str, Any], path: Path) -> None:
    """Three panels (depth, lateral, yaw MAE against the level), one line per method, the default marked."""
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), layout="constrained")
    levels = np.array(a["levels"], dtype=float)
    for ax, stat, label in zip(
        axes,
        ("depth_mae_cm", "lateral_mae_cm", "yaw_mae_deg"),
        ("depth (x) MAE (cm)", "lateral (y) MAE (cm)", "yaw MAE (°)"),
        strict=True,
    ):
        values = []
        for m, s in a["methods"].items():
            v = np.array(s[stat], dtype=float)
            values += [x for x in v if math.isfinite(x) and x > 0]
            valid = min(s["valid_rate"]) * 100
            ax.plot(
                levels,
                v,
                "--" if m == STALE else "-",
                marker="s" if m == STALE else "o",
                color=_COLOURS[m],
                label=f"{_LABELS[m]} (valid ≥ {valid:.0f} %)",
                ms=5,
                mfc="none" if m == STALE else None,
            )
        if values and max(values) / min(values) > 10:
            ax.set_yscale("log")
            ax.yaxis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
            ax.yaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _pos: f"{v:g}"))
            ax.yaxis.set_minor_formatter(ticker.NullFormatter())
        ax.axvline(a["default"], color="grey", ls=":", lw=1.2)
        ax.annotate(
            "default",
            (a["default"], 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(3, -12),
            textcoords="offset points",
            fontsize=8,
            color="grey",
        )
        ax.set_xticks(levels)
        ax.set_xlabel(f"{a['title']} ({a['unit']})")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), fontsize=8, frameon=False)
    fig.suptitle(f"{a['title']}: error against the simulator's truth, {a['frames']} frames per level ({key})")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_robustness_report(result: RobustnessResult, out: Path) -> dict[str, Any]:
    """report.html, report.md, summary.json and one PNG per axis in ``out``; returns the summary."""
    report = HtmlReport("monodock robustness: every method against one nuisance at a time")
    report.heading("Settings")
    report.settings(result.settings)
    report.paragraph(
        "Each axis is swept on its own, everything else at the defaults (Nuisances()). The same test poses are "
        "used at every level, each frame with the same random draws (sensor noise, exposure jitter, motion-blur "
        "direction, occluder), so the curves differ by the nuisance alone. Errors are against the simulator's "
        "truth; MAE is over each method's valid frames (its valid rate is given beside it)."
    )
    report.bullets(
        [
            "regression: the papers' (the bundle's models); pnp: marker 2 alone (IPPE); board: every visible "
            "marker; fused: planar PnP on refined corners combined with the regression.",
            "Calibration axes render the default images and give every method the wrong file. 'fused' has its "
            "tables re-learned with the same wrong files on a LiDAR-labelled calibration set, as monodock train "
            "would have on that robot (also at level 0, from that small set); 'fused (stale tables)' keeps the "
            "bundle's tables, learned with the right files (a calibration that changed after training).",
            "The regression is not retrained per level: under a wrong focal length its inputs shift, which a "
            "regression retrained with the same wrong file would absorb (and so would fused's regression half).",
            "MAE is over each method's own valid frames: where a nuisance makes a method drop frames, its MAE "
            "is over the frames it still answers, which need not be the easy ones nor the hard ones; read it with "
            "the valid rate (in the tables and the legends). frames.npz has every frame's numbers.",
            "Noise: the read noise is the level; the shot noise is scaled by the same factor (a higher gain).",
            "Occlusion: a board 5 cm in front of the charger face, parallel to it, hides the given share of one "
            "marker's area from one side (the marker and side drawn per frame, the same at every level). ArUco "
            "may then miss that marker: the valid rates count it.",
        ]
    )
    report.heading("Headline: the worst level of each axis")
    table, rows = headline(result.axes)
    report.paragraph(
        "Per axis and method: depth MAE (cm) / lateral MAE (cm) / yaw MAE (°), each at the level where it is "
        "worst, and in brackets the lowest valid rate over the levels when below 100 %. 'fused within': "
        "fused stays within 1 cm depth, 1 cm lateral and 1° yaw at every level (on calibration axes: fused "
        "with re-learned tables); 'yes, board not': where board does not."
    )
    report.table(table)
    summary: dict[str, Any] = {
        "settings": result.settings,
        "runtime_s": result.runtime_s,
        "good_enough": {"depth_cm": GOOD_ENOUGH[0], "lateral_cm": GOOD_ENOUGH[1], "yaw_deg": GOOD_ENOUGH[2]},
        "headline": rows,
        "axes": result.axes,
        "occlusion": result.occlusion,
    }
    for kind, title in (("image", "Image nuisances"), ("calibration", "Calibration errors")):
        report.heading(title)
        for key, a in result.axes.items():
            if a["kind"] != kind:
                continue
            report.heading(f"{a['title']} ({a['unit']})", 3)
            report.table(axis_table(a))
            if key == "occlusion" and result.occlusion:
                o = result.occlusion
                report.paragraph(
                    "Share of the marker hidden, as the simulator measures it (9x9 grid): "
                    + ", ".join(
                        f"{lv:g} %: {h:.0f} %" for lv, h in zip(o["levels"], o["hidden_measured_pct"], strict=True)
                    )
                    + ". ArUco found the occluded marker in "
                    + ", ".join(f"{d:.0f} %" for d in o["occluded_marker_detected_pct"])
                    + " of the frames. Occluded marker: "
                    + ", ".join(f"{k} {v}" for k, v in o["occluded_marker"].items())
                    + " frames."
                )
            axis_plot(key, a, out / f"{key}.png")
            report.image(f"{key}.png", a["title"])
    report.paragraph(
        "frames.npz holds every frame's numbers: 'truth' (frames x 3: x m, y m, yaw rad) and one array per "
        "condition and method ('CONDITION|METHOD', the same layout, NaN where the method gave no estimate)."
    )
    arrays = {"truth": result.truth}
    arrays.update({f"{c}|{m}": v for c, per in result.estimates.items() for m, v in per.items()})
    np.savez_compressed(out / "frames.npz", **arrays)  # type: ignore[arg-type]
    report.write(out, summary)
    return summary
